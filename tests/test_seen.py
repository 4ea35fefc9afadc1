"""The fitted model against the cameras' view (recon.posture.seen): analytic bodies scanned by ideal
front and rear parallel cameras; a model placed where the scan has it is confirmed, one moved into
the air the cameras looked through, or to other depths, is not."""

import numpy as np
import pytest

from bodyscan.recon import ReconError
from bodyscan.recon.model import BodyFit, SectionShape
from bodyscan.recon.params import FitParams
from bodyscan.recon.posture.fit import _check_seen, _views
from bodyscan.recon.posture.seen import _surface, agreement, confirmed_fraction, scan_views
from views import front_rear_zbuffer

TRUNK = SectionShape(name="chest", start=np.array([0.0, 0.0, 0.8]), end=np.array([0.0, 0.0, 1.4]),
                     radii=np.array([0.15, 0.10]), frame_x=np.array([1.0, 0.0, 0.0]))
ARM = SectionShape(name="upper_arm_l", start=np.array([0.22, 0.0, 1.35]), end=np.array([0.22, 0.0, 1.05]),
                   radii=np.array([0.04, 0.04]), frame_x=np.array([1.0, 0.0, 0.0]))


def _scan(secs, step=0.01):
    """The union of ``secs``' surfaces as the front and rear cameras see it on a ``step`` grid:
    points (n, 3) and their view directions (n, 3)."""
    P, N = map(np.concatenate, zip(*(_surface(s, 0.002) for s in secs)))
    outside = ~np.any([s.contains(P - 1e-4 * N) & (s.distance(P) > 1e-3) for s in secs], axis=0)
    P, N = P[outside], N[outside]
    keep, vd = front_rear_zbuffer(P, N, step)
    return P[keep], vd[keep]


@pytest.fixture(scope="module")
def views():
    pts, vd = _scan([TRUNK, ARM])
    return scan_views(pts, vd, min_pixel=0.01)


def test_the_model_where_the_scan_has_it_is_confirmed(views):
    ag = agreement({"chest": TRUNK, "upper_arm_l": ARM}, views, 0.03)
    for name, (shown, confirmed) in ag.items():
        assert shown > 100, name                       # both cameras see both sections
        assert confirmed >= 0.95 * shown, (name, shown, confirmed)
    assert confirmed_fraction({"chest": TRUNK, "upper_arm_l": ARM}, views, 0.03) >= 0.95


def test_an_arm_moved_into_the_air_the_cameras_looked_through_is_contradicted(views):
    # in front of the trunk, 20 cm toward the front camera: the camera saw the chest behind it
    moved = ARM.moved(np.eye(3), np.array([-0.22, -0.20, 0.0]))
    secs = {"chest": TRUNK, "upper_arm_l": moved}
    shown, confirmed = agreement(secs, views, 0.03)["upper_arm_l"]
    assert shown > 100 and confirmed <= 0.05 * shown
    assert confirmed_fraction(secs, views, 0.03) < confirmed_fraction({"chest": TRUNK, "upper_arm_l": ARM}, views, 0.03) - 0.03
    # the trunk behind it is hidden from the front camera by the model's own arm, not contradicted
    s, c = agreement(secs, views, 0.03)["chest"]
    assert c >= 0.95 * s


def test_an_arm_at_another_depth_is_contradicted_within_the_tolerance():
    # the true arm 6 cm in front of the trunk's side plane, the model's in that plane: both cameras
    # see it, at a depth 6 cm off (more than the 3 cm tolerance) or, at 2 cm off, confirmed
    pts, vd = _scan([TRUNK, ARM.moved(np.eye(3), np.array([0.0, -0.06, 0.0]))])
    v = scan_views(pts, vd, min_pixel=0.01)
    far = agreement({"chest": TRUNK, "upper_arm_l": ARM}, v, 0.03)["upper_arm_l"]
    near = agreement({"chest": TRUNK, "upper_arm_l": ARM.moved(np.eye(3), np.array([0.0, -0.04, 0.0]))},
                     v, 0.03)["upper_arm_l"]
    assert far[1] < 0.1 * far[0]
    assert near[1] > 0.9 * near[0]


def test_a_fit_the_cameras_contradict_is_refused(views):
    pts, vd = _scan([TRUNK, ARM])
    right = BodyFit(sections={"chest": TRUNK, "upper_arm_l": ARM}, joints={})
    cams = _views(pts, vd, None, FitParams())
    _check_seen(right, cams, FitParams())           # passes
    # the whole model 15 cm toward the front camera: everything it shows lies in seen air
    wrong = right.moved(np.eye(3), np.array([0.0, -0.15, 0.0]))
    with pytest.raises(ReconError, match="confirms only"):
        _check_seen(wrong, cams, FitParams())
    _check_seen(wrong, cams, FitParams(fit_min_agreement=0.0))   # off


def test_a_trunk_the_cameras_contradict_is_not_hidden_by_limbs_that_agree(views):
    # the trunk 15 cm toward the front camera, the arm where the scan has it: the trunk's own
    # surface is all in seen air, so the check's fraction is the trunk's (none), not the whole
    # model's (the arm's confirmed surface would lift it)
    from bodyscan.recon.posture.seen import confirmed_parts

    moved = TRUNK.moved(np.eye(3), np.array([0.0, -0.15, 0.0]))
    secs = {"chest": moved, "upper_arm_l": ARM}
    parts = confirmed_parts(secs, views, 0.03)
    assert parts["trunk"] < 0.05 and parts["limbs"] > 0.5, parts
    assert confirmed_fraction(secs, views, 0.03) == parts["trunk"]
    a = np.array(list(agreement(secs, views, 0.03).values())).sum(axis=0)
    assert a[1] / a[0] > 0.1                  # summed over both sections, the arm lifted it
