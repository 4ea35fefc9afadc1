"""Partial bodies (issue 4): sections cut from the scan are listed unfitted, never placed where their
points are not, and the rest of the body is fitted near the truth."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from bodyscan.benchmarks.fit_table import rot_z, score_fit
from bodyscan.recon import FitParams, estimate_posture
from bodyscan.recon.posture.bodymodel import StandardBody
from bodyscan.recon.model import SECTIONS, SectionShape
from bodyscan.recon.posture.fit import _on_trunk


def _cut_scan(name, cut, turn=0.0):
    """The `paper` scan (10 mm, k = 1) of the library body ``name`` turned ``turn`` degrees before
    the scan, the points of the sections ``cut`` removed (ground-truth labels of the simulator);
    returns (points, true joints)."""
    from bodyscan import poses
    from bodyscan import simulator

    assert name in poses.list_bodies(), f"library body {name} not shipped"
    body = poses.load_body(name)
    if turn:
        R = rot_z(turn)
        body = replace(body, vertices=body.vertices @ R.T, joints=body.joints @ R.T)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=1))
    keep = ~np.isin(scan.gt_section, [SECTIONS.index(n) for n in cut])
    return scan.points[keep], body.joint_dict()


def _fit_cut(name, cut, turn=0.0):
    """`_cut_scan` fitted: (BodyFit, per joint error in m)."""
    pts, joints = _cut_scan(name, cut, turn)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(pts)
    return fit, score_fit(fit, joints)[0]


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
    fit, err = _fit_cut(name, cut, turn)
    assert set(cut) <= set(fit.unfitted), f"cut {cut}, listed {fit.unfitted}"
    assert not set(cut) & set(fit.sections)
    # only sections the scan does not show are listed: the other arm, the legs, the head are fitted
    assert set(fit.unfitted) == set(cut), f"cut {cut}, listed {fit.unfitted}"
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
    trunk's own surface (`recon.posture.fit._on_trunk`)."""
    body, secs = _trunk_and_arm(offset)
    assert _on_trunk("forearm_l", secs, body, FitParams()) is on
    assert _on_trunk("chest", secs, body, FitParams()) is False


def test_points_on_another_sections_surface_are_shared():
    """`recon.posture.reach._shared_fraction`: a limb explains points no other section explains; points of
    the chest's surface under a forearm laid on it are shared, points around a free forearm are not."""
    from bodyscan.recon.posture.reach import _shared_fraction

    body, secs = _trunk_and_arm(0.0)
    on_chest = secs["chest"].surface_points(48, 20)
    on_chest = on_chest[np.abs(on_chest[:, 1]) < 0.05]          # the strip under the forearm
    free = {**secs, "forearm_l": secs["forearm_l"].replace(start=secs["forearm_l"].start + [0.3, 0, 0],
                                                           end=secs["forearm_l"].end + [0.3, 0, 0])}
    own = free["forearm_l"].surface_points(24, 12)
    assert _shared_fraction(on_chest, secs, "forearm_l", 0.02) > 0.9
    assert _shared_fraction(own, free, "forearm_l", 0.02) == 0.0
    assert _shared_fraction(own[:0], free, "forearm_l", 0.02) == 0.0


@pytest.mark.parametrize("name", ["walking", pytest.param("standing", marks=pytest.mark.xfail(
    strict=False, reason="issue 16, open: the size read from standing's cut trunk hangs on the scan's "
    "last bits: right on the CPUs of earlier sessions and with 1 um of noise (8 of 8 seeds), 1.28 m "
    "(legs not listed) on an AMD EPYC")), "t_pose", "arms_forward"])
def test_cut_lower_legs_are_listed_and_the_rest_is_near_the_truth(name):
    """Both lower legs cut from the scan: the body is sized from its trunk (crown to crotch: the leg
    chains measure 0.55-0.73 of it, `recon.posture.match.size_ratios`), the lower legs are listed (walking:
    one was placed across to the other thigh's stump), front and back come from the head and chest
    (`recon.posture.joints._trunk_vote`). Before: walking sized 1.22 m (true 1.71), median 11.9 / max 44.8
    cm; standing, t_pose, arms_forward flipped front to back (wrists 52-145 cm off)."""
    cut = ("lower_leg_l", "lower_leg_r")
    fit, err = _fit_cut(name, cut)
    assert set(fit.unfitted) == set(cut), f"cut {cut}, listed {fit.unfitted}"
    assert np.median(list(err.values())) <= 0.05
    worst = max(err, key=err.get)
    assert err[worst] <= 0.15, f"{worst} {100 * err[worst]:.1f} cm off"


@pytest.mark.parametrize("name", ["standing", "t_pose", "arms_forward"])
def test_one_cut_lower_leg_is_listed_and_the_rest_is_near_the_truth(name):
    """One lower leg cut: listed, the rest near the truth (standing was flipped front to back by the
    missing lower leg's knee "bend": wrists 69 cm off)."""
    cut = ("lower_leg_l",)
    fit, err = _fit_cut(name, cut)
    assert set(fit.unfitted) == set(cut), f"cut {cut}, listed {fit.unfitted}"
    worst = max(err, key=err.get)
    assert err[worst] <= 0.10, f"{worst} {100 * err[worst]:.1f} cm off"


