"""Where the clustering goes wrong: per body, accuracy, confused section pairs and the rule that
decided them, spurious and bridging area.

Usage::

    nice python -m bodyscan.benchmarks.recon_table [--bodies a,b|DIR] [--top 3] [--param NAME=VALUE ...] [--estimated]
                                          [--turn DEG]

Each body of the library is scanned with the `paper` preset, its posture is the oracle one
(`benchmarks.oracle.fit_from_body`; ``--estimated``: `recon.pipeline.estimate_fit`), and it is
reconstructed with ``proposed`` and ``simple``. One line per body:

- ``acc``: `benchmarks.metrics.section_accuracy` of ``proposed`` (a point with m labels scores 1/m
  when the truth is among them), ``any``: the truth among the labels;
- ``loss by rule``: the accuracy lost (1 - score, as a fraction of all points) by the rule that
  decided each point: ``single`` (one section after the T_d threshold), ``refine`` (one section
  after the Otsu refinement), ``adopt`` (no section within T_d, adopted from a neighbour), ``3+``
  (three or more sections), ``joint`` (two adjacent sections at their joint), ``two`` (two
  sections, not at a joint), ``none`` (left unlabelled);
- the ``--top`` confused pairs: ``truth>label`` with the loss and the rule that cost most;
- ``spur``: spurious area fraction of proposed / simple (the paper's test); ``bridge``: bridging
  area fraction of proposed, and its largest pair.

A last line gives the means. Slow (a few seconds per body): run it with ``nice``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np

RULES = ("single", "refine", "adopt", "3+", "joint", "two", "none")


def rule_of_points(points, fit, params, coords, tree):
    """(n,) int index into `RULES`: the clustering rule that decided each point (proposed)."""
    from bodyscan.recon.clustering import cluster as C

    cp = params.cluster
    r, theta, h = coords
    widths = C.section_widths(fit)
    m0 = C.simple_clustering(r, widths, cp.t_d)
    m1 = C.refine_by_distance(m0, r, theta, h, fit, cp)
    radius = C.neighbor_radius(points, cp, tree)
    m2 = C.adopt_unlabeled(m1, points, radius, cp.max_rounds, tree) if cp.adopt_unlabeled else m1
    m3 = C.reduce_to_two(m2, points, r, widths, max_rounds=cp.max_rounds, tree=tree,
                         keep_nearest=cp.three_keep_nearest)
    c0, c1, c2, c3 = (m.sum(axis=1) for m in (m0, m1, m2, m3))
    rule = np.full(len(points), RULES.index("none"))
    rule[c1 == 1] = np.where(c0[c1 == 1] == 1, RULES.index("single"), RULES.index("refine"))
    rule[(c1 == 0) & (c2 > 0)] = RULES.index("adopt")
    two = np.flatnonzero((c3 == 2) & (c2 >= 2))
    if len(two):
        A, B = C._pairs(m3, two)
        at = C.at_joint_mask(points[two], A, B, h[two], fit, cp.joint_reach)
        rule[two] = np.where(at, RULES.index("joint"), RULES.index("two"))
    rule[c2 >= 3] = RULES.index("3+")
    rule[(c2 == 2) & (c3 == 1)] = RULES.index("3+")
    return rule


def body_row(name, overrides, top=3, estimated=False, turn=0.0):
    """Measurements of one body (dict); ``turn``: degrees the body is turned about the vertical
    before the scan (the cameras see it from another side)."""
    from bodyscan.poses import load_body
    from bodyscan.recon import ReconParams, reconstruct
    from bodyscan.recon.pipeline import estimate_fit
    from bodyscan.recon.model import SECTIONS
    from bodyscan.simulator.config import preset
    from bodyscan.simulator.scan import scan

    from . import metrics as M
    from .oracle import fit_from_body

    body = load_body(name)
    if turn:
        from .fit_table import turned_body

        body = turned_body(body, turn)
    s = scan(body, preset("paper"))
    params = ReconParams.from_overrides(overrides)
    # estimated as `reconstruct` does it (outliers left out first)
    fit = estimate_fit(s.points, params, view_dir=s.view_dir, head=s.head) if estimated else fit_from_body(body)
    truth = M.GroundTruth.from_body(body, M.MetricParams(n_samples=1000))
    out = {"body": body.name}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for method in ("simple", "proposed"):
            rec = reconstruct(s.points, method, params, view_dir=s.view_dir, fit=fit)
            # vertices the method made (curved subdivision) take the nearest true triangle
            tf = M.corner_true_faces(rec.vertices, rec.faces, truth, scan_points=s.points,
                                     scan_gt_face=s.gt_face, point_index=rec.point_index)
            out[f"spur_{method}"] = M.spurious(rec.vertices, rec.faces, tf, truth,
                                               truth.params)["spurious_area_fraction"]
            br = M.bridging(rec.vertices, rec.faces, tf, truth, truth.params)
            out[f"bridge_{method}"] = br["bridging_area_fraction"]
            out[f"bridge_pairs_{method}"] = json.loads(br["bridging_pairs"])
            out[f"time_{method}"] = rec.times["total"]
    acc = M.section_accuracy(rec.point_sections, s.gt_section)
    out["acc"], out["any"] = acc["section_accuracy"], acc["section_accuracy_any"]
    from scipy.spatial import cKDTree

    from bodyscan.recon.clustering.cluster import section_coordinates

    p = np.asarray(s.points, dtype=float)
    widest = max(sh.width for sh in fit.sections.values())
    coords = section_coordinates(p, fit, margin=params.cluster.t_d * widest + 0.01)
    rule = rule_of_points(p, fit, params, coords, cKDTree(p))
    gt = np.asarray(s.gt_section)
    ps = rec.point_sections
    known = gt >= 0
    m = ps.sum(axis=1)
    hit = ps[np.arange(len(gt)), np.where(known, gt, 0)] & known
    loss = np.where(known, 1.0 - np.where(hit, 1.0 / np.maximum(m, 1), 0.0), 0.0)
    total = known.sum()
    out["loss_by_rule"] = {RULES[k]: float(loss[rule == k].sum() / total) for k in range(len(RULES))}
    # confused pairs: each wrong label of a point carries its share of the point's loss
    pairs = {}
    wrong = np.flatnonzero(loss > 0)
    for k in range(len(SECTIONS)):
        sel = wrong[ps[wrong, k] & (gt[wrong] != k)]
        if len(sel) == 0:
            continue
        nwrong = (ps[sel] & (np.arange(len(SECTIONS))[None, :] != gt[sel, None])).sum(axis=1)
        share = loss[sel] / nwrong
        for t in np.unique(gt[sel]):
            q = gt[sel] == t
            by_rule = np.bincount(rule[sel][q], weights=share[q], minlength=len(RULES)) / total
            pairs[f"{SECTIONS[t]}>{SECTIONS[k]}"] = (float(share[q].sum() / total),
                                                     RULES[int(by_rule.argmax())])
    none = wrong[m[wrong] == 0]
    if len(none):
        pairs["*>none"] = (float(loss[none].sum() / total), "none")
    out["pairs"] = sorted(pairs.items(), key=lambda kv: -kv[1][0])[:top]
    return out


def _short(name):
    return (name.replace("upper_arm", "uarm").replace("forearm", "farm").replace("lower_leg", "shin"))


def format_row(row):
    rules = " ".join(f"{k}{v * 100:.1f}" for k, v in row["loss_by_rule"].items() if v >= 0.0005)
    pairs = ", ".join(f"{_short(k)} {v * 100:.1f}({rule})" for k, (v, rule) in row["pairs"])
    bp = row["bridge_pairs_proposed"]
    worst = next(iter(bp), "-")
    return (f"{row['body']:>17s} acc {row['acc']:.3f} any {row['any']:.3f} | loss% {rules} | {pairs} | "
            f"spur {row['spur_proposed']:.3f}/{row['spur_simple']:.3f} | bridge "
            f"{row['bridge_proposed'] * 100:.2f}% ({_short(worst)}) | {row['time_proposed']:.1f}s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bodies", help="library bodies, body files or folders of them (a corpus of "
                        "`bodyscan poses sample`), comma-separated (default: all shipped)")
    parser.add_argument("--top", type=int, default=3, help="confused pairs shown per body (default 3)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a reconstruction parameter (repeatable)")
    parser.add_argument("--estimated", action="store_true",
                        help="estimate the posture instead of the oracle one")
    parser.add_argument("--turn", type=float, default=0.0,
                        help="turn every body this many degrees about the vertical before the scan")
    parser.add_argument("--json", help="also write the rows to this JSON file")
    a = parser.parse_args(argv)
    from bodyscan.poses.library import expand_bodies

    from bodyscan.recon import ReconError, ReconParams

    from .bench_cli import _pairs

    overrides = _pairs(a.param, "--param")
    ReconParams.from_overrides(overrides)   # a bad name or value: one line, before any work
    if a.json:
        from bodyscan._io import check_out

        check_out(a.json, option="--json", suffixes=(".json",))
    bodies = expand_bodies(b for b in (a.bodies or "").split(",") if b)

    rows, refused = [], []
    for name in bodies:
        try:
            row = body_row(name, overrides, a.top, a.estimated, a.turn)
        except ReconError as e:   # the estimated posture refused
            refused.append(name)
            print(f"{name:>17s} refused: {e}", flush=True)
            continue
        rows.append(row)
        print(format_row(row), flush=True)
    if refused:
        print(f"{'refused':>17s} {len(refused)}: {', '.join(refused)}")
    if rows:
        mean = {k: float(np.mean([r[k] for r in rows])) for k in
                ("acc", "any", "spur_proposed", "spur_simple", "bridge_proposed")}
        n95 = sum(r["acc"] >= 0.95 for r in rows)
        a95 = sum(r["any"] >= 0.95 for r in rows)
        nbr = sum(r["bridge_proposed"] < 0.005 for r in rows)
        nsp = sum(r["spur_proposed"] < r["spur_simple"] for r in rows)
        lbr = {k: float(np.mean([r["loss_by_rule"][k] for r in rows])) * 100 for k in RULES}
        print(f"{'mean':>17s} acc {mean['acc']:.3f} (min {min(r['acc'] for r in rows):.3f}, "
              f">=0.95: {n95}/{len(rows)}) any {mean['any']:.3f} (min {min(r['any'] for r in rows):.3f}, "
              f">=0.95: {a95}/{len(rows)}) | loss% "
              + " ".join(f"{k}{v:.2f}" for k, v in lbr.items())
              + f" | spur {mean['spur_proposed']:.3f}/{mean['spur_simple']:.3f} (p<s {nsp}/{len(rows)})"
              f" | bridge {mean['bridge_proposed'] * 100:.2f}% (max "
              f"{max(r['bridge_proposed'] for r in rows) * 100:.2f}%, <0.5%: {nbr}/{len(rows)})")
        from .fit_table import wilson

        n = len(rows)
        (alo, ahi), (blo, bhi) = wilson(n95, n), wilson(nbr, n)
        print(f"{'rates':>17s} acc >= 0.95 {n95}/{n} = {n95 / n:.3f} (95% CI {alo:.3f}-{ahi:.3f}); "
              f"bridging < 0.5% {nbr}/{n} = {nbr / n:.3f} (95% CI {blo:.3f}-{bhi:.3f})")
    if a.json:
        from bodyscan._io import write_json

        write_json(a.json, rows, indent=1)
    return 0


if __name__ == "__main__":
    from bodyscan.benchmarks.cli import run_script

    sys.exit(run_script("recon_table", main))
