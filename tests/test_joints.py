"""The reported sections (`recon.posture.joints`): where they start and how thick they are, against the
ground truth's labels."""

import warnings

import numpy as np
import pytest

from bodyscan.recon import estimate_posture
from bodyscan.recon.posture.bodymodel import SHOULDER_CAP, UPPER_ARM_SHAPE
from bodyscan.recon.posture.joints import joint_caps, shape_limbs
from bodyscan.recon.model import SECTIONS, SectionShape

X, Y, Z = np.eye(3)


def _torso_and_arm(arm_axis):
    """A chest (wider across x than deep along y, axis +z) and a round left upper arm (radius
    4.5 cm) hanging from its shoulder along the unit ``arm_axis``."""
    chest = SectionShape("chest", [0, 0, 1.15], [0, 0, 1.50], [0.16, 0.11], X)
    top = np.array([0.19, 0.0, 1.40])
    helper = Z if abs(arm_axis @ Z) < 0.9 else X
    arm = SectionShape("upper_arm_l", top, top + 0.27 * np.asarray(arm_axis, float), [0.045, 0.045],
                       np.cross(arm_axis, helper))
    return {"chest": chest, "upper_arm_l": arm}


def test_upper_arm_is_deeper_front_to_back_with_its_area_kept():
    secs = _torso_and_arm(-Z)
    out = shape_limbs(secs)
    a = out["upper_arm_l"]
    assert np.allclose(a.radii, 0.045 * np.asarray(UPPER_ARM_SHAPE))
    assert a.radii[0] > 1.2 * a.radii[1]
    assert abs(a.frame_x @ Y) > 0.999          # the larger radius runs front to back
    assert np.isclose(np.prod(a.radii), 0.045 ** 2, rtol=1e-3)
    assert np.allclose(a.start, secs["upper_arm_l"].start) and np.allclose(a.end, secs["upper_arm_l"].end)
    # applied once: an elliptic arm is left alone
    again = shape_limbs(out)["upper_arm_l"]
    assert np.allclose(again.radii, a.radii)
    assert out["chest"] is secs["chest"]


def test_upper_arm_held_forward_keeps_its_round_section():
    out = shape_limbs(_torso_and_arm(-Y))["upper_arm_l"]
    assert np.allclose(out.radii, [0.045, 0.045])
    # raised sideways (t_pose): front to back is still across the arm
    side = shape_limbs(_torso_and_arm(X))["upper_arm_l"]
    assert abs(side.frame_x @ Y) > 0.999 and side.radii[0] > side.radii[1]


def test_shoulder_cap_reaches_further_along_a_hanging_arm_than_a_raised_one():
    caps = {}
    for name, d in (("down", -Z), ("sideways", X), ("raised", np.array([0.34, 0.0, 0.94]))):
        caps[name] = joint_caps(_torso_and_arm(d))["upper_arm_l"].caps
    rmin = 0.045 * min(UPPER_ARM_SHAPE)
    assert np.isclose(caps["down"][0], (SHOULDER_CAP[0] + SHOULDER_CAP[1]) * rmin)
    assert caps["down"][0] > caps["sideways"][0] > caps["raised"][0] >= 0.0
    # the elbow end stays a flat joint cap
    assert np.isclose(caps["down"][1], 0.5 * rmin)


@pytest.fixture(scope="module")
def limb_scans():
    from bodyscan.benchmarks.oracle import fit_from_body
    from bodyscan.poses import load_body
    from bodyscan.simulator.config import preset
    from bodyscan.simulator.scan import scan

    out = {}
    for name in ("standing", "arms_close", "seated"):
        body = load_body(name)
        s = scan(body, preset("paper"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = estimate_posture(s.points, view_dir=s.view_dir)
        out[name] = (np.asarray(s.points), np.asarray(s.gt_section), fit, fit_from_body(body))
    return out


def test_reported_upper_arm_reaches_the_labelled_shoulder(limb_scans):
    """Estimated posture, `paper` scans: the reported upper arm's larger radius runs as the
    oracle's (the labels' principal direction), and it reaches (within T_d = 0.3 of its width) more
    of the points labelled upper arm than the fitted round arm did (measured 0.81-0.97 -> 0.87-0.99
    of them, mean gain 0.065), while the chest's points stay out of its reach (at most 4.3 %)."""
    gains = []
    for name, (p, gt, fit, oracle) in limb_scans.items():
        if name == "seated":   # the arms as standing
            continue
        for side in ("l", "r"):
            sec = f"upper_arm_{side}"
            rep, ora = fit.sections[sec], oracle.sections[sec]
            assert abs(rep.frame_x @ ora.frame_x) > np.cos(np.radians(20)), (name, sec)
            r = float(np.sqrt(np.prod(rep.radii)))
            round_arm = rep.replace(radii=[r, r], caps=[0.5 * r, rep.caps[1]])
            arm, chest = p[gt == SECTIONS.index(sec)], p[gt == SECTIONS.index("chest")]

            def reach(shape, q):
                return float(np.mean(np.abs(shape.coords(q)[0]) < 0.3 * shape.width))

            assert reach(rep, arm) > reach(round_arm, arm), (name, sec)
            assert reach(rep, chest) < 0.06, (name, sec)
            gains.append(reach(rep, arm) - reach(round_arm, arm))
    assert np.mean(gains) > 0.04


def test_reported_lower_leg_reaches_the_labelled_calf(limb_scans):
    """Estimated posture, `paper` scans, standing and seated: the reported lower leg's larger
    radius runs front to back as the oracle's, and it reaches more of the points labelled lower leg
    than the fitted round one did (the foot, in the lower leg's labels, stays out of reach: measured
    0.50-0.91 -> 0.63-0.93, mean gain 0.086), while the thigh's points it reaches grow by less
    than 4 % of them (measured 0.4-0.8 % standing and arms_close, 2.9-3.6 % seated: its deeply bent
    knees, on the lower leg's axis since `recon.posture.joints.bent_knee`, start the lower legs nearer the
    thigh's underside; seated's section accuracy rose 0.956 -> 0.964 with that change)."""
    gains = []
    for name, (p, gt, fit, oracle) in limb_scans.items():
        for side in ("l", "r"):
            sec = f"lower_leg_{side}"
            rep, ora = fit.sections[sec], oracle.sections[sec]
            assert abs(rep.frame_x @ ora.frame_x) > np.cos(np.radians(25)), (name, sec)
            r = float(np.sqrt(np.prod(rep.radii)))
            round_leg = rep.replace(radii=[r, r])
            leg, thigh = p[gt == SECTIONS.index(sec)], p[gt == SECTIONS.index(f"thigh_{side}")]

            def reach(shape, q):
                return float(np.mean(np.abs(shape.coords(q)[0]) < 0.3 * shape.width))

            assert reach(rep, leg) > reach(round_leg, leg), (name, sec)
            assert reach(rep, thigh) < reach(round_leg, thigh) + 0.04, (name, sec)
            gains.append(reach(rep, leg) - reach(round_leg, leg))
    assert np.mean(gains) > 0.05
