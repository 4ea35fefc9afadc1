"""recon.posture.reach: an arm the scan shows only sparsely, searched as a chain from its shoulder."""

import warnings

import numpy as np
import pytest

from bodyscan.recon import FitParams, estimate_posture
from bodyscan.recon.posture.bodymodel import standard_body
from bodyscan.recon.model import SECTIONS, SectionShape
from bodyscan.recon.posture.reach import reach_arms

X = np.array([1.0, 0.0, 0.0])


def _scene(arm_points: bool = True, seed: int = 0):
    """A chest column (points all round it), a left arm held straight forward (-y) from the shoulder,
    seen end-on: a sparse line of points along the top of the upper arm and forearm (every 3 cm) and
    the fist (the forearm's end cap, seen by the camera the arm points at). The fit placed the arm
    hanging down the torso's side (listed unfitted)."""
    rng = np.random.default_rng(seed)
    body = standard_body(1.75)
    Lu, Lf = body.section_length("upper_arm_l"), body.section_length("forearm_l")
    ru, rf = body.radii("upper_arm").mean(), body.radii("forearm").mean()
    shoulder = np.array([0.2, -0.02, 1.41])
    fwd = np.array([0.0, -1.0, 0.0])
    chest = SectionShape("chest", [0, 0, 1.05], [0, 0, 1.5], [0.16, 0.115], X)
    pts = [chest.surface_points(48, 30)]
    if arm_points:
        # the top of the arm: a line 30 degrees either side of straight up, every 3 cm
        t = np.arange(0.05, Lu + Lf - 0.02, 0.03)
        r = np.where(t < Lu, ru, rf)
        for a in np.radians([-30.0, 30.0]):
            side = np.array([np.sin(a), 0.0, np.cos(a)])
            pts.append(shoulder + t[:, None] * fwd + (r * 1.0)[:, None] * side)
        # the fist: the end cap facing the camera, 25 points on a disc
        u = rng.uniform(0, 2 * np.pi, 25)
        q = rf * np.sqrt(rng.uniform(0, 1, 25))
        pts.append(shoulder + (Lu + Lf) * fwd + np.stack([q * np.cos(u), np.zeros(25), q * np.sin(u)], 1)
                   + 0.6 * rf * fwd * np.sqrt(1 - (q / rf) ** 2)[:, None])
    down = np.array([0.0, 0.0, -1.0])
    secs = {
        "chest": chest,
        "upper_arm_l": SectionShape("upper_arm_l", shoulder, shoulder + Lu * down, [ru, ru], X),
        "forearm_l": SectionShape("forearm_l", shoulder + Lu * down, shoulder + (Lu + Lf) * down, [rf, rf], X),
    }
    return np.concatenate(pts), secs, body, fwd


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(a @ b, -1, 1))))


def test_a_sparse_arm_held_forward_is_found():
    """About 40 points on the arm's top and 25 on its fist place the arm within 10 degrees, both
    sections, and they are no longer listed."""
    pts, secs, body, fwd = _scene()
    resid = {k: 0.01 for k in secs}
    counts = {"chest": 1000, "upper_arm_l": 0, "forearm_l": 0}
    out, res, cnt, reached = reach_arms(pts, secs, resid, counts, ("upper_arm_l", "forearm_l"), body, FitParams())
    assert reached == {"upper_arm_l", "forearm_l"}
    assert _angle(out["upper_arm_l"].axis, fwd) < 10 and _angle(out["forearm_l"].axis, fwd) < 10
    assert np.linalg.norm(out["upper_arm_l"].start - secs["upper_arm_l"].start) < 0.02   # from the shoulder
    assert np.linalg.norm(out["forearm_l"].end - (secs["upper_arm_l"].start + fwd * (
        body.section_length("upper_arm_l") + body.section_length("forearm_l")))) < 0.08
    assert cnt["forearm_l"] >= 10 and res["forearm_l"] < 0.02


def test_a_missing_arm_is_not_invented():
    """The same scene without the arm's points: nothing is found, the arm stays listed; and an arm
    not listed is never searched."""
    pts, secs, body, _ = _scene(arm_points=False)
    resid = {k: 0.01 for k in secs}
    counts = {"chest": 1000, "upper_arm_l": 0, "forearm_l": 0}
    out, _, _, reached = reach_arms(pts, secs, resid, counts, ("upper_arm_l", "forearm_l"), body, FitParams())
    assert reached == set() and out["upper_arm_l"] is secs["upper_arm_l"]

    pts, secs, body, _ = _scene()
    out, _, _, reached = reach_arms(pts, secs, resid, counts, ("chest",), body, FitParams())
    assert reached == set() and out["forearm_l"] is secs["forearm_l"]


def test_an_arm_cut_at_the_elbow_is_not_completed():
    """Only the upper arm's points (the forearm and hand cut off): no chain has a hand end on points,
    so no forearm is invented (bent back onto the upper arm's own points, say)."""
    pts, secs, body, fwd = _scene()
    shoulder = secs["upper_arm_l"].start
    t = (pts - shoulder) @ fwd
    keep = (t < body.section_length("upper_arm_l")) | (np.linalg.norm(pts[:, :2], axis=1) < 0.2)
    out, _, _, reached = reach_arms(pts[keep], secs, {k: 0.01 for k in secs}, {k: 0 for k in secs},
                                    ("upper_arm_l", "forearm_l"), body, FitParams())
    assert reached == set()


def _arms_forward_scan():
    from bodyscan import poses
    from bodyscan import simulator

    assert "arms_forward" in poses.list_bodies(), "arms_forward not shipped"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return poses.load_body("arms_forward"), simulator.scan(poses.load_body("arms_forward"),
                                                              simulator.preset("paper"))


def test_arms_forward_is_fitted_with_its_arms():
    """The shipped arms_forward scan (paper, 10 mm, k = 1): both arms fitted, each limb section within
    20 degrees of its bone (issue 4); before `recon.posture.reach` three arm sections were listed."""
    from bodyscan.benchmarks.fit_table import score_fit

    body, scan = _arms_forward_scan()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(scan.points)
    assert fit.unfitted == ()
    err, ang = score_fit(fit, body.joint_dict())
    assert max(ang[n] for n in ang if "arm" in n) <= 20
    assert np.median(list(err.values())) <= 0.04 and max(err.values()) <= 0.10


@pytest.mark.parametrize("side", ["l", "r"])
def test_arms_forward_with_an_arm_cut_off_lists_it(side):
    """The same scan with one arm's points removed (simulator labels): that arm stays unfitted, the
    other is fitted."""
    _, scan = _arms_forward_scan()
    cut = np.isin(scan.gt_section, [SECTIONS.index(f"upper_arm_{side}"), SECTIONS.index(f"forearm_{side}")])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(scan.points[~cut])
    other = "r" if side == "l" else "l"
    assert {f"upper_arm_{side}", f"forearm_{side}"} <= set(fit.unfitted)
    assert not {f"upper_arm_{other}", f"forearm_{other}"} & set(fit.unfitted)
