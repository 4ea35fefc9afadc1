"""Section geometry against analytic distances."""

import numpy as np
import pytest

from bodyscan.recon.model import SECTIONS, SectionShape, section_coords


def _cyl(**kw):
    args = dict(name="thigh_l", start=[0, 0, 0], end=[0, 0, 1.0], radii=[0.1, 0.1], frame_x=[1, 0, 0])
    args.update(kw)
    return SectionShape(**args)


def test_cylinder_coords_are_exact():
    s = _cyl()
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, 2 * np.pi, 200)
    h = rng.uniform(0, 1, 200)
    rho = rng.uniform(0.0, 0.3, 200)
    p = np.c_[rho * np.cos(theta), rho * np.sin(theta), h]
    r, t, hh = s.coords(p)
    np.testing.assert_allclose(r, rho - 0.1, atol=1e-12)
    np.testing.assert_allclose(hh, h, atol=1e-12)
    ok = rho > 1e-9
    np.testing.assert_allclose(np.cos(t[ok]), np.cos(theta[ok]), atol=1e-9)


def test_hemisphere_caps_and_open_end():
    s = _cyl()
    # beyond the closed end: distance to the sphere of radius 0.1 around the end point
    p = np.array([[0.0, 0.0, 1.5], [0.3, 0.0, 1.4], [0.0, 0.0, -0.05]])
    r, _, _ = s.coords(p)
    np.testing.assert_allclose(r, [0.4, 0.5 - 0.1, -0.05], atol=1e-12)
    # an open end extends the column
    r_open, _, _ = s.replace(closed=(True, False)).coords(p)
    np.testing.assert_allclose(r_open[:2], [-0.1, 0.2], atol=1e-12)


def test_elliptic_column_surface_points_have_zero_r():
    s = _cyl(radii=[0.15, 0.08], frame_x=[1, 1, 0], start=[0.2, 0.1, 0.5], end=[0.3, -0.2, 1.4])
    pts = s.surface_points(36, 10)
    r, _, _ = s.coords(pts)
    np.testing.assert_allclose(r, 0.0, atol=1e-9)
    assert s.width == pytest.approx(0.3)
    assert not s.is_cylinder


def test_section_coords_fills_missing_sections_with_nan():
    r, theta, h = section_coords({"thigh_l": _cyl()}, np.zeros((5, 3)) + [0.2, 0, 0.5])
    assert r.shape == (5, len(SECTIONS))
    j = SECTIONS.index("thigh_l")
    np.testing.assert_allclose(r[:, j], 0.1)
    assert np.isnan(np.delete(r, j, axis=1)).all()


def test_degenerate_section_is_rejected():
    with pytest.raises(ValueError):
        _cyl(end=[0, 0, 0])
    with pytest.raises(ValueError):
        _cyl(frame_x=[0, 0, 1])


def test_recon_sections_match_body_format():
    from bodyscan import poses
    assert SECTIONS == poses.SECTIONS


def test_bodyfit_json_roundtrip():
    import json
    from bodyscan.recon.model import BodyFit, adjacency_matrix
    fit = BodyFit(sections={"thigh_l": _cyl(closed=(True, False))}, joints={"hip_l": np.array([0.1, 0, 0.9])},
                  residuals={"thigh_l": 0.004}, unfitted=("head",))
    back = BodyFit.from_dict(json.loads(json.dumps(fit.to_dict())))
    s = back.sections["thigh_l"]
    assert s.closed == (True, False)
    np.testing.assert_allclose(s.end, [0, 0, 1.0])
    assert back.residuals == {"thigh_l": 0.004} and back.unfitted == ("head",)
    m = adjacency_matrix()
    assert m.sum() == 20 and (m == m.T).all()


def test_bodyfit_seams_are_kept_apart_from_the_joints():
    """A fit's seams (where the clustering cuts) survive the fit file and a rigid motion apart from
    its joints; a fit file without seams (written before they were kept) cuts at its joints."""
    import json
    from bodyscan.recon.geometry import rotvec
    from bodyscan.recon.model import BodyFit
    joints = {"hip_l": np.array([0.1, 0.04, 0.9])}
    seams = {"hip_l": np.array([0.08, 0.0, 0.92])}
    fit = BodyFit(sections={"thigh_l": _cyl()}, joints=joints, seams=seams)
    d = json.loads(json.dumps(fit.to_dict()))
    back = BodyFit.from_dict(d)
    np.testing.assert_array_equal(back.joints["hip_l"], joints["hip_l"])
    np.testing.assert_array_equal(back.seams["hip_l"], seams["hip_l"])
    R, t = rotvec(np.array([0.0, 0.0, 0.7])), np.array([1.0, -2.0, 0.5])
    moved = back.moved(R, t)
    np.testing.assert_allclose(moved.joints["hip_l"], R @ joints["hip_l"] + t)
    np.testing.assert_allclose(moved.seams["hip_l"], R @ seams["hip_l"] + t)
    del d["seams"]
    old = BodyFit.from_dict(d)
    np.testing.assert_array_equal(old.seams["hip_l"], joints["hip_l"])
    assert BodyFit(sections={}, joints=joints).seams is joints
