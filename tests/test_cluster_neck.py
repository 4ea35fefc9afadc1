"""`recon.posture.joints.centre_neck`: the reported chest's top midway between the sides of the neck."""

import numpy as np

from bodyscan.recon.posture.joints import NECK_SLAB, centre_neck
from bodyscan.recon.model import SectionShape


def _col(name, start, end, radii, frame_x=(1.0, 0, 0)):
    return SectionShape(name=name, start=np.asarray(start, float), end=np.asarray(end, float),
                        radii=np.asarray(radii, float), frame_x=np.asarray(frame_x, float))


def _neck_points(centre_x, z0, z1, radius=0.05, n=400):
    """(n, 3) points on a vertical neck cylinder about x = centre_x, y = 0, between z0 and z1."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(z0, z1, n)
    return np.column_stack([centre_x + radius * np.cos(a), radius * np.sin(a), z])


def _body(top_x):
    """A chest from (0, 0, 1.2) to (top_x, 0, 1.55), a head hanging from its top to (0, 0, 1.8),
    a right arm hanging beside the chest."""
    chest = _col("chest", (0, 0, 1.2), (top_x, 0, 1.55), (0.17, 0.10))
    head = _col("head", chest.end, (0, 0, 1.8), (0.08, 0.09))
    ua = _col("upper_arm_r", (-0.2, 0, 1.45), (-0.2, 0, 1.17), (0.045, 0.045))
    fa = _col("forearm_r", ua.end, (-0.22, -0.05, 0.80), (0.035, 0.035))
    return {"chest": chest, "head": head, "upper_arm_r": ua, "forearm_r": fa}


def test_centre_neck_moves_the_chest_top_to_the_neck_and_keeps_the_measured_ends():
    secs = _body(top_x=0.06)   # the fitted chest top 6 cm to the side of the true neck at x = 0
    L = secs["head"].length
    z0 = 1.55 + NECK_SLAB[0] * L
    pts = _neck_points(0.0, z0, 1.55 + NECK_SLAB[1] * L)
    out = centre_neck(pts, secs)
    # the neck's sides are at x = +-5 cm: the chest's top moves most of the way to x = 0 (the slab
    # is cut across the head's axis, which leans with the old top: its midpoint falls a little short)
    assert 0.0 < out["chest"].end[0] < 0.3 * 0.06
    assert np.allclose(out["chest"].start, secs["chest"].start)
    # the head hangs from the moved neck and keeps its top (the crown)
    assert np.allclose(out["head"].start, out["chest"].end)
    assert np.allclose(out["head"].end, secs["head"].end)
    # the arm slides along its own axis only; the forearm keeps its end (the fingertips)
    ua0, ua1 = secs["upper_arm_r"], out["upper_arm_r"]
    d = ua1.start - ua0.start
    assert np.linalg.norm(np.cross(d, ua0.axis)) < 1e-9 and np.linalg.norm(d) > 1e-3
    assert np.allclose(ua1.axis, ua0.axis) and abs(ua1.length - ua0.length) < 1e-12
    assert np.allclose(out["forearm_r"].start, ua1.end)
    assert np.allclose(out["forearm_r"].end, secs["forearm_r"].end)
    # turning the chest's top toward -x about its lower end lowers the shoulder on the -x side
    assert ua1.start[2] < ua0.start[2]


def test_centre_neck_leaves_a_centred_neck_and_a_slab_wider_than_the_head_alone():
    secs = _body(top_x=0.0)
    L = secs["head"].length
    z0, z1 = 1.55 + NECK_SLAB[0] * L, 1.55 + NECK_SLAB[1] * L
    out = centre_neck(_neck_points(0.0, z0, z1), secs)
    assert np.allclose(out["chest"].end, secs["chest"].end, atol=2e-3)
    # arms raised beside the head: the slab is no neck, nothing moves
    wide = np.vstack([_neck_points(0.0, z0, z1), _neck_points(0.11, z0, z1, radius=0.03),
                      _neck_points(-0.11, z0, z1, radius=0.03)])
    assert centre_neck(wide, secs) is secs
    # no points in the slab, or no head: unchanged
    assert centre_neck(np.zeros((0, 3)), secs) is secs
    nohead = {k: v for k, v in secs.items() if k != "head"}
    assert centre_neck(_neck_points(0.0, z0, z1), nohead) is nohead