def _head_and_chest(nose: bool):
    """Points on a head (ellipsoid-like column, radii 0.075 x 0.095 m) and a chest column, both
    along +z, each with a bump in front (-y: a nose, a chest) when ``nose``; their sections."""
    ang = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    pts = []
    secs = {}
    for name, z0, L, a, b in (("chest", 1.1, 0.35, 0.16, 0.10), ("head", 1.47, 0.22, 0.075, 0.095)):
        A, Z = np.meshgrid(ang, np.arange(z0, z0 + L, 0.01))
        x, y = a * np.cos(A.ravel()), b * np.sin(A.ravel())
        if nose:
            front = np.clip(-np.sin(A.ravel()), 0, None) ** 8     # a bump towards -y
            y = y - 0.03 * front
        pts.append(np.column_stack([x, y, Z.ravel()]))
        secs[name] = SectionShape(name, [0, 0, z0], [0, 0, z0 + L], [a, b], [1.0, 0, 0])
    return np.vstack(pts), secs


@pytest.mark.parametrize("turn", [0.0, 180.0])
def test_the_trunk_says_where_the_front_is(turn):
    """`recon.posture.joints.front_sign` without legs: the head and chest stick out in front (`_trunk_vote`);
    the body faces -y, and turned 180 degrees +y; symmetric sections give no vote."""
    from bodyscan.recon.posture.joints import _trunk_vote, front_sign

    pts, secs = _head_and_chest(nose=True)
    R = rot_z(turn)
    pts = pts @ R.T
    secs = {k: SectionShape(k, R @ v.start, R @ v.end, v.radii, R @ v.frame_x) for k, v in secs.items()}
    frame = np.eye(3)    # provisional front -y, back +y
    assert front_sign(pts, secs, frame) == (1.0 if turn == 0.0 else -1.0)
    assert abs(_trunk_vote(pts, secs, frame[:, 1])) > 1.0
    flat, flat_secs = _head_and_chest(nose=False)
    assert abs(_trunk_vote(flat, flat_secs, frame[:, 1])) < 0.1


def test_one_cut_lower_leg_of_a_walker_is_listed():
    """walking without its left lower leg: the coarse lower leg (in empty voxels) was fitted across
    onto the right knee and kept as a leg seen on its surface, ankle_l 73.6 cm off, nothing listed;
    a leg chain running across the body is listed (`recon.posture.fit._leg_across`)."""
    cut = ("lower_leg_l",)
    fit, err = _fit_cut("walking", cut)
    assert set(cut) <= set(fit.unfitted)
    assert max(err.values()) <= 0.15


@pytest.mark.parametrize("foot_x, across", [(0.10, False), (0.0, False), (-0.05, False), (-0.25, True)])
def test_a_leg_chain_running_across_the_body_is_found(foot_x, across):
    """`recon.posture.fit._leg_across`: hips at x = +-0.09 m, the left thigh straight down 0.42 m, the
    left sole at ``foot_x``: a chain ending 0.34 m toward the other hip over 0.92 m of length is more
    than `match_max_adduction` (0.25) across; a leg held in or out a little is not."""
    from bodyscan.recon.posture.fit import _leg_across

    def col(name, a, b):
        return SectionShape(name, np.array(a, float), np.array(b, float), [0.06, 0.06], [1.0, 0, 0])

    secs = {"thigh_l": col("thigh_l", [0.09, 0, 0.9], [0.09, 0, 0.48]),
            "thigh_r": col("thigh_r", [-0.09, 0, 0.9], [-0.09, 0, 0.48]),
            "lower_leg_l": col("lower_leg_l", [0.09, 0, 0.48], [foot_x, 0, 0.05])}
    assert _leg_across("lower_leg_l", secs, 0.25) is across
    # mirrored: the right leg's chain toward +x
    mirrored = {("thigh_r" if k == "thigh_l" else "thigh_l" if k == "thigh_r" else "lower_leg_r"):
                v.replace(start=v.start * [-1, 1, 1], end=v.end * [-1, 1, 1]) for k, v in secs.items()}
    assert _leg_across("lower_leg_r", mirrored, 0.25) is across
    assert _leg_across("lower_leg_r", secs, 0.25) is False   # no right lower leg: nothing to say


@pytest.mark.parametrize("hip, knee, up", [(0, 0, False), (100, 75, False), (85, 0, False), (110, 55, False),
                                           (100, 0, True), (120, 20, True), (150, 40, True)])
def test_a_lower_leg_above_the_horizontal_is_found(hip, knee, up):
    """`recon.posture.fit._shank_up`: a sagittal leg with the hip flexed ``hip`` and the knee bent
    ``knee`` degrees points its shank ``hip - knee`` degrees from straight down, the ankle above the
    knee beyond 90; the same with the torso's frame turned about the vertical."""
    from bodyscan.recon.posture.fit import _shank_up

    a = np.radians(hip - knee)
    d = np.array([0.0, -np.sin(a), -np.cos(a)])          # the subject faces -y
    assert _shank_up(d, np.eye(3)) is up
    c, s = np.cos(np.radians(70)), np.sin(np.radians(70))
    turn = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    assert _shank_up(turn @ d, turn) is up
