"""`benchmarks.recon_table`: its area measures agree with the bench's scoring of the same mesh."""

import warnings

import pytest

from bodyscan.benchmarks import recon_table


def test_body_row_scores_the_curved_mesh_as_the_bench_does():
    # proposed's mesh has vertices the curved subdivision made, beyond the scan's points: each
    # needs the true triangle under it (indexing the scan's by vertex failed on them)
    from bodyscan.benchmarks.bench import score
    from bodyscan.benchmarks.oracle import fit_from_body
    from bodyscan.poses import load_body
    from bodyscan.recon import reconstruct
    from bodyscan.simulator.config import preset
    from bodyscan.simulator.scan import scan

    row = recon_table.body_row("standing", {}, top=3)
    body = load_body("standing")
    s = scan(body, preset("paper"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(s.points, "proposed", view_dir=s.view_dir, fit=fit_from_body(body))
    assert len(rec.vertices) > len(s.points)          # the case that failed: made vertices
    ref = score(rec.vertices, rec.faces, body, s, point_index=rec.point_index,
                point_sections=rec.point_sections)
    assert row["bridge_proposed"] == pytest.approx(ref["bridging_area_fraction"], abs=1e-9)
    assert row["spur_proposed"] == pytest.approx(ref["spurious_area_fraction"], abs=1e-9)
    assert row["acc"] == pytest.approx(ref["section_accuracy"], abs=1e-9)


def test_perf_recon_sweep_scores_the_curved_mesh(capsys):
    from bodyscan.benchmarks.perf_recon import sweep_tn

    sweep_tn(["standing"], [0.5], oracle=True)
    out = capsys.readouterr().out.splitlines()
    accuracy, spurious, bridging = map(float, out[-1].split()[1:])
    assert 0.9 < accuracy <= 1 and 0 <= spurious < 0.05 and 0 <= bridging < 0.005
