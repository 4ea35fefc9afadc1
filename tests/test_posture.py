"""Posture estimation: analytic fits, bad input, and the shipped postures against ground truth."""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from bodyscan.benchmarks.fit_table import rot_z as _rz
from bodyscan.benchmarks.fit_table import score_fit as _scores
from bodyscan.recon import FitParams, ReconError, estimate_posture, fit_section
from bodyscan.recon.model import SECTIONS, SectionShape


# -- analytic ------------------------------------------------------------------------------------
def test_fit_section_recovers_a_cylinder_exactly():
    rng = np.random.default_rng(1)
    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    start = np.array([0.1, 0.2, 0.3])
    truth = SectionShape("thigh_l", start, start + 0.5 * axis, [0.07, 0.07], [1.0, 0, 0], closed=(False, False))
    t = rng.uniform(0, 2 * np.pi, 3000)
    h = rng.uniform(0, 0.5, 3000)
    fx, fy, z = truth.frame
    pts = start + 0.07 * (np.cos(t)[:, None] * fx + np.sin(t)[:, None] * fy) + h[:, None] * z
    tilt = np.array([0.3, -0.2, 1.0]) + [0.08, 0.05, 0.0]
    guess = SectionShape("thigh_l", start + [0.02, -0.01, 0], start + [0.02, -0.01, 0] + 0.5 * tilt / np.linalg.norm(tilt),
                         [0.05, 0.05], [1.0, 0, 0], closed=(False, False))
    fit, rms = fit_section(pts, guess, loss="linear", iterations=6, free_end=False)
    assert abs(fit.radii[0] - 0.07) < 1e-4
    assert np.degrees(np.arccos(min(1.0, abs(fit.axis @ axis)))) < 0.1
    # the fitted axis passes through the true one: distance of the true start from the fitted line
    rel = start - fit.start
    assert np.linalg.norm(rel - (rel @ fit.axis) * fit.axis) < 1e-3
    assert rms < 1e-4


def test_fit_section_finds_a_closed_end_and_keeps_an_open_one():
    start, axis = np.zeros(3), np.array([0, 0, 1.0])
    truth = SectionShape("forearm_l", start, start + 0.3 * axis, [0.04, 0.04], [1.0, 0, 0])
    pts = truth.surface_points(48, 40)
    guess = truth.replace(end=start + 0.25 * axis)
    fit, _ = fit_section(pts, guess, iterations=2)
    assert fit.closed[1] and abs(fit.length - 0.3) < 0.01
    side = pts[(pts[:, 2] >= 0) & (pts[:, 2] <= 0.3)]  # no cap: the end stays open, length kept
    fit2, _ = fit_section(side, guess, iterations=2)
    assert not fit2.closed[1] and abs(fit2.length - 0.25) < 1e-9


@pytest.mark.parametrize("radii", [(0.09, 0.09), (0.08, 0.10)])
def test_fit_section_closes_an_end_seen_only_on_the_flanks_of_its_cap(radii):
    # a head seen by cameras below its crown (perspective heads): the cap shows no point near the
    # axis, only its flanks (here from 45 degrees off the pole: 0.71 of the way out and more)
    start, axis = np.zeros(3), np.array([0, 0, 1.0])
    cap = min(radii)     # the model's cap: half an ellipsoid, the column's semi-axes, this height
    truth = SectionShape("head", start, start + 0.15 * axis, radii, [1.0, 0, 0], caps=[cap, cap])
    pts = truth.surface_points(64, 60)
    e = np.hypot(pts[:, 0] / radii[0], pts[:, 1] / radii[1])
    flanks = pts[(pts[:, 2] >= 0) & ((pts[:, 2] <= 0.15) | (e >= np.sin(np.radians(45))))]
    guess = truth.replace(end=start + 0.12 * axis)
    fit, _ = fit_section(flanks, guess, iterations=2)
    assert fit.closed[1]
    assert abs(fit.length - 0.15) < 0.005     # the crown within 5 mm
    # the paper's rule alone (points within 0.6 radii of the axis) finds nothing there
    assert (np.hypot(flanks[:, 0], flanks[:, 1]) >= 0.6 * np.mean(radii)).all()


# -- bad input -------------------------------------------------------------------------------------
def _sphere(n=5000, r=0.3):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(n, 3))
    return r * v / np.linalg.norm(v, axis=1, keepdims=True) + [0, 0, 1.0]


