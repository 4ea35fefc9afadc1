"""The ``paper`` method: the proposed steps with every rule of ours off (`recon.params.PAPER`)."""

import dataclasses
import warnings

import numpy as np

from bodyscan.recon import ReconParams, reconstruct
from bodyscan.recon.params import PAPER
from test_pipeline import capsule_body


def test_paper_params_switch_off_every_rule_of_ours_and_nothing_else():
    base = ReconParams()
    paper = base.paper()
    flat, flat_base = paper.to_dict(), base.to_dict()
    assert all(flat[k] == v for k, v in PAPER.items())
    assert {k for k in flat if flat[k] != flat_base[k]} <= set(PAPER)
    # the user's other choices are kept
    tuned = ReconParams.from_overrides({"t_n_factor": 1.0, "fold_cos": 0.3}).paper()
    assert tuned.cluster.t_n_factor == 1.0 and tuned.surface.fold_cos == -1.0


def test_paper_method_is_proposed_with_the_paper_params_on_an_analytic_body():
    P, L, N, vd, fit = capsule_body()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paper = reconstruct(P, "paper", view_dir=vd, fit=fit)
        same = reconstruct(P, "proposed", ReconParams.from_overrides(PAPER), view_dir=vd, fit=fit)
    assert paper.method == "paper" and paper.params == ReconParams().paper()
    np.testing.assert_array_equal(paper.faces, same.faces)
    np.testing.assert_array_equal(paper.point_sections, same.point_sections)
    # against the truth: the paper's clustering on capsules (true labels L) is good, not perfect
    m = paper.point_sections
    score = np.where(m[np.arange(len(L)), L], 1.0 / np.maximum(m.sum(1), 1), 0.0)
    assert 0.9 < score.mean() < 1.0
    assert dataclasses.asdict(ReconParams()) != dataclasses.asdict(paper.params)
