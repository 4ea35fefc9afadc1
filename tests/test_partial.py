"""Partial bodies (issue 4): sections cut from the scan are listed unfitted, never placed where their
points are not, and the rest of the body is fitted near the truth."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from benchmarks.fit_table import rot_z, score_fit
from recon import FitParams, estimate_posture
from recon.bodymodel import StandardBody
from recon.model import SECTIONS, SectionShape
from recon.posture import _on_trunk


def _cut_scan(name, cut, turn=0.0):
    """The `paper` scan (10 mm, k = 1) of the library body ``name`` turned ``turn`` degrees before
    the scan, the points of the sections ``cut`` removed (ground-truth labels of the simulator);
    returns (points, true joints)."""
    import poses
    import simulator

    if name not in poses.list_bodies():
        pytest.skip(f"library body {name} not shipped")
    body = poses.load_body(name)
    if turn:
        R = rot_z(turn)
        body = replace(body, vertices=body.vertices @ R.T, joints=body.joints @ R.T)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=1))
    keep = ~np.isin(scan.gt_section, [SECTIONS.index(n) for n in cut])
    return scan.points[keep], body.joint_dict()


@pytest.mark.parametrize("name, cut, turn", [
    # each of these placed a section on points not its own before the arm-clearance check
    # (walking: a forearm across the chest, wrist 55 cm off; arms_forward: the right forearm folded
    # onto the chest, wrist 57 cm off)
    ("walking", ("forearm_l",), 0.0),
    ("arms_forward", ("upper_arm_l", "forearm_l"), 0.0),
    ("standing", ("forearm_l",), 90.0),
    ("t_pose", ("upper_arm_l", "forearm_l"), 0.0),
])
def test_cut_sections_are_listed_and_the_rest_is_near_the_truth(name, cut, turn):
    pts, joints = _cut_scan(name, cut, turn)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(pts)
    assert set(cut) <= set(fit.unfitted), f"cut {cut}, listed {fit.unfitted}"
    assert not set(cut) & set(fit.sections)
    # only sections the scan does not show are listed: the other arm, the legs, the head are fitted
    assert set(fit.unfitted) == set(cut), f"cut {cut}, listed {fit.unfitted}"
    err, _ = score_fit(fit, joints)
    worst = max(err, key=err.get)
    assert err[worst] <= 0.15, f"{worst} {100 * err[worst]:.1f} cm off"


def _trunk_and_arm(offset):
    """A chest column (radii 0.16 x 0.11 m, along +z) and a left forearm running down its side,
    its axis ``offset`` m outside the chest's surface across the body (+x)."""
    body = StandardBody()
    chest = SectionShape("chest", np.array([0, 0, 1.0]), np.array([0, 0, 1.5]), [0.16, 0.11], [1.0, 0, 0])
    waist = SectionShape("waist", np.array([0, 0, 0.6]), np.array([0, 0, 1.0]), [0.15, 0.10], [1.0, 0, 0])
    x = 0.16 + offset
    fore = SectionShape("forearm_l", np.array([x, 0, 1.45]), np.array([x, 0, 1.20]), [0.037, 0.037], [0, 1.0, 0])
    return body, {"chest": chest, "waist": waist, "forearm_l": fore}


@pytest.mark.parametrize("offset, on", [(-0.02, True), (0.0, True), (0.015, True), (0.05, False), (0.08, False)])
def test_a_forearm_on_the_trunks_surface_is_not_an_arm(offset, on):
    """An arm's axis keeps about a radius outside the skin; one on or in the trunk's surface is the
    trunk's own surface (`recon.posture._on_trunk`)."""
    body, secs = _trunk_and_arm(offset)
    assert _on_trunk("forearm_l", secs, body, FitParams()) is on
    assert _on_trunk("chest", secs, body, FitParams()) is False


def test_points_on_another_sections_surface_are_shared():
    """`recon.reach._shared_fraction`: a limb explains points no other section explains; points of
    the chest's surface under a forearm laid on it are shared, points around a free forearm are not."""
    from recon.reach import _shared_fraction

    body, secs = _trunk_and_arm(0.0)
    on_chest = secs["chest"].surface_points(48, 20)
    on_chest = on_chest[np.abs(on_chest[:, 1]) < 0.05]          # the strip under the forearm
    free = {**secs, "forearm_l": secs["forearm_l"].replace(start=secs["forearm_l"].start + [0.3, 0, 0],
                                                           end=secs["forearm_l"].end + [0.3, 0, 0])}
    own = free["forearm_l"].surface_points(24, 12)
    assert _shared_fraction(on_chest, secs, "forearm_l", 0.02) > 0.9
    assert _shared_fraction(own, free, "forearm_l", 0.02) == 0.0
    assert _shared_fraction(own[:0], free, "forearm_l", 0.02) == 0.0


@pytest.mark.xfail(strict=True, reason="legs cut from the scan are not listed: the coarse match sizes the body from "
                          "its leg chains (recon.match) and places the lower legs on the thigh stumps, the thighs on "
                          "the pelvis; walking without its lower legs: nothing listed, median 11.9 / max 44.8 cm "
                          "(ankles), stature judged 1.22 m (true 1.71). Even at the true stature (fit_stature) 4 of "
                          "6 leg cuts on standing / t_pose / arms_forward stay WRONG (front and back from the legs, "
                          "recon.joints.front_sign, flipped: wrists 52-145 cm off)")
def test_cut_lower_legs_are_listed_and_the_rest_is_near_the_truth():
    cut = ("lower_leg_l", "lower_leg_r")
    pts, joints = _cut_scan("walking", cut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(pts)
    assert set(cut) <= set(fit.unfitted)
    err, _ = score_fit(fit, joints)
    assert max(err.values()) <= 0.15