@pytest.mark.parametrize("points, message", [
    (np.zeros((50, 3)), "only 50 points"),
    (np.where(np.arange(3000)[:, None] == 5, np.nan, _sphere(3000)), "NaN"),
    (_sphere() * 1000, "millimetres"),
])
def test_bad_points_are_rejected_in_one_line(points, message):
    with pytest.raises(ReconError, match=message) as err:
        estimate_posture(points)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("make", [
    lambda: _sphere(),
    lambda: np.random.default_rng(0).uniform([-0.4, -0.3, 0], [0.4, 0.3, 1.2], (8000, 3)) * [1, 1, 1],
], ids=["sphere", "box"])
def test_a_non_person_is_not_fitted_silently(make):
    with pytest.raises(ReconError, match="does not look like a human body"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            estimate_posture(make())


def test_params_from_strings():
    p = FitParams.from_strings(["voxel_max=0.03", "match_beam=4"])
    assert p.voxel_max == 0.03 and p.match_beam == 4 and p.contour_weight == 2.0
    with pytest.raises(ReconError, match="unknown posture parameter 'nope'"):
        FitParams.from_strings(["nope=1"])
    with pytest.raises(ReconError, match="name=value"):
        FitParams.from_strings(["voxel_max"])
    with pytest.raises(ReconError, match="voxel_max=.big.: expected a number"):
        FitParams.from_strings(["voxel_max=big"])


def test_knee_closes_the_leg_triangle():
    """The knee from hip, ankle and the bend of the axes: exact on a bent leg, whichever way the
    hinge turns, and on a straight leg at the thigh's share of hip to ankle."""
    from bodyscan.recon.posture.joints import knee_between

    back, left = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    hip = np.array([0.1, 0.0, 0.9])
    for bend, spread in ((25.0, 0.0), (90.0, 0.0), (100.0, 20.0)):
        # thigh forward-down by `bend` from the vertical, turned `spread` degrees outwards
        b, s = np.radians(bend), np.radians(spread)
        d1 = np.array([np.sin(b) * np.sin(s), -np.sin(b) * np.cos(s), -np.cos(b)])
        d2 = np.array([0.0, 0.0, -1.0])
        knee = hip + 0.40 * d1
        ankle = knee + 0.45 * d2
        got = knee_between(hip, ankle, d1, d2, back, left, 0.40 / 0.85)
        # a thigh spread outwards: the body's left-right axis pulls the hinge a little (2 cm at 20 deg)
        assert np.linalg.norm(got - knee) < (0.025 if spread else 1e-9)
    down = np.array([0.0, 0.0, -1.0])
    straight = knee_between(hip, hip + 0.85 * down, down, down, back, left, 0.4)
    assert np.allclose(straight, hip - [0, 0, 0.34])


def test_a_deeply_bent_knee_lies_on_the_lower_legs_axis():
    """`bent_knee`: a squat's leg (bent 118 degrees). Exact axes and ankle give the knee exactly. A
    thigh fitted from above only (its column 4 cm high at the hip, drooping 10 degrees towards the
    knee, as on the squat scans: bend 108 degrees) moves the triangle's knee (`knee_between`) 6.3 cm,
    the knee on the lower leg's axis, between where the thigh's axis crosses it and a shank above the
    ankle, 1.6 cm; `place_seams` uses it beyond `KNEE_MEET_DEG`."""
    from bodyscan.recon.posture.bodymodel import standard_body
    from bodyscan.recon.geometry import unit
    from bodyscan.recon.posture.joints import KNEE_MEET_DEG, bent_knee, knee_between, place_seams

    x = np.array([1.0, 0.0, 0.0])
    hip, knee, ankle = np.array([0.12, 0.0, 0.47]), np.array([0.17, -0.40, 0.44]), np.array([0.26, -0.15, 0.08])
    shank = float(np.linalg.norm(ankle - knee))
    shin = SectionShape("lower_leg_l", knee, ankle, [0.05, 0.05], x)
    thigh = SectionShape("thigh_l", hip, knee, [0.075, 0.075], x)
    assert np.degrees(np.arccos(thigh.axis @ shin.axis)) > KNEE_MEET_DEG
    assert np.allclose(bent_knee(thigh, shin, ankle, shank), knee, atol=1e-9)
    assert np.allclose(bent_knee(thigh, shin, None, shank), knee, atol=1e-9)
    # the thigh seen from above: its column starts 4 cm high and droops 10 degrees more to the knee
    start = hip + [0.0, 0.0, 0.04]
    d = unit(knee - hip)
    side = unit(np.cross(d, np.cross([0.0, 0.0, 1.0], d)))
    droop = np.cos(np.radians(10.0)) * d - np.sin(np.radians(10.0)) * side
    high = SectionShape("thigh_l", start, start + 0.40 * droop, [0.075, 0.075], x)
    got = bent_knee(high, shin, ankle, shank)
    left, back = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    tri = knee_between(hip, ankle, high.axis, shin.axis, back, left, 0.485)
    assert np.linalg.norm(tri - knee) > 0.05
    assert np.linalg.norm(got - knee) < 0.4 * np.linalg.norm(tri - knee)
    assert abs(np.linalg.norm(np.cross(got - knee, shin.axis))) < 1e-9      # on the lower leg's axis
    # place_seams takes it for a leg bent beyond KNEE_MEET_DEG
    body = standard_body(1.75)
    secs = {"waist": SectionShape("waist", [0, 0.0, 0.5], [0, 0.0, 0.85], [0.15, 0.11], x),
            "thigh_l": high.replace(end=got), "lower_leg_l": shin.replace(start=got)}
    j = place_seams(secs, body, back)
    assert np.allclose(j["knee_l"], bent_knee(secs["thigh_l"], secs["lower_leg_l"], None, shank))


@pytest.mark.parametrize("turn", [0.0, 40.0])
def test_joints_sit_where_the_offset_table_puts_them_in_their_sections_frame(turn):
    """`offset_joints` moves each joint from its section's end or axis by stature x (a + b x (stature
    / STATURE - 1)) along (out, back, along) of its section: a standing body 2.1 m tall with
    known sections, every joint placed against positions worked out by hand (left is +x, the back
    +y, the thighs and lower legs point down, the left forearm straight back: its offset towards the
    back has no direction across it and is dropped). The scene turned about the vertical and tilted
    gives the same joints, turned."""
    from bodyscan.recon.posture.bodymodel import STATURE, standard_body
    from bodyscan.recon.posture.joints import place_joints
    from bodyscan.recon.geometry import rotvec

    H = 2.1
    g = H / STATURE - 1.0
    table = {"pelvis": ((0.3, 0.01, 0.02), (0.0, 0.0, 0.05)), "hip": ((0.01, 0.02, 0.03), (0.05, 0.0, -0.1)),
             "knee": ((0.0, 0.01, -0.02), (0.0, 0.0, 0.1)), "wrist": ((0.01, 0.02, 0.03), (0.0, 0.0, 0.0))}
    x, y, z = np.eye(3)
    secs = {"waist": SectionShape("waist", [0, 0, 1.0], [0, 0, 1.36], [0.15, 0.11], x),
            "chest": SectionShape("chest", [0, 0, 1.36], [0, 0, 1.6], [0.17, 0.12], x),
            "upper_arm_l": SectionShape("upper_arm_l", [0.2, 0, 1.5], [0.2, 0, 1.2], [0.045, 0.045], x),
            "forearm_l": SectionShape("forearm_l", [0.2, 0, 1.2], [0.2, 0.3, 1.2], [0.04, 0.04], x,
                                      closed=(True, False))}
    for side, sx in (("l", 0.1), ("r", -0.1)):
        secs[f"thigh_{side}"] = SectionShape(f"thigh_{side}", [sx, 0, 1.0], [sx, 0, 0.55], [0.07, 0.07], x)
        secs[f"lower_leg_{side}"] = SectionShape(f"lower_leg_{side}", [sx, 0, 0.55], [sx, 0, 0.1], [0.05, 0.05], x)
    body = standard_body(H)
    want = {"pelvis": [0, 0, 1.0] + H * np.array([0.0, 0.01, 0.02 + 0.05 * g]),   # spine: no out
            "chest": np.array([0, 0, 1.36]), "neck": np.array([0, 0, 1.6]),
            "elbow_l": np.array([0.2, 0, 1.2]),
            "wrist_l": [0.2, body.length("forearm"), 1.2] + H * np.array([0.01, 0.03, 0.0])}
    for side, sx, out in (("l", 0.1, x), ("r", -0.1, -x)):
        want[f"hip_{side}"] = [sx, 0, 1.0] + H * ((0.01 + 0.05 * g) * out + 0.02 * y + (0.03 - 0.1 * g) * z)
        want[f"knee_{side}"] = [sx, 0, 0.55] + H * (0.01 * y - (-0.02 + 0.1 * g) * z)
        want[f"ankle_{side}"] = np.array([sx, 0, 0.55 - body.length("lower_leg")])
    R = rotvec(np.radians(turn) * z) @ rotvec(np.radians(turn / 4) * x)
    turned = {k: v.moved(R, np.zeros(3)) for k, v in secs.items()}
    got = place_joints(turned, body, R @ y, offsets=table)
    assert set(got) == set(want) | {"shoulder_l"}
    for k, v in want.items():
        assert np.allclose(got[k], R @ v, atol=1e-9), k
    raw = place_joints(turned, body, R @ y, offsets={})
    assert np.allclose(raw["pelvis"], R @ [0, 0, 1.0]) and np.allclose(raw["knee_r"], R @ [-0.1, 0, 0.55])


@pytest.mark.parametrize("stretch", [1.0, 1.2, 0.9])
def test_a_seen_hand_puts_its_wrist_between_fingertips_and_model_forearm(stretch):
    """An arm whose fingertips are seen (its forearm section closed at them): the wrist lies
    halfway between a hand length before the fingertips and a model forearm past the elbow. On the
    model's own arm it is exact. On an arm ``stretch`` times the model's (forearm and hand alike)
    the two estimates err on opposite sides, by the hand's and the forearm's stretch, and the
    wrist is off by only half their difference."""
    from bodyscan.recon.posture.bodymodel import standard_body
    from bodyscan.recon.posture.joints import place_joints

    body = standard_body(1.75)
    fore, hand = body.length("forearm"), body.length("hand")
    cap = 0.02
    reach = stretch * (fore + hand)                 # elbow to fingertips, along +y
    secs = {"forearm_l": SectionShape("forearm_l", [0.2, 0, 1.2], [0.2, reach - cap, 1.2], [0.04, 0.04],
                                      [1.0, 0, 0], closed=(True, True), caps=(0.04, cap))}
    wrist = place_joints(secs, body, np.array([0, 1.0, 0]), offsets={})["wrist_l"]
    off = np.linalg.norm(wrist - [0.2, stretch * fore, 1.2])
    assert off == pytest.approx(0.5 * abs(stretch - 1) * abs(fore - hand), abs=1e-12)
    if stretch != 1.0:
        assert off < 0.3 * abs(stretch - 1) * min(fore, hand)


def test_crown_anchor_keeps_a_level_thigh_on_its_line():
    """Sliding the model along the torso axis to hang from the crown moves a level thigh (seated,
    knee raised) only along itself: moved across itself it would leave its points."""
    from bodyscan.recon.posture.bodymodel import standard_body
    from bodyscan.recon.posture.adjust import anchor_on_head_top

    x = [1.0, 0.0, 0.0]
    secs = {
        "waist": SectionShape("waist", [0, 0, 1.0], [0, 0, 1.36], [0.15, 0.11], x),
        "head": SectionShape("head", [0, 0, 1.50], [0, 0, 1.70], [0.08, 0.09], x),
        "thigh_l": SectionShape("thigh_l", [0.1, 0, 1.0], [0.1, -0.4, 1.0], [0.07, 0.07], x),
        "lower_leg_l": SectionShape("lower_leg_l", [0.1, -0.4, 1.0], [0.1, -0.4, 0.55], [0.05, 0.05], x),
    }
    out = anchor_on_head_top(secs, standard_body(1.75), FitParams())
    move = out["waist"].start - secs["waist"].start
    assert abs(move[2]) > 0.01                      # the model did slide
    assert np.allclose(out["head"].start - secs["head"].start, move)
    assert np.allclose(out["thigh_l"].start, secs["thigh_l"].start)    # level: stays on its line
    assert np.allclose(out["lower_leg_l"].start - secs["lower_leg_l"].start, move)  # along itself


def test_doubted_forearm_is_found_again_on_the_points():
    """A forearm held across the chest, matched pointing down into the belly (its fit doubted: poor
    cover, 3 cm rms), is searched again from the elbow on the points: the new axis follows the true
    forearm; a forearm the check does not doubt is left alone."""
    from bodyscan.recon.posture.adjust import research_distal
    from bodyscan.recon.posture.bodymodel import standard_body

    body = standard_body(1.75)
    x = [1.0, 0.0, 0.0]
    elbow = np.array([-0.2, -0.17, 1.2])
    true_dir = np.array([1.0, 0.0, 0.0])
    L = body.section_length("forearm_r")
    truth = {
        "chest": SectionShape("chest", [0, 0, 1.0], [0, 0, 1.5], [0.15, 0.11], x),
        "upper_arm_r": SectionShape("upper_arm_r", [-0.2, -0.02, 1.47], elbow, [0.045, 0.045], x),
        "forearm_r": SectionShape("forearm_r", elbow, elbow + L * true_dir, [0.035, 0.035], [0, 0, 1.0]),
    }
    pts = np.concatenate([v.surface_points(36, 40) for v in truth.values()])
    wrong = truth["forearm_r"].replace(end=elbow + L * np.array([0.6, 0.1, -0.8]) / np.linalg.norm([0.6, 0.1, -0.8]))
    secs = {**truth, "forearm_r": wrong}
    resid = {"chest": 0.005, "upper_arm_r": 0.005, "forearm_r": 0.03}
    counts = {k: 500 for k in secs}

    out, res, _, replaced = research_distal(pts, secs, resid, counts, body, FitParams())
    assert replaced == {"forearm_r"}
    assert np.degrees(np.arccos(out["forearm_r"].axis @ true_dir)) < 10
    assert res["forearm_r"] < 0.01

    kept, _, _, none = research_distal(pts, truth, {**resid, "forearm_r": 0.005}, counts, body, FitParams())
    assert none == set() and kept["forearm_r"] is truth["forearm_r"]


def test_lower_leg_left_off_its_points_is_found_again():
    """Legs seen from their outer sides only (a body turned to the cameras): a lower leg matched
    across to the other ankle holds no points of its own; searched again from its knee on the
    points, it follows its shin. The other lower leg, on its points, is left alone."""
    from bodyscan.recon.posture.adjust import research_distal
    from bodyscan.recon.posture.bodymodel import standard_body

    body = standard_body(1.75)
    y = [0.0, 1.0, 0.0]
    truth = {"waist": SectionShape("waist", [0, 0, 0.9], [0, 0, 1.15], [0.15, 0.11], [1.0, 0, 0])}
    for side, x in (("l", 0.1), ("r", -0.1)):
        truth["thigh_" + side] = SectionShape("thigh_" + side, [x, 0, 0.9], [x, 0, 0.48], [0.07, 0.07], y)
        truth["lower_leg_" + side] = SectionShape("lower_leg_" + side, [x, 0, 0.48], [x, 0, 0.08],
                                                  [0.05, 0.05], y)
    pts = np.concatenate([v.surface_points(36, 40) for v in truth.values()])
    pts = pts[(pts[:, 2] > 0.9) | (np.abs(pts[:, 0]) > 0.1)]      # the legs' outer halves only
    across = np.array([0.1, 0.0, 0.08]) - [-0.1, 0.0, 0.48]
    wrong = truth["lower_leg_r"].replace(end=truth["lower_leg_r"].start + 0.4 * across / np.linalg.norm(across))
    secs = {**truth, "lower_leg_r": wrong}
    resid = {**{k: 0.005 for k in secs}, "lower_leg_r": np.nan}
    counts = {**{k: 500 for k in secs}, "lower_leg_r": 5}

    out, res, n, replaced = research_distal(pts, secs, resid, counts, body, FitParams())
    assert replaced == {"lower_leg_r"}
    assert np.degrees(np.arccos(out["lower_leg_r"].axis @ [0.0, 0.0, -1.0])) < 10
    assert res["lower_leg_r"] < 0.01 and n["lower_leg_r"] >= FitParams().fit_min_points
    assert out["lower_leg_l"] is truth["lower_leg_l"]


# -- shipped postures ------------------------------------------------------------------------------
def _library():
    """The shipped bodies: tracked in the repository, so one missing (or a stage that does not
    import) is a failure, not a skip."""
    from bodyscan import poses

    names = poses.list_bodies()
    assert names, "no shipped bodies"
    return names


@pytest.fixture(scope="module")
def standing_scans():
    _library()
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body("standing")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scans = {k: simulator.scan(body, simulator.preset("paper", k=k)).points for k in (1, 3)}
    return body.joint_dict(), scans


@pytest.fixture(scope="module")
def standing_fits(standing_scans):
    joints, scans = standing_scans
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out["k1"] = (estimate_posture(scans[1]), joints)
        R = _rz(137)
        out["k1_rot137"] = (estimate_posture(scans[1] @ R.T), {k: R @ v for k, v in joints.items()})
        out["k3"] = (estimate_posture(scans[3]), joints)
    return out


@pytest.mark.parametrize("case", ["k1", "k1_rot137", "k3"])
def test_standing_fit_is_near_the_true_joints(standing_fits, case):
    """Regression level reached today (the issue's targets are in the xfail test below)."""
    fit, joints = standing_fits[case]
    assert set(fit.sections) == set(SECTIONS) and fit.unfitted == ()
    err, ang = _scores(fit, joints)
    assert np.median(list(err.values())) < 0.08
    # left and right are told apart from the shape, whatever way the subject faces
    assert err["shoulder_l"] < 0.15 and err["hip_l"] < 0.15 and err["knee_r"] < 0.15
    assert sorted(ang.values())[-3] < 30  # most limb axes follow their bones
    assert set(fit.times) == {"voxelize", "match", "fine"}
    assert fit.coarse is not None and set(fit.coarse.sections) == set(SECTIONS)


@pytest.mark.parametrize("case", ["k1", "k1_rot137", "k3"])
def test_standing_fit_meets_the_issue_targets(standing_fits, case):
    fit, joints = standing_fits[case]
    err, ang = _scores(fit, joints)
    assert np.median(list(err.values())) <= 0.04
    assert max(err.values()) <= 0.10
    assert max(ang.values()) <= 20


@pytest.mark.parametrize("name", ["seated", "child_standing"])
def test_other_postures_and_sizes(name):
    """A seated adult and a child: regression level reached today (median 3-6 cm, worst 5-9 cm)."""
    names = _library()
    assert name in names, f"{name} not shipped"
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(simulator.scan(body, simulator.preset("paper")).points)
    err, ang = _scores(fit, body.joint_dict())
    assert len(fit.unfitted) <= 2   # a forearm lying on a thigh may be listed, not the body
    assert np.median(list(err.values())) < 0.07
    assert max(err.values()) < 0.15
    assert max(ang.values()) < 25


def test_seated_scanned_at_2mm_is_fitted():
    """The 2 mm scanner sees a seated person's thighs from above only (no inside voxels in them): the
    legs are placed on their seen surface, not listed, and the cloud is not refused."""
    names = _library()
    assert "seated" in names, "seated not shipped"
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body("seated")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(simulator.scan(body, simulator.preset("scanner")).points)
    err, ang = _scores(fit, body.joint_dict())
    assert {"thigh_l", "thigh_r", "lower_leg_l", "lower_leg_r"} <= set(fit.sections)
    assert len(fit.unfitted) <= 2   # a forearm lying on a thigh may be listed
    assert np.median(list(err.values())) < 0.07
    assert max(err.values()) < 0.15
    assert max(ang.values()) < 25


def _scan_and_fit(name, k=1):
    names = _library()
    assert name in names, f"{name} not shipped"
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_posture(simulator.scan(body, simulator.preset("paper", k=k)).points)
    return fit, body.joint_dict()


@pytest.mark.parametrize("name", ["t_pose", "leaning", "child_standing", "walking", "knee_raised", "tall_walking"])
def test_more_postures_meet_the_issue_targets(name):
    """Arms out, a leaning trunk, a child, a stride and a knee raised at k = 1: the issue's targets,
    every section fitted (walking: the rear leg's knee, bent 25 degrees, was 10.6 cm off where its
    thigh and shin axes met; knee_raised: the level thigh, seen from the front and above, holds no
    inside voxels and was listed unfitted; tall_walking, 1.97 m: its first match, 1.72 m, sat 11 cm
    high, its legs measured 2.2 m from there; sized from crown to sole and hung from the crown,
    worst joint 16.9 -> 8.9 cm)."""
    fit, joints = _scan_and_fit(name)
    assert fit.unfitted == ()
    err, ang = _scores(fit, joints)
    assert np.median(list(err.values())) <= 0.04
    assert max(err.values()) <= 0.10
    assert max(ang.values()) <= 20


@pytest.mark.parametrize("name", ["hands_on_hips", "arms_close"])
def test_a_hand_resting_on_the_body_keeps_its_wrist(name):
    """Fingertips resting on the hips, or hands against the thighs: the hand's points go to the
    waist or thigh, yet each wrist lies within 6 cm of the truth (measured 3.5-4.9 cm; the
    fitted forearm's end minus a hand length falls 6.5-11.4 cm short)."""
    fit, joints = _scan_and_fit(name)
    for side in "lr":
        assert np.linalg.norm(fit.joints[f"wrist_{side}"] - joints[f"wrist_{side}"]) <= 0.06


@pytest.mark.parametrize("name, k", [("standing", 1), ("standing", 3), ("arms_raised", 1), ("arms_raised", 3)])
def test_neck_shoulders_and_elbows_follow_the_arms_posture(name, k):
    """Arms hanging or raised: the neck within 3 cm (centred between its sides; measured 1.4-2.9,
    was 1.8-5.6), shoulders and elbows within 5 cm (measured at most 4.7, was up to 6.9: the torso
    sliding to the crown carried the arms off their points, and a raised arm lifts its shoulder)."""
    fit, joints = _scan_and_fit(name, k=k)
    err, _ = _scores(fit, joints)
    assert err["neck"] <= 0.03
    for j in ("shoulder_l", "shoulder_r", "elbow_l", "elbow_r"):
        assert err[j] <= 0.05, j


@pytest.mark.parametrize("name", ["t_pose", "heavy_a_pose"])
def test_arms_are_listed_rather_than_placed_wrongly_at_k3(name):
    """At k = 3 the arms are half seen; an arm that cannot be placed with confidence is listed
    unfitted, and every section that is fitted follows its bone (heavy_a_pose: its torso tilted
    forward, an upper arm was fitted pointing backwards-up onto the shoulder, 127 degrees off its
    bone: an elbow raised behind the shoulder is not anatomy, the arm is listed)."""
    fit, joints = _scan_and_fit(name, k=3)
    assert len(fit.unfitted) <= 4 and {"waist", "chest", "head", "thigh_l", "thigh_r"} <= set(fit.sections)
    err, ang = _scores(fit, joints)
    assert max(ang.values()) <= 20
    assert max(err.values()) <= 0.15
    assert np.median(list(err.values())) <= 0.06


def test_fit_is_the_same_when_the_scan_turns_about_the_vertical(standing_fits, standing_scans):
    """The issue's "rotate a scan about the vertical axis: same fit": the fit is made in a facing
    read from the cloud's own shape, so a scan turned by any angle (and moved sideways) gets the
    same fit, turned and moved, to rounding."""
    a, _ = standing_fits["k1"]
    _, scans = standing_scans
    rng = np.random.default_rng(7)
    for deg in rng.uniform(0, 360, 2):
        R, t = _rz(deg), np.array([0.4, -0.25, 0.0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            b = estimate_posture(scans[1] @ R.T + t)
        assert set(b.joints) == set(a.joints) and b.unfitted == a.unfitted
        moved = max(np.linalg.norm(R @ a.joints[k] + t - b.joints[k]) for k in a.joints)
        assert moved < 1e-6, (deg, moved)
        for name, s in a.sections.items():
            assert np.allclose(R @ s.start + t, b.sections[name].start, atol=1e-6)
            assert np.allclose(R @ s.axis, b.sections[name].axis, atol=1e-6)


def test_facing_frame_turns_the_shoulders_across_and_the_front_to_minus_y():
    """An analytic body: a torso column 0.40 m wide, 0.24 m deep, shoulders a 0.50 m wide slab,
    and a block in front (feet, arms forward) at +x turned by 40 degrees: the frame turns the wide
    direction to x and the front to -y, from any starting turn; R is a rotation about +z."""
    from bodyscan.recon.posture.fit import facing_frame

    def box(x, y, z, n):   # a grid filling [x0, x1] x [y0, y1] x [z0, z1], symmetric about its centre
        return np.stack(np.meshgrid(*(np.linspace(*r, m) for r, m in zip((x, y, z), n))), -1).reshape(-1, 3)

    g = box((-0.20, 0.20), (-0.12, 0.12), (0.0, 1.8), (21, 13, 91))
    shoulders = box((-0.25, 0.25), (-0.06, 0.06), (1.30, 1.45), (51, 13, 8))
    front = box((-0.10, 0.10), (-0.40, -0.14), (0.0, 0.10), (11, 14, 6))
    body = np.concatenate([g, shoulders, front])
    for deg in (0.0, 40.0, 200.0, 305.0):
        R0, t = _rz(deg), np.array([1.0, 2.0, 0.0])
        R, c = facing_frame(body @ R0.T + t)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1) and np.allclose(R[2], [0, 0, 1])
        turned = (body @ R0.T + t - c) @ R.T
        assert np.allclose(turned, body - [*body[:, :2].mean(axis=0), 0.0], atol=1e-9)
    with pytest.raises(ReconError, match="fit_facing_band"):
        facing_frame(body, 0.9, 0.8)


def _column_points(a, b, r, step=0.012):
    """Points on the side of a round column of radius ``r`` from ``a`` to ``b`` (3,), metres."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    u = np.cross(d, [1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.cross(d, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    t, h = np.meshgrid(np.linspace(0, 2 * np.pi, int(2 * np.pi * r / step), endpoint=False),
                       np.arange(0.0, np.linalg.norm(b - a), step))
    t, h = t.reshape(-1, 1), h.reshape(-1, 1)
    return a + h * d + r * (np.cos(t) * u + np.sin(t) * np.cross(d, u))


def _body_with_feet(front_foot: float, back_foot: float) -> np.ndarray:
    """An analytic body facing -y, left at +x: an elliptic trunk 0.34 m wide, 0.22 m deep, a head,
    arms hanging beside the trunk, legs from the hips to ankles 9 cm above the floor, the left ankle
    ``front_foot`` m in front (-y), the right ``back_foot`` m behind; under each ankle a foot 9 cm
    wide, its surface from the heel 5 cm behind the ankle to the toes 17 cm in front (top sloping
    from 7 cm at the heel to 2 cm at the toes, sides, heel and toe ends; no sole)."""
    t, h = np.meshgrid(np.linspace(0, 2 * np.pi, 90, endpoint=False), np.arange(0.90, 1.45, 0.012))
    parts = [np.column_stack([0.17 * np.cos(t).ravel(), 0.11 * np.sin(t).ravel(), h.ravel()]),
             _column_points((0, 0, 1.50), (0, 0, 1.74), 0.085)]
    g = np.arange(0.0, 1.0 + 1e-9, 0.05)
    x, y, z = (a.ravel() for a in np.meshgrid(np.linspace(-0.045, 0.045, 10), np.linspace(-0.17, 0.05, 23), g))
    top = 0.02 + 0.05 * (y + 0.17) / 0.22
    foot = np.concatenate([np.column_stack([x, y, top])[z == 0],                                  # top
                           np.column_stack([np.sign(x) * 0.045, y, z * top])[np.abs(x) > 0.04],   # sides
                           np.column_stack([x, y, z * top])[(np.abs(y + 0.17) < 1e-9) | (np.abs(y - 0.05) < 1e-9)]])
    for side, ay in ((1.0, -front_foot), (-1.0, back_foot)):
        parts += [_column_points((0.09 * side, 0.0, 0.90), (0.10 * side, ay, 0.09), 0.065),
                  foot + [0.10 * side, ay, 0.0],
                  _column_points((0.21 * side, 0.0, 1.40), (0.25 * side, 0.0, 0.80), 0.045)]
    return np.concatenate(parts)


@pytest.mark.parametrize("front_foot, back_foot", [(0.0, 0.0), (0.25, 0.25), (0.15, 0.40)])
def test_facing_frame_reads_the_front_from_the_feet(front_foot, back_foot):
    """The facing of an analytic body with feet, standing and in a stride, turned to any heading
    about the vertical and moved: across the shoulders comes to x and the front to -y (the feet
    point forward from their ankles: `feet_forward`). The stride with the trailing foot far behind
    (0.15 in front, 0.40 behind) turns the cloud's third moment round, which set the front before."""
    from bodyscan.recon.posture.fit import facing_frame, feet_forward

    body = _body_with_feet(front_foot, back_foot)
    assert feet_forward(body) @ [0.0, -1.0] > 0.03            # the feet point to -y, 3 cm or more
    for deg in (0.0, 35.0, 90.0, 160.0, 245.0, 310.0):
        R0 = _rz(deg)
        R, c = facing_frame(body @ R0.T + [0.6, -0.3, 0.0])
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1) and np.allclose(R[2], [0, 0, 1])
        turned = R @ R0                                       # the body's own frame to the facing's
        assert turned[0, 0] > np.cos(np.radians(5)), (deg, turned)   # left to +x, front to -y


def test_body_fit_moves_rigidly():
    """`BodyFit.moved`: joints and sections carried by p -> R p + t, lengths and radii kept."""
    from bodyscan.recon.model import BodyFit

    s = SectionShape("thigh_l", np.array([0.1, 0.0, 0.9]), np.array([0.1, -0.1, 0.5]), np.array([0.07, 0.07]),
                     np.array([1.0, 0.0, 0.0]))
    fit = BodyFit(sections={"thigh_l": s}, joints={"hip_l": s.start, "knee_l": s.end})
    R, t = _rz(63), np.array([0.3, -0.2, 0.1])
    m = fit.moved(R, t)
    assert np.allclose(m.joints["knee_l"], R @ s.end + t)
    ms = m.sections["thigh_l"]
    assert np.isclose(ms.length, s.length) and np.allclose(ms.radii, s.radii)
    assert np.allclose(ms.axis, R @ s.axis) and np.allclose(ms.frame_x, R @ s.frame_x)
    back = m.moved(R.T, -R.T @ t)
    assert np.allclose(back.sections["thigh_l"].start, s.start) and np.allclose(back.joints["hip_l"], s.start)


def test_a_missing_forearm_is_listed_unfitted(standing_scans):
    """A partial body: the left forearm cut from the scan (ground-truth labels of the simulator)."""
    from bodyscan import poses
    from bodyscan import simulator

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(poses.load_body("standing"), simulator.preset("paper"))
    keep = scan.gt_section != SECTIONS.index("forearm_l")
    with pytest.warns(UserWarning, match="forearm_l"):
        fit = estimate_posture(scan.points[keep])
    assert "forearm_l" in fit.unfitted and "forearm_l" not in fit.sections
    assert {"waist", "chest", "head", "thigh_l", "thigh_r"} <= set(fit.sections)


def test_cli_writes_fit_json_and_preview(tmp_path, standing_scans):
    from bodyscan import simulator
    from bodyscan import poses

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(poses.load_body("standing"), simulator.preset("paper"))
    cloud = simulator.write_cloud(scan, tmp_path / "s.ply")
    out, png = tmp_path / "fit.json", tmp_path / "fit.png"
    r = subprocess.run([sys.executable, "-m", "bodyscan.benchmarks.cli", "fit", str(cloud), "--out", str(out),
                        "--preview", str(png)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert set(d["joints"]) >= {"pelvis", "neck", "head", "shoulder_l", "wrist_r", "ankle_l"}
    assert set(d["sections"]) == set(SECTIONS) and "coarse" in d
    assert png.stat().st_size > 10000
    bad = tmp_path / "bad.xyz"
    np.savetxt(bad, np.zeros((20, 3)))
    r = subprocess.run([sys.executable, "-m", "bodyscan.benchmarks.cli", "fit", str(bad), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


# -- sparse scans (20 mm, as the sweeps use): a wrong coarse pose is retried or refused ------------
def _fit_or_refuse(name, resolution, k, rot=0.0):
    """(fit or None when refused, ground-truth joints) of a library body scanned at ``resolution``."""
    names = _library()
    assert name in names, f"{name} not shipped"
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body(name)
    R = _rz(rot)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts = simulator.scan(body, simulator.preset("paper", resolution=resolution, k=k)).points @ R.T
        try:
            fit = estimate_posture(pts)
        except ReconError as e:
            assert "\n" not in str(e)
            return None, None
    return fit, {n: R @ v for n, v in body.joint_dict().items()}


@pytest.mark.parametrize("name, resolution, k, rot", [
    ("standing", 0.02, 1, 0), ("standing", 0.02, 3, 0), ("standing", 0.02, 1, 137),
    ("standing", 0.03, 1, 0), ("standing", 0.03, 3, 0),
    ("t_pose", 0.02, 1, 0), ("woman_standing", 0.02, 1, 0), ("walking", 0.02, 3, 0),
    ("tall_standing", 0.02, 1, 0), ("a_pose", 0.02, 1, 0), ("seated", 0.02, 1, 0),
])
def test_sparse_scans_are_fitted_near_the_body_or_refused(name, resolution, k, rot):
    """Each of these was a silent nonsense fit before (left and right swapped by the calf taken for
    the foot, or the torso tilted onto an arm: median joint error 0.2-0.4 m): now the fit is near
    the body (median <= 10 cm, no joint 30 cm off, no fitted limb more than 45 degrees off its bone)
    or a `ReconError` says the posture was not found."""
    fit, joints = _fit_or_refuse(name, resolution, k, rot)
    if fit is None:
        return
    err, ang = _scores(fit, joints)
    assert np.median(list(err.values())) <= 0.10
    assert max(err.values()) <= 0.30
    assert max(ang.values()) <= 45
    # left and right are right: each hip is nearer its own true joint than the other side's
    assert err["hip_l"] < np.linalg.norm(fit.joints["hip_l"] - joints["hip_r"])


@pytest.mark.parametrize("name, resolution, seed", [
    ("tall_standing", 0.01, 0), ("tall_standing", 0.01, 1), ("standing", 0.002, 0)])
def test_perspective_heads_fit_the_head_at_the_crown(name, resolution, seed):
    """Perspective heads (the `scanner` preset: pinholes 2 m away, 1.1 m up) look up at the crown
    and see no point near the head's axis; the head's end is read from its cap's flanks and the
    torso hangs from it (without that end the torso stays where the coarse match put it, low)."""
    from bodyscan import poses, simulator
    from bodyscan.recon import ReconParams
    from bodyscan.recon.pipeline import estimate_fit

    assert name in _library(), f"{name} not shipped"
    body = poses.load_body(name)
    scan = simulator.scan(body, simulator.preset("scanner", resolution=resolution, seed=seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = estimate_fit(scan.points, ReconParams(), view_dir=scan.view_dir, head=scan.head)
    joints = body.joint_dict()
    err, _ = _scores(fit, joints)
    assert abs(fit.joints["head"][2] - joints["head"][2]) <= 0.03
    assert np.median(list(err.values())) <= 0.03


@pytest.mark.parametrize("k", [1, 3])
def test_standing_at_20mm_meets_the_issue_targets(k):
    """The sweeps' 20 mm scans of the standing body: the issue's targets, every section placed or
    listed."""
    fit, joints = _fit_or_refuse("standing", 0.02, k)
    assert fit is not None, "refused"
    err, ang = _scores(fit, joints)
    assert len(fit.unfitted) <= 1
    assert np.median(list(err.values())) <= 0.04
    assert max(err.values()) <= 0.10
    assert max(ang.values()) <= 20


def _seated_chain(H, pelvis, thigh_dir):
    """Sections of a body of stature ``H`` sat with its torso upright: head, thighs along
    ``thigh_dir``, shins down (the model's proportions), arms hanging; its pelvis at ``pelvis``."""
    from bodyscan.recon.posture.bodymodel import standard_body

    b = standard_body(H)
    x, up, down = np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
    neck = pelvis + b.length("neck") * up
    secs = {"head": SectionShape("head", neck, neck + b.section_length("head") * up, b.radii("head"), x,
                                 closed=(False, True), caps=[0.002, 0.002])}
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        hip = pelvis + b.root_offset(f"hip_{side}")
        knee = hip + b.section_length("thigh") * thigh_dir
        secs[f"thigh_{side}"] = SectionShape(f"thigh_{side}", hip, knee, b.radii("thigh"), x)
        secs[f"lower_leg_{side}"] = SectionShape(f"lower_leg_{side}", knee, knee + b.section_length("lower_leg") * down,
                                                 b.radii("lower_leg"), x, closed=(False, True), caps=[0.002, 0.002])
        sh = pelvis + b.root_offset(f"shoulder_{side}") + [sgn * 0.3, 0, 0]   # arms away from the legs
        secs[f"upper_arm_{side}"] = SectionShape(f"upper_arm_{side}", sh, sh + [0, 0, -0.25], b.radii("upper_arm"), x)
        secs[f"forearm_{side}"] = SectionShape(f"forearm_{side}", sh + [0, 0, -0.25], sh + [0, 0.25, -0.25],
                                               b.radii("forearm"), x)
    return b, secs


@pytest.mark.parametrize("thigh", [[0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
def test_size_from_crown_to_sole_whatever_the_knees_bend(thigh):
    """Crown to sole measured over the coarse model (matched at 1.50 m) gives the stature of a
    1.75 m body, standing or seated (thighs level, knees bent 90 degrees): on a bent knee the
    model's thigh, not the points, sets where the shin hangs, so its length is not measured and is
    taken out of the ratio (uncorrected, a seated 1.75 m body measured 1.67 m from a 1.50 m match)."""
    from bodyscan.recon.posture.match import Pose, size_ratios, torso_len

    d = np.array(thigh)
    _, truth = _seated_chain(1.75, np.array([0.0, 0.0, 1.0]), d)
    pts = np.concatenate([truth[k].surface_points(24, 40) for k in ("head", "lower_leg_l", "lower_leg_r")])
    # the small model hangs from the same pelvis height: its crown and shins fall short of the points
    body, secs = _seated_chain(1.50, np.array([0.0, 0.0, 1.0]), d)
    pose = Pose(centre=np.array([0.0, 0.0, 1.0 + 0.5 * torso_len(body)]), R=np.eye(3), body=body, sections=secs)
    r = size_ratios(pts, pose)
    assert len(r["body"]) == 2
    assert np.allclose(np.array(r["body"]) * 1.50, 1.75, atol=0.03)


def test_a_hand_over_the_head_is_not_the_crown():
    """A forearm raised over the head (its hand in line with the head's axis) does not lengthen the
    crown to sole measure: points nearer a placed forearm than the head are not the crown."""
    from bodyscan.recon.posture.match import Pose, size_ratios, torso_len

    down = np.array([0.0, 0.0, -1.0])
    _, truth = _seated_chain(1.75, np.array([0.0, 0.0, 1.0]), down)
    top = truth["head"].end
    hand = SectionShape("forearm_l", top + [0.0, 0.0, 0.08], top + [0.0, 0.0, 0.35], [0.035, 0.035], [1.0, 0, 0])
    pts = np.concatenate([truth[k].surface_points(24, 40) for k in ("head", "lower_leg_l", "lower_leg_r")]
                         + [hand.surface_points(24, 40)])
    body, secs = _seated_chain(1.75, np.array([0.0, 0.0, 1.0]), down)
    secs["forearm_l"] = hand
    pose = Pose(centre=np.array([0.0, 0.0, 1.0 + 0.5 * torso_len(body)]), R=np.eye(3), body=body, sections=secs)
    assert np.allclose(np.array(size_ratios(pts, pose)["body"]) * 1.75, 1.75, atol=0.03)


def test_a_head_in_the_scan_is_seen_above_the_neck():
    """`_head_seen`: a head's surface points above the chest's top end are seen; with the head cut
    from the scan, or with the chest placed a head length too high (its top above the crown), none."""
    from bodyscan.recon.posture.fit import _head_seen

    body, truth = _seated_chain(1.75, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    up = np.array([0.0, 0.0, 1.0])
    neck = truth["head"].start
    chest = SectionShape("chest", neck - 0.2 * up, neck, body.radii("chest"), [1.0, 0, 0])
    head = truth["head"].surface_points(24, 40)
    rest = np.concatenate([truth[k].surface_points(24, 40) for k in ("lower_leg_l", "lower_leg_r")])
    assert _head_seen(np.concatenate([head, rest]), chest, body, 30)
    assert not _head_seen(rest, chest, body, 30)
    high = chest.replace(start=chest.start + 0.3 * up, end=chest.end + 0.3 * up)
    assert not _head_seen(np.concatenate([head, rest]), high, body, 30)


@pytest.mark.parametrize("off", [0.0, 0.06])
def test_the_crown_on_the_trunk_axis_of_a_torso_placed_too_high(off):
    """`_crown_on_trunk`: with the chest placed 0.15 m too high (its head would lean into the air),
    the crown found on the trunk's axis says how far down the neck belongs (within 1 cm), also with
    the head carried ``off`` metres forward of that axis; with no head in the scan, None."""
    from bodyscan.recon.posture.match import _crown_on_trunk

    body, truth = _seated_chain(1.75, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    up = np.array([0.0, 0.0, 1.0])
    fwd = np.array([0.0, -off, 0.0])
    head = truth["head"]
    head = head.replace(start=head.start + fwd, end=head.end + fwd)
    pts = head.surface_points(24, 40)
    neck = truth["head"].start + 0.15 * up
    chest = SectionShape("chest", neck - 0.2 * up, neck, body.radii("chest"), [1.0, 0, 0])
    Lh, r = body.section_length("head"), float(body.radii("head").min())
    shift = _crown_on_trunk(pts, chest, Lh, r)
    assert shift is not None and abs(shift - (-0.15 + head.caps[1])) < 0.01
    assert _crown_on_trunk(truth["lower_leg_l"].surface_points(24, 40), chest, Lh, r) is None


@pytest.mark.parametrize("bend", [0.0, 20.0, 34.0])
def test_elbow_between_closes_the_arm_at_the_bone_proportion(bend):
    """`elbow_between`: an arm of upper arm 0.27 m and forearm 0.25 m bent ``bend`` degrees, from
    its shoulder and wrist and the two bones' directions, gives back its elbow (within 1 mm), at any
    overall size (the model's lengths are not used, only their proportion)."""
    from bodyscan.recon.posture.joints import elbow_between

    for scale in (0.8, 1.0):
        u, f = 0.27 * scale, 0.25 * scale
        shoulder = np.array([0.2, 0.0, 1.4])
        d1 = np.array([0.0, 0.0, -1.0])
        a = np.radians(bend)
        d2 = np.array([0.0, -np.sin(a), -np.cos(a)])
        elbow = shoulder + u * d1
        wrist = elbow + f * d2
        got = elbow_between(shoulder, wrist, d1, d2, 0.27 / 0.52)
        assert np.linalg.norm(got - elbow) < 1e-3


def test_a_torso_deeper_than_wide_is_not_a_fit():
    """A waist deeper than wide means the fit took the body's front for its side (a walker's stride
    read as legs spread apart): the candidate is rejected, so another is tried or the cloud refused."""
    from bodyscan.recon.posture.bodymodel import standard_body
    from bodyscan.recon.posture.fit import _check_plausible

    x = np.array([1.0, 0, 0])
    chest = SectionShape("chest", np.array([0, 0, 1.3]), np.array([0, 0, 1.6]), np.array([0.16, 0.11]), x)
    for radii, bad in (((0.15, 0.11), False), ((0.11, 0.15), True)):
        waist = SectionShape("waist", np.array([0, 0, 1.0]), np.array([0, 0, 1.3]), np.array(radii), x)
        if bad:
            with pytest.raises(ReconError, match="deeper"):
                _check_plausible({"waist": waist, "chest": chest}, standard_body(1.75))
        else:
            _check_plausible({"waist": waist, "chest": chest}, standard_body(1.75))


def test_a_leg_far_longer_than_the_body_size_is_not_a_fit():
    """The sole (the farthest points along the shin) 1.9 standard shanks below the knee: the body's size
    was misjudged; at the standard length the fit stands."""
    from bodyscan.recon.posture.bodymodel import standard_body
    from bodyscan.recon.posture.fit import _check_leg_length

    body = standard_body(1.75)
    knee = np.array([0.1, 0, 0.5])
    shin = SectionShape("lower_leg_l", knee, knee - [0, 0, 0.45], np.array([0.05, 0.05]), np.array([1.0, 0, 0]))
    seg, foot = body.length("lower_leg"), body.length("foot_height")
    for depth, bad in ((seg + foot, False), (1.9 * seg + foot, True)):
        z = np.linspace(0.0, depth, 200)
        pts = knee + np.column_stack([0.03 * np.cos(40 * z), 0.03 * np.sin(40 * z), -z])
        if bad:
            with pytest.raises(ReconError, match="size was misjudged"):
                _check_leg_length(pts, {"lower_leg_l": shin}, body)
        else:
            _check_leg_length(pts, {"lower_leg_l": shin}, body)


def test_a_tilted_winner_brings_back_the_best_upright_torso_when_resized():
    """`recon.posture.match.upright_restart`: the first size is measured along the winning torso's axis; when
    that torso is tilted (heavy_a_pose k3: 22 degrees, arms unfitted) the best upright match is
    matched again at the new size; an upright winner brings back nothing."""
    from types import SimpleNamespace as NS

    from bodyscan.benchmarks.fit_table import rot_z

    def tilt(deg):   # torso frame turned ``deg`` about x: its axis (third column) leaves +z
        a = np.radians(deg)
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]) @ rot_z(30)

    from bodyscan.recon.posture.match import upright_restart

    tilted = NS(R=tilt(22), explained=0.58)
    up_a, up_b = NS(R=tilt(3), explained=0.46), NS(R=tilt(4.9), explained=0.48)
    leaning = NS(R=tilt(12), explained=0.50)
    assert upright_restart(tilted, [tilted, up_a, up_b, leaning], 5.0) is up_b
    assert upright_restart(tilted, [tilted, leaning], 5.0) is None
    assert upright_restart(up_a, [up_a, tilted, up_b], 5.0) is None


def test_a_roll_from_the_legs_needs_a_waist_wider_than_deep():
    """`recon.posture.match.waist_wider_than_deep`: the stride's roll of tall_walking k2 measured its waist
    0.26 m wide and 0.30 deep (refused before the rule); the right roll 0.32 x 0.28."""
    from types import SimpleNamespace as NS

    from bodyscan.recon.posture.match import waist_wider_than_deep

    def waist(wide, deep):
        return NS(radii=np.array([wide, deep]))

    assert not waist_wider_than_deep(waist(0.13, 0.152))
    assert waist_wider_than_deep(waist(0.159, 0.142))


# -- the whole library: 21 bodies x (k = 1, turned 137 degrees, k = 2, k = 3), as benchmarks.fit_table
@pytest.fixture(scope="module")
def library_table():
    names = _library()
    from bodyscan import poses
    from bodyscan.benchmarks.fit_table import CONDITIONS, run_one

    return [dict(run_one(poses.load_body(n), c, 0.01), body=n) for n in names for c in CONDITIONS]


def test_a_section_pointed_at_the_cameras_is_missing_from_the_scan_and_others_are_seen():
    """`fit_table.seen_fractions` on the simulator's ground truth: standing shows every section;
    arms held forward (seen end-on by both cameras) leave the forearms out, so listing them unfitted
    is what the issue allows, while listing a forearm of the standing scan is a miss."""
    assert {"standing", "arms_forward"} <= set(_library()), "library postures missing"
    from bodyscan import poses
    from bodyscan import simulator
    from bodyscan.benchmarks.fit_table import SEEN, outcome, seen_fractions

    seen = {}
    for name in ("standing", "arms_forward"):
        body = poses.load_body(name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=1))
        seen[name] = seen_fractions(body, scan.gt_section, 0.01)
    assert min(seen["standing"].values()) >= SEEN
    assert seen["arms_forward"]["forearm_l"] < 0.5 * SEEN and seen["arms_forward"]["forearm_r"] < 0.5 * SEEN
    err, ang = {"neck": 0.02, "knee_l": 0.03}, {"thigh_l": 5.0}
    assert outcome(err, ang, ("forearm_l",), seen["arms_forward"]) == "part"
    assert outcome(err, ang, ("forearm_l",), seen["standing"]) == "unfit"
    assert outcome(err, ang, ()) == "pass"


def test_a_body_turned_in_the_scanner_is_fitted_in_the_facing_that_explains_it():
    """A fit in doubt is made in every facing (`recon.posture.fit._fit_facings`): a heavy body
    standing turned 30 degrees in the scanner (its occlusions differ from any turned scan) was
    matched 17 cm low in the facing read from its shape (median joint error 16.6 cm, nothing
    listed, no error: a silent wrong fit); its sections explain fewer than `fit_min_coverage` of
    the points (0.58). The kept fit meets the targets and explains more."""
    from bodyscan.benchmarks.fit_table import run_one, score_fit, turned_body

    assert "heavy_standing" in _library(), "library postures missing"
    from bodyscan import poses
    from bodyscan import simulator
    from bodyscan.recon.posture.fit import _estimate, facing_frame
    from bodyscan.recon.posture.match import explained_fraction

    row = run_one(poses.load_body("heavy_standing"), "k1_turn30", 0.01, clean=False)
    assert row["outcome"] == "pass", row
    body = turned_body(poses.load_body("heavy_standing"), 30.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=1)).points
        R, c = facing_frame(pts)
        own = _estimate(np.round((pts - c) @ R.T, 9), FitParams()).moved(R.T, c)
        kept = estimate_posture(pts)
    expl = [explained_fraction(pts, f.sections, 0.02) for f in (own, kept)]
    assert expl[0] < FitParams().fit_min_coverage and expl[1] >= expl[0] + 0.02, expl
    err, _ = score_fit(kept, body.joint_dict())
    assert np.median(list(err.values())) <= 0.04


def test_a_fit_in_doubt_is_made_in_every_facing_and_the_best_kept(monkeypatch):
    """`_fit_facings`: a first turn not in doubt is kept without fitting the others; when it is in
    doubt (`fit_facing_retry` sections unfitted, or under `fit_min_coverage` of the points
    explained), every turn is fitted and the one with fewest sections unfitted, then most points
    explained, is kept, even after a turn that is not in doubt (taking the first such turn was
    faster but lost targets on the validate corpus). A turn refused is never kept, and when every
    turn is refused its first refusal is raised. (The fit itself is replaced here, so that which
    turn is in doubt is known.)"""
    from bodyscan.recon.posture import fit as F

    class Turned:   # what `_estimate` returns: a fit with its unfitted sections, turned back as is
        def __init__(self, unfitted, explained):
            self.unfitted, self.sections = unfitted, explained

        def moved(self, R, c):
            return self

    pts = np.random.default_rng(0).normal(size=(2000, 3)) * [0.15, 0.1, 0.5] + [0, 0, 0.9]
    params = FitParams()
    many = ("forearm_l", "upper_arm_l", "hand_l", "lower_leg_r")
    assert len(many) >= params.fit_facing_retry and params.fit_facing == 4
    refused = ReconError("posture not found")
    every = [ReconError(f"refusal {i}") for i in (1, 2, 3, 4)]
    monkeypatch.setattr(F, "explained_fraction", lambda sample, sections, distance: sections)
    for answers, tried, kept in (   # kept None: the first refusal is raised
            ([Turned(("hand_l",), 0.8), Turned((), 0.99), Turned((), 0.9), Turned((), 0.9)], 1, 0),
            ([Turned(many, 0.9), Turned((), 0.7), Turned((), 0.95), Turned((), 0.99)], 4, 3),
            ([Turned((), 0.5), refused, Turned(many, 0.9), Turned((), 0.52)], 4, 3),
            ([refused, Turned(many[:3], 0.8), Turned(many, 0.95), refused], 4, 1),
            (every, 4, None)):
        calls = []

        def estimate(points, params, front=None, lattice=0.0, behind=None, answers=answers, calls=calls):
            calls.append(lattice)
            answer = answers[len(calls) - 1]
            if isinstance(answer, ReconError):
                raise answer
            return answer

        monkeypatch.setattr(F, "_estimate", estimate)
        if kept is None:
            with pytest.raises(ReconError, match="refusal 1$"):
                F._fit_facings(pts, params)
        else:
            assert F._fit_facings(pts, params) is answers[kept]
        assert len(calls) == tried


def test_library_fits_are_never_silent_nonsense(library_table):
    """No WRONG fit (median > 10 cm or a joint > 30 cm with no error raised), and no refusal: every
    shipped posture is a whole body."""
    outcomes = {(r["body"], r["condition"]): r["outcome"] for r in library_table}
    assert not [k for k, o in outcomes.items() if o in ("WRONG", "refused")]


#: Library runs that miss issue 4's targets with the fit made as `bodyscan fit` makes it (outliers
#: left out first): leaning at k = 2 is fitted with its left shoulder 12.2 cm off (median joint
#: error 4.3 cm), every section fitted, passing every check. The volume match is chaotic
#: (`fit_regrid`): listed here until the fit is robust to such a change of the points.
LIBRARY_MISSES = {("leaning", "k2")}


def test_library_fits_meet_the_issue_targets(library_table):
    """Issue 4 on every run of the library but `LIBRARY_MISSES`: median joint error <= 4 cm, every
    joint <= 10 cm, every limb within 20 degrees of its bone; a run with a section listed unfitted
    counts only when the scan misses that section (`benchmarks.fit_table.SEEN`). Measured: 82 of 84
    (squat k2 met since the deeply bent knee lies on the lower leg's axis,
    `recon.posture.joints.bent_knee`; tall_walking k3 since the body is matched at both sizes when its
    legs and crown to sole disagree, `match_size_both`; squat k3, refused on the first lattice, since
    `fit_regrid`)."""
    missed = {(r["body"], r["condition"]) for r in library_table if r["outcome"] not in ("pass", "part")}
    assert missed <= LIBRARY_MISSES, sorted(missed - LIBRARY_MISSES)


def test_the_shifted_lattice_discretizes_the_same_points_half_a_voxel_off():
    """`voxelize`'s ``offset``: the grid's origin moves back by that fraction of a voxel, and each
    point's voxel index is floor(coordinate / size + pad + offset) from the points' corner: a point
    more than half a voxel into a voxel of the first lattice lies in the next voxel of the shifted
    one."""
    from bodyscan.recon.posture.volume import voxelize

    size = 0.02
    pts = np.array([[0.0, 0.0, 0.0], [0.011, 0.0, 0.0], [0.029, 0.031, 0.05], [0.1, 0.1, 0.1]])
    a, b = voxelize(pts, size), voxelize(pts, size, offset=0.5)
    assert np.allclose(b.origin, a.origin - 0.5 * size)
    for vol, off in ((a, 0.0), (b, 0.5)):
        idx = np.floor((pts - pts.min(axis=0)) / size + 3 + off).astype(int)
        assert vol.contour[tuple(idx.T)].all()
        assert vol.contour.sum() == len({tuple(i) for i in idx})
    # 11 mm from the corner: voxel 3 on the first lattice (3.55), voxel 4 on the shifted one (4.05)
    assert a.contour[3, 3, 3] and not a.contour[4, 3, 3]
    assert b.contour[3, 3, 3] and b.contour[4, 3, 3]


def _elliptic_column(a, b, z, n_theta):
    """The side of an upright elliptic column, semi-axes ``a`` along x and ``b`` along y, sampled at
    ``n_theta`` angles on each height of ``z`` (k,): points (n_theta * k, 3) and unit outward normals."""
    t, zz = np.meshgrid(np.linspace(0, 2 * np.pi, n_theta, endpoint=False), z)
    P = np.column_stack([a * np.cos(t.ravel()), b * np.sin(t.ravel()), zz.ravel()])
    N = np.column_stack([np.cos(t.ravel()) / a, np.sin(t.ravel()) / b, np.zeros(t.size)])
    return P, N / np.linalg.norm(N, axis=1, keepdims=True)


def test_a_column_seen_only_at_its_ends_is_filled_between_the_views():
    """`voxelize`'s ``behind`` (`recon.views.Views.behind`): an elliptic column 0.32 m deep along
    the cameras' axis and 0.2 m wide, seen by the front and rear cameras only on its two ends
    (surface facing them at under 60 degrees; its flanks, along the view, unseen: a body turned
    90 degrees in the scanner shows its trunk so) has two 0.3 m gaps in every slice, which the
    closing and the in-plane test do not enclose; the space behind both seen ends is filled, and
    nothing outside the column is."""
    from bodyscan.recon.posture.seen import scan_views
    from bodyscan.recon.posture.volume import voxelize
    from views import front_rear_zbuffer

    a, b, height, size = 0.10, 0.16, 0.6, 0.025                  # semi-axes along x and y (the view)
    P, N = _elliptic_column(a, b, np.linspace(0, height, 121), 600)
    ends = np.abs(N[:, 1]) > 0.5
    keep, vd = front_rear_zbuffer(P[ends], N[ends], 0.01)
    pts, vd = P[ends][keep], vd[keep]
    assert np.abs(pts[:, 0]).max() < 0.8 * a                    # the flanks are not in the scan

    def cover(vol):
        c = vol.centres(np.ones(vol.shape, bool)).reshape(vol.shape + (3,))
        solid = vol.inside | vol.contour
        r_in = (c[..., 0] / (a - size)) ** 2 + (c[..., 1] / (b - size)) ** 2 < 1
        deep = r_in & (c[..., 2] > 2 * size) & (c[..., 2] < height - 2 * size)
        r_out = (c[..., 0] / (a + size)) ** 2 + (c[..., 1] / (b + size)) ** 2 > 1
        return solid[deep].mean(), int(vol.inside[r_out].sum())

    plain, _ = cover(voxelize(pts, size))
    filled, outside = cover(voxelize(pts, size, behind=scan_views(pts, vd).behind))
    assert plain < 0.5, plain
    assert filled > 0.98 and outside == 0, (filled, outside)


def test_heads_of_a_tower_each_say_only_where_their_picture_reaches():
    """Two towers (`simulator.head_layout`'s ``two_towers``): an upper and a lower head in front,
    the same behind, the upper ones seeing an elliptic column 0.1-1.9 m high above 0.9 m, the
    lower ones below 1.3 m. A voxel is inside when it lies behind what every head whose picture
    reaches it saw: the whole column, not only the band all four heads see, and nothing beside
    it. On the library's standing body scanned so (parallel heads, 10 mm), the fit meets issue 4's
    targets (with every head required, its volume held the band alone: a joint 28 cm off)."""
    from bodyscan import poses, simulator
    from bodyscan.recon.posture.seen import scan_views
    from bodyscan.recon.posture.volume import voxelize
    from bodyscan.simulator.config import head_layout

    a, b, size = 0.15, 0.10, 0.025
    P, N = _elliptic_column(a, b, np.arange(0.1, 1.9, 0.005), 300)
    pts, vd, head = [], [], []
    for h, (side, lo, hi) in enumerate([(-1, 0.9, 2.0), (-1, 0.0, 1.3), (1, 0.9, 2.0), (1, 0.0, 1.3)]):
        seen = (N[:, 1] * side > 0) & (P[:, 2] >= lo) & (P[:, 2] <= hi)
        pts.append(P[seen])
        vd.append(np.tile([0.0, side, 0.0], (seen.sum(), 1)))
        head.append(np.full(seen.sum(), h))
    vol = voxelize(np.vstack(pts), size, behind=scan_views(np.vstack(pts), np.vstack(vd), np.concatenate(head)).behind)
    c = vol.centres(np.ones(vol.shape, bool)).reshape(vol.shape + (3,))
    r = (c[..., 0] / a) ** 2 + (c[..., 1] / b) ** 2
    deep = (r < 0.6) & (c[..., 2] > 0.1 + 2 * size) & (c[..., 2] < 1.9 - 2 * size)
    assert vol.inside[deep].mean() > 0.98 and not vol.inside[r > 1.5].any()

    assert "standing" in _library(), "library postures missing"
    body = poses.load_body("standing")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, heads=head_layout("two_towers")))
        fit = estimate_posture(scan.points, view_dir=scan.view_dir, head=scan.head)
    err = [np.linalg.norm(fit.joints[n] - p) for n, p in body.joint_dict().items()]
    assert not fit.unfitted and np.median(err) <= 0.04 and max(err) <= 0.10, (np.median(err), max(err))


def test_perspective_views_leave_a_shared_shadow_behind_both_and_enclose_the_volume(monkeypatch):
    """Perspective heads 2 m in front of and behind an elliptic column standing 0.2-1.0 m high,
    their centres at 1.1 m: every line of sight through the space under the column passes through
    the column first, so that space lies behind the surface both heads saw (the soles of a body
    scanned from above them), and `Views.behind` holds it: a loose bound there. The column's
    inside is held as well as by parallel heads, which hold nothing under it. The fit encloses its
    volume between the views of either."""
    from bodyscan.recon.posture import fit as F
    from bodyscan.recon.posture.seen import scan_views
    from bodyscan.recon.posture.volume import voxelize

    a, b, bottom, top, size = 0.15, 0.10, 0.2, 1.0, 0.025
    P, N = _elliptic_column(a, b, np.arange(bottom, top, 0.005), 300)
    gx, gy = np.meshgrid(np.arange(-a, a, 0.005), np.arange(-b, b, 0.005))
    cap = (gx / a) ** 2 + (gy / b) ** 2 < 1
    P = np.vstack([P, np.column_stack([gx[cap], gy[cap], np.full(cap.sum(), top)])])
    N = np.vstack([N, np.tile([0.0, 0.0, 1.0], (cap.sum(), 1))])
    for perspective in (True, False):
        pts, vd, head = [], [], []
        for h, centre in enumerate(([0.0, -2.0, 1.1], [0.0, 2.0, 1.1])):
            to = np.asarray(centre) - P if perspective else np.tile([0.0, np.sign(centre[1]), 0.0], (len(P), 1))
            seen = np.einsum("ij,ij->i", to, N) > 0                     # a convex body: facing is seen
            pts.append(P[seen])
            vd.append(to[seen] / np.linalg.norm(to[seen], axis=1, keepdims=True))
            head.append(np.full(seen.sum(), h))
        pts, vd, head = np.vstack(pts), np.vstack(vd), np.concatenate(head)
        views = scan_views(pts, vd, head)
        assert views.parallel is not perspective
        vol = voxelize(pts, size, behind=views.behind)
        c = vol.centres(np.ones(vol.shape, bool)).reshape(vol.shape + (3,))
        below = c[..., 2] < bottom - size
        deep = ((c[..., 0] / a) ** 2 + (c[..., 1] / b) ** 2 < 0.8) & (np.abs(c[..., 2] - 0.6) < 0.35)
        assert bool(vol.inside[below].any()) is perspective
        assert vol.inside[deep].mean() > 0.9
        given = []     # what the fit hands the volume

        def voxelize_stop(*args, behind=None, **kwargs):
            given.append(behind)
            raise ReconError("stop")

        monkeypatch.setattr(F, "voxelize", voxelize_stop)
        with pytest.raises(ReconError, match="stop"):
            F.estimate_posture(pts, view_dir=vd, head=head, params=FitParams(fit_facing=0, fit_regrid=0))
        # the points as they lie (no facing turn): the fit's views' own test
        at = c[deep | below]
        assert len(given) == 1 and given[0] is not None
        assert np.array_equal(given[0](at), F._views(pts, vd, head, FitParams()).behind(at))
        monkeypatch.undo()


def test_a_cloud_refused_on_one_lattice_is_fitted_on_the_shifted_one():
    """`fit_regrid`: the library's squat at k = 3, made as `bodyscan fit` makes it (outliers left
    out), on the volume its contours enclose (`voxel_views` off; between the views its first
    lattice meets the targets), is refused on the volume's first lattice (the cameras confirm
    62.7 % of the trunk the fit shows them) and meets issue 4's targets fitted on the lattice
    shifted by half a voxel."""
    from bodyscan.benchmarks.fit_table import run_one

    assert "squat" in _library(), "library postures missing"
    from bodyscan import poses

    body = poses.load_body("squat")
    off = run_one(body, "k3", 0.01, FitParams(fit_regrid=False, voxel_views=False))
    assert off["outcome"] == "refused" and "trunk" in off["message"], off
    row = run_one(body, "k3", 0.01, FitParams(voxel_views=False))
    assert row["outcome"] in ("pass", "part"), row


def test_legs_and_crown_disagreeing_are_both_matched_and_the_points_decide():
    """tall_walking (1.97 m) at k = 3, fitted in the facing turned 180 degrees from its feet's (the one
    the cloud's third moment gave): its first match's hips sat high, the legs measured 2.18 m and
    crown to sole 2.02 m, 0.086 apart (under `match_size_disagree`): sized by the legs alone its knees
    lie 8-9 cm off; matched at both sizes, the one explaining more points is 2.02 m, and the fit
    meets the targets with its knees within 5 cm. (In its feet's facing both ways meet the
    targets.)"""
    from bodyscan.benchmarks.fit_table import outcome, seen_fractions

    assert "tall_walking" in _library(), "library postures missing"
    from bodyscan import poses, simulator
    from bodyscan.recon.posture.fit import _estimate, facing_frame

    body = poses.load_body("tall_walking")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=3))
    pts, seen = scan.points, seen_fractions(body, scan.gt_section, 0.01)
    R, c = facing_frame(pts)
    R = _rz(180) @ R
    rows, knees = [], []
    for params in (FitParams(), FitParams(match_size_both=0)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = _estimate(np.round((pts - c) @ R.T, 9), params).moved(R.T, c)
        err, ang = _scores(fit, body.joint_dict())
        rows.append(outcome(err, ang, fit.unfitted, seen))
        knees.append(max(err.get("knee_l", np.inf), err.get("knee_r", np.inf)))
    assert rows[0] == "pass" and knees[0] < 0.05 and knees[1] > 0.07, (rows, knees)


@pytest.mark.parametrize("k", [1, 2])
def test_a_childs_proportions_are_not_a_size_disagreement_or_cut_legs(k):
    """child_arms_raised at 20 mm: a child's large head and short legs make crown to sole and the
    legs disagree (1.53 against 1.41 m at k = 1), and one leg chain may measure 0.78 of the trunk
    (k = 2); matched at the larger size (`match_size_both`), or sized from the trunk with the lower
    legs listed (`match_leg_trunk_min`), the fit listed a lower leg the scan shows (k = 1) or missed
    the targets (k = 2, elbow 10.1 cm). Both rules hold for adult sizes and both legs only; sized as
    a child, the crown-to-sole match goes first only when it explains more points by
    `match_crown_first_margin` (at k = 2 it explains 0.17 more than the legs' 1.26 m, and tried
    first at a margin of 0.1 the fit misses, a joint 28 cm off). On the
    volume the contours enclose (`voxel_views` off): between the views, k = 1 misses the targets
    otherwise (the whole body low, median 5.3 cm, a wrist 10.0 cm off)."""
    from bodyscan.benchmarks.fit_table import run_one

    assert "child_arms_raised" in _library(), "library postures missing"
    from bodyscan import poses

    row = run_one(poses.load_body("child_arms_raised"), f"k{k}", 0.02, FitParams(voxel_views=False), clean=False)
    assert row["outcome"] == "pass", row


def test_a_short_adult_is_sized_by_the_match_explaining_more_points():
    """Body 43 of the corpus of seed 0 (tune62: a stride, 1.29 m), k = 1: under
    `fit_anchor_min_stature` it is sized as a child, by its legs, which are short for its trunk:
    1.10 m, whose model explains 0.60 of the points; its crown to sole, 1.31 m, explains 0.89 and
    was only the first fallback, so the legs' size was fitted (the right arm, seen, listed unfitted;
    neck 8.3 cm off).
    Tried first when it explains more points by `match_crown_first_margin`, the fit meets issue
    4's targets."""
    pytest.importorskip("torch", reason="the generator needs the 'bodies' extra (torch)")
    pytest.importorskip("anny", reason="the generator needs the 'bodies' extra (anny)")
    from bodyscan.benchmarks.fit_table import run_one
    from bodyscan.poses.sample import sample_body

    body = sample_body(0, 43)
    off = run_one(body, "k1", 0.01, FitParams(match_crown_first_margin=1.0))
    assert off["outcome"] not in ("pass", "part"), off    # the case, without the rule
    row = run_one(body, "k1", 0.01, FitParams())
    assert row["outcome"] == "pass" and row["max"] < 0.05, row


def test_legs_ending_in_feet_are_never_judged_cut():
    """Both leg chains measuring under `match_leg_trunk_min` of the trunk are legs cut from the scan,
    unless the scan shows feet (`recon.posture.fit.feet_forward`): with the limit raised to 1.5, where
    every whole leg measures short (as a short heavy body matched at too large a first size does),
    standing keeps both lower legs; cut from the scan (no feet), they are listed."""
    from bodyscan.benchmarks.fit_table import run_one

    assert "standing" in _library(), "library postures missing"
    from bodyscan import poses

    body = poses.load_body("standing")
    params = FitParams(match_leg_trunk_min=1.5)
    row = run_one(body, "k1", 0.02, params, clean=False)
    assert row["outcome"] == "pass" and row["unfitted"] == (), row
    row = run_one(body, "k1_without-lower_leg_l+lower_leg_r", 0.02, params, clean=False)
    assert {"lower_leg_l", "lower_leg_r"} <= set(row.get("unfitted", ())), row


def test_lower_legs_seen_from_the_side_stay_on_their_points():
    """a_pose turned 90 degrees (k = 1: the cameras see its sides, each leg's outer side only),
    fitted on the volume its contours enclose (`voxel_views` off): both lower legs, seen, are
    fitted and not listed. A lower leg the fit leaves off its points is searched again from its
    knee (`research_distal`)."""
    from bodyscan.benchmarks.fit_table import run_one

    assert "a_pose" in _library(), "library postures missing"
    from bodyscan import poses

    row = run_one(poses.load_body("a_pose"), "k1_turn90", 0.01, FitParams(voxel_views=False), clean=False)
    assert row["outcome"] == "pass" and row["unfitted"] == (), row


def _torso_points(bottom_z, spacing):
    """Points of an elliptic column (radii 0.16 across, 0.11 front to back) from ``bottom_z`` to
    1.3 m, closed at the bottom."""
    A, Z = np.meshgrid(np.linspace(0, 2 * np.pi, 120, endpoint=False), np.arange(bottom_z, 1.3, spacing))
    torso = np.column_stack([0.16 * np.cos(A.ravel()), 0.11 * np.sin(A.ravel()), Z.ravel()])
    gx, gy = np.meshgrid(np.arange(-0.16, 0.16, spacing), np.arange(-0.11, 0.11, spacing))
    inside = (gx / 0.16) ** 2 + (gy / 0.11) ** 2 < 1
    return np.vstack([torso, np.column_stack([gx[inside], gy[inside], np.full(inside.sum(), bottom_z)])])


def _crotch_scene(crotch_z=0.80, spacing=0.01):
    """Points of a torso (elliptic column closed at the crotch height) over two legs held apart,
    and a fit whose thighs start 15 cm above the crotch."""
    x = np.array([1.0, 0, 0])
    ang = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    legs = []
    for cx in (0.1, -0.1):
        a2, z2 = np.meshgrid(ang, np.arange(0.0, crotch_z + 0.05, spacing))
        legs.append(np.column_stack([cx + 0.07 * np.cos(a2.ravel()), 0.07 * np.sin(a2.ravel()), z2.ravel()]))
    points = np.vstack([_torso_points(crotch_z, spacing)] + legs)
    top = crotch_z + 0.15
    secs = {"waist": SectionShape("waist", [0, 0, top], [0, 0, 1.2], [0.16, 0.11], x),
            "thigh_l": SectionShape("thigh_l", [0.1, 0, top], [0.1, 0, top - 0.45], [0.07, 0.07], x),
            "thigh_r": SectionShape("thigh_r", [-0.1, 0, top], [-0.1, 0, top - 0.45], [0.07, 0.07], x)}
    return points, secs


def test_find_crotch_between_legs_apart():
    """The crotch is the lowest point of the mid-plane strip between the legs: the torso's bottom."""
    from bodyscan.recon.posture.joints import find_crotch

    points, secs = _crotch_scene(0.80)
    c = find_crotch(points, secs)
    assert c is not None and abs(c[2] - 0.80) < 0.006 and abs(c[0]) < 0.01


def test_split_hips_lowers_thighs_to_the_crotch():
    """Thighs fitted 15 cm above the crotch start CROTCH_SPLIT thigh lengths above it; a thigh
    already starting lower, and flexed hips (no crotch sought along the thighs), are left alone."""
    from bodyscan.recon.posture.bodymodel import CROTCH_SPLIT
    from bodyscan.recon.posture.joints import split_hips

    points, secs = _crotch_scene(0.80)
    out = split_hips(points, secs)
    for side in "lr":
        t = out[f"thigh_{side}"]
        assert abs(t.start[2] - (0.80 + CROTCH_SPLIT * 0.45)) < 0.006
        assert np.allclose(t.end, secs[f"thigh_{side}"].end)
    low = {**secs, "thigh_l": secs["thigh_l"].replace(start=np.array([0.1, 0, 0.82]))}
    assert np.allclose(split_hips(points, low)["thigh_l"].start, [0.1, 0, 0.82])
    x = np.array([1.0, 0, 0])
    flexed = {**secs, **{f"thigh_{s}": SectionShape(f"thigh_{s}", [c, 0, 0.95], [c, -0.45, 0.95], [0.07, 0.07], x)
                         for s, c in (("l", 0.1), ("r", -0.1))}}
    assert all(np.allclose(split_hips(points, flexed)[k].start, flexed[k].start) for k in ("thigh_l", "thigh_r"))


def test_pelvis_from_below_meets_the_crotch_halfway():
    """A waist fitted 15 cm above a crotch at 0.80 m: the pelvis and both hips move up the waist's
    axis halfway to PELVIS_ABOVE_CROTCH statures above the crotch, the other joints stay; flexed
    thighs over legs that go on down (no crotch sought, no seat: the column does not end) leave
    every joint where it was."""
    from bodyscan.recon.posture.bodymodel import PELVIS_ABOVE_CROTCH, StandardBody
    from bodyscan.recon.posture.joints import pelvis_from_below

    points, secs = _crotch_scene(0.80)
    body, back = StandardBody(1.70), np.array([0.0, 1.0, 0.0])
    joints = {"pelvis": np.array([0.0, 0.02, 0.95]), "hip_l": np.array([0.1, 0.0, 0.94]),
              "hip_r": np.array([-0.1, 0.0, 0.94]), "knee_l": np.array([0.1, 0.0, 0.5])}
    out = pelvis_from_below(joints, secs, points, body, back)
    want = 0.5 * ((0.80 + PELVIS_ABOVE_CROTCH * 1.70) - 0.95)          # the crotch at 0.80 m (found within 6 mm)
    for k in ("pelvis", "hip_l", "hip_r"):
        assert out[k][2] - joints[k][2] == pytest.approx(want, abs=0.003)
        assert np.allclose(out[k][:2], joints[k][:2])
    assert np.array_equal(out["knee_l"], joints["knee_l"])
    x = np.array([1.0, 0, 0])
    flexed = {**secs, **{f"thigh_{s}": SectionShape(f"thigh_{s}", [c, 0, 0.95], [c, -0.45, 0.95], [0.07, 0.07], x)
                         for s, c in (("l", 0.1), ("r", -0.1))}}
    assert all(np.array_equal(v, joints[k]) for k, v in pelvis_from_below(joints, flexed, points, body, back).items())


def _seated_scene(seat_z=0.55, spacing=0.01, above=0.17):
    """Points of a seated torso (elliptic column closed at the seat height) with two thighs leaving
    forward (-y) at 0.60 m and nothing below, and a fit whose waist starts ``above`` metres above
    the seat."""
    x = np.array([1.0, 0, 0])
    ang = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    thighs = []
    for cx in (0.1, -0.1):
        a2, y2 = np.meshgrid(ang, np.arange(-0.5, -0.11, spacing))
        thighs.append(np.column_stack([cx + 0.07 * np.cos(a2.ravel()), y2.ravel(), 0.60 + 0.07 * np.sin(a2.ravel())]))
    points = np.vstack([_torso_points(seat_z, spacing)] + thighs)
    secs = {"waist": SectionShape("waist", [0, 0, seat_z + above], [0, 0, 1.2], [0.16, 0.11], x)}
    for s, cx in (("l", 0.1), ("r", -0.1)):
        secs[f"thigh_{s}"] = SectionShape(f"thigh_{s}", [cx, -0.08, 0.60], [cx, -0.5, 0.60], [0.07, 0.07], x)
    return points, secs


def test_find_seat_under_flexed_hips():
    """Seated, the seat is the bottom of the torso seen behind the waist's axis; a thigh held down
    (the legs' line, where the crotch is sought), or a knee under the hips, finds none."""
    from bodyscan.recon.posture.joints import find_seat

    points, secs = _seated_scene(0.55)
    back = np.array([0.0, 1.0, 0.0])
    seat = find_seat(points, secs, back, 1.70)
    assert seat is not None and seat[2] == pytest.approx(0.55, abs=1e-9) and seat[1] > 0
    down = {**secs, "thigh_r": SectionShape("thigh_r", [-0.1, 0, 0.6], [-0.1, 0, 0.15], [0.07, 0.07],
                                            np.array([1.0, 0, 0]))}
    assert find_seat(points, down, back, 1.70) is None
    # without the thighs, the knees (the lower legs' starts) show the flexion: forward, a seat;
    # under the hips, none
    x = np.array([1.0, 0, 0])
    shins = {"waist": secs["waist"]}
    for s, c in (("l", 0.1), ("r", -0.1)):
        shins[f"lower_leg_{s}"] = SectionShape(f"lower_leg_{s}", [c, -0.5, 0.6], [c, -0.5, 0.15], [0.05, 0.05], x)
    assert np.allclose(find_seat(points, shins, back, 1.70), seat)
    hanging = {**shins, "lower_leg_r": SectionShape("lower_leg_r", [-0.1, 0, 0.3], [-0.1, 0, -0.1], [0.05, 0.05], x)}
    assert find_seat(points, hanging, back, 1.70) is None


def test_find_seat_below_a_waist_fitted_high():
    """A squat's waist column runs on into the buttocks: with its lower end fitted 30 cm (0.18
    statures) above the seat, where the rig's pelvis lies 0.05 statures above it, the seat is still
    found (`SEAT_WINDOW` reaches 0.2 statures down; at 0.15 it was not)."""
    from bodyscan.recon.posture.joints import find_seat

    points, secs = _seated_scene(0.45, above=0.30)
    seat = find_seat(points, secs, np.array([0.0, 1.0, 0.0]), 1.70)
    assert seat is not None and seat[2] == pytest.approx(0.45, abs=1e-9)


def test_pelvis_from_below_sits_on_the_seat():
    """A seated waist fitted 17 cm above the seat: the pelvis and both hips move down the waist's
    axis to their heights above the seat (ABOVE_SEAT statures); the other joints stay."""
    from bodyscan.recon.posture.bodymodel import ABOVE_SEAT, StandardBody
    from bodyscan.recon.posture.joints import pelvis_from_below

    points, secs = _seated_scene(0.55)
    joints = {"pelvis": np.array([0.0, 0.02, 0.72]), "hip_l": np.array([0.1, 0.0, 0.71]),
              "hip_r": np.array([-0.1, 0.0, 0.71]), "knee_l": np.array([0.1, -0.45, 0.6])}
    out = pelvis_from_below(joints, secs, points, StandardBody(1.70), np.array([0.0, 1.0, 0.0]))
    for k in ("pelvis", "hip_l", "hip_r"):
        assert out[k][2] == pytest.approx(0.55 + ABOVE_SEAT[k.split("_")[0]] * 1.70, abs=1e-6)
        assert np.allclose(out[k][:2], joints[k][:2])
    assert np.array_equal(out["knee_l"], joints["knee_l"])


def _torso_scene():
    """The crotch scene with a chest column on the waist (pelvis end 0.95, chest joint 1.20, neck
    1.50 m): the crotch seen at 0.80 m, 15 cm below the waist column's lower end."""
    points, secs = _crotch_scene(0.80)
    x = np.array([1.0, 0, 0])
    chest = SectionShape("chest", [0, 0, 1.2], [0, 0, 1.5], [0.17, 0.12], x)
    return points, {**secs, "chest": chest}


def test_split_torso_cuts_from_the_crotch_seen_or_along_the_column():
    """The reported waist and chest meet TORSO_SPLIT_CROTCH of the way from the crotch seen in the
    points to the chest joint; without a crotch (hips flexed) at TORSO_SPLIT of the waist column;
    within TORSO_SPLIT_RANGE of the column always. The chest keeps its top, the waist its bottom."""
    from bodyscan.recon.posture.bodymodel import TORSO_SPLIT, TORSO_SPLIT_CROTCH, TORSO_SPLIT_RANGE
    from bodyscan.recon.posture.joints import split_torso

    points, secs = _torso_scene()
    out = split_torso(points, secs)
    cut = 0.80 + TORSO_SPLIT_CROTCH * (1.20 - 0.80)
    assert abs(out["waist"].end[2] - cut) < 0.006 and abs(out["chest"].start[2] - cut) < 0.006
    assert np.allclose(out["waist"].start, secs["waist"].start) and np.allclose(out["chest"].end, secs["chest"].end)
    x = np.array([1.0, 0, 0])
    flexed = {**secs, **{f"thigh_{s}": SectionShape(f"thigh_{s}", [c, 0, 0.95], [c, -0.45, 0.95], [0.07, 0.07], x)
                         for s, c in (("l", 0.1), ("r", -0.1))}}
    assert abs(split_torso(points, flexed)["waist"].end[2] - (0.95 + TORSO_SPLIT * 0.25)) < 1e-9
    far = split_torso(points, secs, from_crotch=1.5)   # a cut beyond the chest joint is held on the waist
    assert abs(far["waist"].end[2] - (0.95 + TORSO_SPLIT_RANGE[1] * 0.25)) < 1e-9


@pytest.mark.parametrize("case", ["k1", "k1_rot137", "k3"])
def test_standing_waist_and_chest_meet_where_the_labels_change(standing_fits, case):
    """The reported waist/chest boundary of the estimated posture lies within 2 cm, along the waist
    column, of the plane across it that best separates the body's waist and chest vertices (cut at
    0.625 of the column from the fitted pelvis: -3.0, -2.9, -1.2 cm; from the crotch: -1.2, -1.0,
    +0.8 cm)."""
    from bodyscan import poses
    from bodyscan.benchmarks.fit_table import rot_z

    fit, _ = standing_fits[case]
    body = poses.load_body("standing")
    verts = body.vertices @ rot_z(137 if case == "k1_rot137" else 0).T
    w = fit.sections["waist"]
    lab = np.asarray(body.vertex_section)
    torso = np.isin(lab, [SECTIONS.index("waist"), SECTIONS.index("chest")])
    t = (verts[torso] - w.start) @ w.axis
    is_waist = lab[torso] == SECTIONS.index("waist")
    cuts = np.linspace(0.0, 0.6, 601)
    wrong = (is_waist[None, :] & (t[None, :] > cuts[:, None])).sum(1) + \
        (~is_waist[None, :] & (t[None, :] <= cuts[:, None])).sum(1)
    best = cuts[wrong == wrong.min()].mean()
    assert abs(w.length - best) < 0.02


def test_a_forearm_through_the_head_is_inside_another_section():
    """`_inside_others`: a forearm whose axis runs into the head counts as inside another section
    (the re-search drops it); the same forearm held a forearm radius beside the head, or any
    section tested against itself only, does not."""
    from bodyscan.recon.posture.adjust import _inside_others

    x = np.array([1.0, 0, 0])
    head = SectionShape("head", [0, 0, 1.5], [0, 0, 1.75], [0.08, 0.08], x)
    through = SectionShape("forearm_l", [0.25, 0, 1.55], [0.0, 0, 1.66], [0.035, 0.035], x)
    beside = SectionShape("forearm_l", [0.35, 0, 1.55], [0.115, 0, 1.66], [0.035, 0.035], x)
    assert _inside_others(through, {"head": head, "forearm_l": through}, "forearm_l")
    assert not _inside_others(beside, {"head": head, "forearm_l": beside}, "forearm_l")
    assert not _inside_others(through, {"forearm_l": through}, "forearm_l")


def test_a_lower_leg_stands_on_its_own_points_when_its_thigh_is_missing_from_the_scan():
    """Squat at k = 3: a thigh held level, seen from the front and above, holds no inside voxels and
    is listed as missing from the scan (seen on 0.14 of its area); its lower leg is seen (0.20) and
    stands on its own points and checks, no longer listed with it (measured: knee 4.0 cm, ankle
    2.1 cm off, 7 degrees from its bone)."""
    assert "squat" in _library(), "library postures missing"
    from bodyscan import poses
    from bodyscan import simulator

    body = poses.load_body("squat")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(body, simulator.preset("paper", resolution=0.01, k=3))
        fit = estimate_posture(scan.points)
    err, ang = _scores(fit, body.joint_dict())
    listed = [s[-1] for s in fit.unfitted if s.startswith("thigh")]
    assert listed, "the case needs a thigh listed as missing from the scan"
    for side in listed:
        assert f"lower_leg_{side}" in fit.sections and f"lower_leg_{side}" not in fit.unfitted
        assert err[f"knee_{side}"] < 0.06 and err[f"ankle_{side}"] < 0.05 and ang[f"lower_leg_{side}"] < 20


def test_a_head_leaning_beyond_the_necks_flexion_does_not_place_the_torso():
    """Body 17 of the corpus of seed 0 (tune62: arms at the sides) turned 90 degrees, k = 1 (the
    cameras see its sides): the torso matched 12 cm high with its head leaning 67 degrees forward
    onto the face explained more points (0.86) than the torso slid down to the crown on the
    trunk's axis (0.83), a silent nonsense fit (shoulders and neck 13-16 cm off;
    `match_head_max_lean` = 180: the rule off). A head leaning forward or back beyond the neck's
    flexion (`recon.posture.match.head_in_range`) lets the slid torso win: the fit meets issue
    4's targets. This is on the volume its contours enclose (`voxel_views` off): between the
    views, the torso is not matched high, with or without the rule."""
    pytest.importorskip("torch", reason="the generator needs the 'bodies' extra (torch)")
    pytest.importorskip("anny", reason="the generator needs the 'bodies' extra (anny)")
    from bodyscan.benchmarks.fit_table import run_one
    from bodyscan.poses.sample import sample_body
    from bodyscan.recon.posture.match import head_in_range

    body = sample_body(0, 17)
    off = run_one(body, "k1_turn90", 0.01, FitParams(match_head_max_lean=180.0, voxel_views=False), clean=False)
    assert off["outcome"] == "WRONG" or off.get("silent"), off    # the case, without the rule
    row = run_one(body, "k1_turn90", 0.01, FitParams(voxel_views=False), clean=False)
    assert row["outcome"] == "pass", row

    # the lean is measured towards the chest's front or back only
    chest = SectionShape(name="chest", start=np.zeros(3), end=np.array([0, 0, 0.3]),
                         radii=np.array([0.15, 0.1]), frame_x=np.array([1.0, 0, 0]))

    def head(deg, towards):
        d = np.cos(np.radians(deg)) * np.array([0, 0, 1.0]) + np.sin(np.radians(deg)) * np.asarray(towards)
        return chest.replace(name="head", start=chest.end, end=chest.end + 0.2 * d)

    assert head_in_range({"chest": chest, "head": head(55, [0, 1, 0])}, 60)
    assert not head_in_range({"chest": chest, "head": head(65, [0, -1, 0])}, 60)
    assert head_in_range({"chest": chest, "head": head(80, [1, 0, 0])}, 60)   # sideways: not flexion


@pytest.mark.parametrize("unfitted, dropped", [
    ((), ()),
    (("lower_leg_l",), ("knee_l",)),
    (("forearm_r",), ("elbow_r",)),
    (("forearm_l", "lower_leg_r"), ("elbow_l", "knee_r")),
    # an unfitted proximal or trunk section takes no joint of another section with it
    (("thigh_l", "upper_arm_r", "head"), ()),
])
def test_an_elbow_or_knee_is_not_reported_without_its_distal_section(unfitted, dropped):
    """`_reported_joints`: the elbow (knee) of an unfitted forearm (lower leg), which only the upper
    arm's (thigh's) model length would place, is left out; every other joint is kept as it was."""
    from bodyscan.recon.posture.fit import _reported_joints

    names = ["pelvis", "chest", "neck", "head"] + [f"{j}_{s}" for j in ("shoulder", "elbow", "wrist", "hip",
                                                                        "knee", "ankle") for s in "lr"]
    joints = {n: np.full(3, float(i)) for i, n in enumerate(names)}
    got = _reported_joints(joints, set(unfitted))
    assert set(got) == set(names) - set(dropped)
    assert all(got[n] is joints[n] for n in got)


def _column_mesh(start, end, a, b):
    """A capsule from ``start`` to ``end`` with radius ``a`` towards world x (the body's left-right, as
    the model's sections are wide: not `recon.geometry.frames_from_dirs`, whose x is arbitrary about
    the axis) and ``b`` across both."""
    import trimesh

    start, end = np.asarray(start, float), np.asarray(end, float)
    L = float(np.linalg.norm(end - start))
    d = (end - start) / L
    m = trimesh.creation.capsule(height=L, radius=b, count=[32, 32])
    m.apply_scale([a / b, 1.0, 1.0])
    fx = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    fx = fx - d * (fx @ d)
    fx /= np.linalg.norm(fx)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([fx, np.cross(d, fx), d])
    T[:3, 3] = (start + end) / 2
    return m.apply_transform(T)


def _articulated_body(rng, stature=1.75):
    """A body made of the model's own sections (`recon.posture.bodymodel`: its proportions and
    radii at ``stature``), facing -y, in a random pose: each arm abducted 25-75 degrees, raised
    forward up to 40 and its elbow flexed up to 80; each leg abducted up to 12 degrees, the hip
    flexed -10 to 35 and the knee up to 45. Returns the mesh and its joints (section ends; wrists
    and ankles a forearm and a shank from the elbows and knees)."""
    import trimesh

    from bodyscan.recon.geometry import rotvec
    from bodyscan.recon.posture.bodymodel import _F, standard_body

    def turn(axis, deg):
        return rotvec(np.radians(deg) * axis)

    body, H = standard_body(stature), stature
    X, Y, Z = np.eye(3)
    J = {"pelvis": np.array([0.0, 0.0, 0.53 * H])}
    J["chest"] = J["pelvis"] + _F["chest"] * H * Z
    J["neck"] = J["pelvis"] + _F["neck"] * H * Z
    parts = [_column_mesh(J["pelvis"], J["chest"], *body.radii("waist")),
             _column_mesh(J["chest"], J["neck"], *body.radii("chest")),
             _column_mesh(J["neck"], J["neck"] + _F["head"] * H * Z, *body.radii("head"))]
    for s, side in (("l", 1.0), ("r", -1.0)):
        root = J["pelvis"] + np.array([side * _F["shoulder_x"], 0.0, _F["shoulder_z"]]) * H
        up = turn(X, -rng.uniform(-10, 40)) @ turn(Y, -side * rng.uniform(25, 75)) @ -Z
        mid = root + _F["upper_arm"] * H * up
        low = turn(X, -rng.uniform(0, 80)) @ up
        J[f"shoulder_{s}"], J[f"elbow_{s}"], J[f"wrist_{s}"] = root, mid, mid + _F["forearm"] * H * low
        parts += [_column_mesh(root, mid, *body.radii("upper_arm")),
                  _column_mesh(mid, mid + (_F["forearm"] + _F["hand"]) * H * low, *body.radii("forearm"))]
        root = J["pelvis"] + np.array([side * _F["hip_x"], 0.0, _F["hip_z"]]) * H
        up = turn(X, -rng.uniform(-10, 35)) @ turn(Y, -side * rng.uniform(0, 12)) @ -Z
        mid = root + _F["thigh"] * H * up
        low = turn(X, rng.uniform(0, 45)) @ up
        J[f"hip_{s}"], J[f"knee_{s}"], J[f"ankle_{s}"] = root, mid, mid + _F["lower_leg"] * H * low
        parts += [_column_mesh(root, mid, *body.radii("thigh")),
                  _column_mesh(mid, mid + (_F["lower_leg"] + _F["foot_height"]) * H * low, *body.radii("lower_leg"))]
    mesh = trimesh.util.concatenate(parts)
    lift = np.array([0.0, 0.0, -mesh.vertices[:, 2].min()])
    mesh.apply_translation(lift)
    return mesh, {k: v + lift for k, v in J.items()}


def _limb_targets_met(seed: int, turn: float = 0.0, preset: str = "paper") -> bool:
    """Whether the fit of `_articulated_body` of ``seed``, turned ``turn`` degrees about the
    vertical in the scanner (``preset``, 10 mm, k = 1, no noise), meets issue 4's targets on the limb
    joints (median at most 4 cm, none over 10 cm, at least 10 of the 12 given). The trunk's joints
    follow the rig's anatomy (the pelvis above the crotch, the spine behind the torso's axis),
    which a body of columns does not have: they are left out."""
    from bodyscan import simulator

    limbs = [f"{j}_{s}" for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle") for s in "lr"]
    mesh, joints = _articulated_body(np.random.default_rng(seed))
    R = _rz(turn)
    mesh.vertices = mesh.vertices @ R.T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(mesh, simulator.preset(preset, resolution=0.01, k=1, noise_sigma=0.0))
        try:
            fit = estimate_posture(scan.points, view_dir=scan.view_dir, head=scan.head)
        except ReconError:
            return False
    err = [np.linalg.norm(fit.joints[k] - R @ joints[k]) for k in limbs if k in fit.joints]
    return len(err) >= 10 and np.median(err) <= 0.04 and max(err) <= 0.10


def test_the_fit_recovers_the_limb_joints_of_an_articulated_body_across_random_poses():
    """Issue 16's analytic test: bodies made of the model's own sections in 8 random poses, scanned
    and fitted (`_limb_targets_met`): at least 6 of 8 meet issue 4's targets on the limb joints (all
    8 where this was written, medians 2.9-3.7 cm; the fit is chaotic, so the count has slack).
    Joints 6 cm off fail every pose."""
    met = [_limb_targets_met(seed) for seed in range(8)]
    assert sum(met) >= 6, met


def test_the_fit_recovers_the_limb_joints_of_articulated_bodies_turned_in_the_scanner():
    """The same bodies turned 90 degrees in the scanner, 16 poses: the cameras see their sides, and
    the trunk's front and back, along the lines of sight, not at all. The volume is enclosed
    between the views (`voxelize`'s ``behind``), so at least 8 of 16 meet the targets (11 where
    this was written; 2 when the volume was enclosed by the closing and the in-plane test alone)."""
    met = [_limb_targets_met(seed, 90.0) for seed in range(16)]
    assert sum(met) >= 8, met


def test_the_fit_recovers_the_limb_joints_of_turned_articulated_bodies_seen_in_perspective():
    """The same 16 turned bodies seen by the `scanner` preset's perspective heads, from 2 m at
    1.1 m high: the volume is enclosed between their views (their shared shadows beyond the body
    in), so at least 8 of 16 meet the targets."""
    met = [_limb_targets_met(seed, 90.0, "scanner") for seed in range(16)]
    assert sum(met) >= 8, met
