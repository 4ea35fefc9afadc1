"""Completion beyond the paper (recon.surface.complete, recon.surface.closed): hands and feet meshed, holes filled, a closed surface."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from bodyscan.benchmarks.metrics import is_watertight
from bodyscan.recon import ReconParams, reconstruct
from bodyscan.recon.clustering.cluster import assign_extremities
from bodyscan.recon.posture.extremities import place_extremities
from bodyscan.recon.surface.closed import grid_surface, radial_field, seen_distance
from bodyscan.recon.views import seen_air
from bodyscan.recon.model import SECTIONS, BodyFit, SectionShape
from bodyscan.recon.surface.mesh import face_areas, model_outward
from test_pipeline import capsule_body
from views import front_rear_zbuffer

FOREARM, LOWER_LEG = SECTIONS.index("forearm_l"), SECTIONS.index("lower_leg_l")
HAND, FOOT = 11, 12   # labels of the extremities' true points (scored as forearm / lower leg)


def extremities(fit):
    """A flat hand below the left forearm and a foot turned out from the left lower leg (not in the
    fit: the paper's model has neither)."""
    fa, ll = fit.sections["forearm_l"], fit.sections["lower_leg_l"]
    hand = SectionShape("hand", fa.end + (0, 0, 0.01), fa.end - (0, 0, 0.13), (0.045, 0.015), (1.0, 0, 0))
    ankle = ll.end
    foot = SectionShape("foot", ankle + (-0.03, 0, -0.02), ankle + (0.16, -0.02, -0.03), (0.04, 0.03), (0, 1.0, 0))
    return hand, foot


@pytest.fixture(scope="module")
def with_hand_and_foot():
    """The capsule body with a hand and a foot, scanned front and rear on a 10 mm grid."""
    P, L, N, vd, fit = capsule_body()
    hand, foot = extremities(fit)
    pts, lab, nrm = [P], [L], [N]
    for k, sh in ((HAND, hand), (FOOT, foot)):
        p = sh.surface_points(n_theta=int(2 * np.pi * sh.radii.max() / 0.003), n_h=int(sh.length / 0.003))
        pts.append(p)
        lab.append(np.full(len(p), k))
        nrm.append(model_outward(sh, p))
    P, L, N = np.concatenate(pts), np.concatenate(lab), np.concatenate(nrm)
    shapes = list(fit.sections.values()) + [hand, foot]
    own = {**{j: fit.sections[n] for j, n in enumerate(SECTIONS)}, HAND: hand, FOOT: foot}
    inside = np.zeros(len(P), bool)
    for j, sh in own.items():
        inside |= (sh.coords(P)[0] < -1e-4) & (L != j)
    P, L, N = P[~inside], L[~inside], N[~inside]
    # front and rear z-buffer on a 10 mm grid (as capsule_body)
    keep, vd = front_rear_zbuffer(P, N, 0.01)
    P = P[keep] + np.random.default_rng(0).normal(0, 0.0005, (keep.sum(), 3))
    return P, L[keep], vd[keep], fit, shapes


def outside(shapes, x):
    """(k,) distance (metres) of ``x`` outside the union of ``shapes`` (<= 0 inside)."""
    return np.min([s.coords(x)[0] for s in shapes], axis=0)


def with_joints(fit):
    """The capsule fit with the left wrist and ankle (joints and seams) at its forearm's and lower
    leg's ends."""
    joints = {**fit.joints, "wrist_l": fit.sections["forearm_l"].end, "ankle_l": fit.sections["lower_leg_l"].end}
    return replace(fit, joints=joints, seams=joints)


def test_the_fit_places_the_hand_and_the_foot_and_the_clustering_gives_them_their_points(with_hand_and_foot):
    P, L, vd, fit, shapes = with_hand_and_foot
    placed = place_extremities(P, with_joints(fit))
    assert set(placed.extremities) == {"hand_l", "foot_l"}     # no right wrist or ankle in this fit
    assert all(placed.sections[k] is fit.sections[k] for k in fit.sections)   # the paper's 11 untouched
    for name, true in (("hand_l", shapes[-2]), ("foot_l", shapes[-1])):
        got = placed.extremities[name]
        assert abs(got.axis @ true.axis) > np.cos(np.radians(10))
        tip = lambda s: s.end + s.caps[1] * s.axis   # noqa: E731
        assert np.linalg.norm(tip(got) - tip(true)) < 0.03     # three pixels of the 10 mm scan
        assert abs(got.radii.max() - true.radii.max()) < 0.01
    back = BodyFit.from_dict(json.loads(json.dumps(placed.to_dict())))     # the fit file keeps them
    assert np.allclose(back.extremities["foot_l"].end, placed.extremities["foot_l"].end)
    old = placed.to_dict()
    del old["extremities"]
    assert BodyFit.from_dict(old).extremities == {}       # an old fit file has none
    member = np.zeros((len(P), len(SECTIONS)), bool)
    member[np.arange(len(P)), np.clip(L, 0, len(SECTIONS) - 1)] = L < len(SECTIONS)
    ext = assign_extremities(P, member, placed)
    for k, label, parent in ((0, HAND, FOREARM), (2, FOOT, LOWER_LEG)):   # hand_l, foot_l: EXTREMITIES' order
        assert (ext[L == label] == k).mean() > 0.9
        assert (L[(ext == k) & (L != label)] == parent).all()     # else only its section's end, past the joint


def test_the_hand_radii_fit_minimises_the_column_distance_with_its_exact_derivatives():
    """`_radii`'s residuals are an open column's signed distances (`SectionShape.coords`' r), and
    their analytic Jacobian is the finite-difference one; on points of a known flat column the fit
    recovers its radii."""
    from bodyscan.recon.posture.extremities import _open_distance, _open_distance_jac, _radii

    true = SectionShape("hand", np.zeros(3), np.array([0.0, 0.0, 0.12]), (0.045, 0.015), (1.0, 0.0, 0.0),
                        closed=(False, False))
    rng = np.random.default_rng(1)
    q = rng.uniform(-0.06, 0.06, (200, 3)) + (0, 0, 0.06)
    x2, y2 = q[:, 0] ** 2, q[:, 1] ** 2
    ab = np.array([0.04, 0.02])
    assert np.allclose(_open_distance(ab, x2, y2), true.replace(radii=ab).coords(q)[0], atol=1e-12)
    h = 1e-7 * np.eye(2)   # central differences by each radius
    numeric = np.column_stack([(_open_distance(ab + d, x2, y2) - _open_distance(ab - d, x2, y2)) / 2e-7 for d in h])
    assert np.allclose(_open_distance_jac(ab, x2, y2), numeric, rtol=1e-4, atol=1e-5)
    on = true.surface_points(n_theta=48, n_h=12)
    on = on[(on[:, 2] > 0) & (on[:, 2] < 0.12)]
    got = _radii(on, true.replace(radii=np.array([0.03, 0.03]), closed=(False, True), caps=(0.03, 0.03)))
    assert np.allclose(got.radii, true.radii, atol=1e-4)


def test_hand_and_foot_are_meshed_and_joined_without_air(with_hand_and_foot):
    P, L, vd, fit, shapes = with_hand_and_foot
    fit = with_joints(fit)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paper = reconstruct(P, "proposed", ReconParams.from_overrides({"far_charts": False, "extremities": False}),
                            view_dir=vd, fit=fit)
        rec = reconstruct(P, "proposed", view_dir=vd, fit=fit)
        # the same triangles over the points, unsplit: their sections beside the points' labels
        flat = reconstruct(P, "proposed", ReconParams.from_overrides({"curve_edge": 0}), view_dir=vd, fit=fit)
    assert np.array_equal(np.sort(flat.faces, axis=1), np.sort(rec.point_faces, axis=1))
    assert set(rec.fit.extremities) == {"hand_l", "foot_l"} and not paper.fit.extremities
    ext = np.isin(L, [HAND, FOOT])
    used = np.zeros(len(P), bool)
    used[rec.point_faces.ravel()] = True
    used_paper = np.zeros(len(P), bool)
    used_paper[paper.point_faces.ravel()] = True
    assert used[ext].mean() > 0.95 > 0.7 > used_paper[ext].mean()
    assert rec.points_unmeshed < paper.points_unmeshed
    lab = L[flat.faces]
    for part, section in ((HAND, FOREARM), (FOOT, LOWER_LEG)):
        assert ((lab == part).any(axis=1) & (lab == section).any(axis=1)).any()   # joined
        # scored as its section (the hand's points within T_d of the waist are the clustering's)
        assert np.mean(flat.face_section[(lab == part).all(axis=1)] == section) > 0.5
    for r in (rec, flat):
        area = face_areas(r.vertices, r.faces)
        air = outside(shapes, r.vertices[r.faces].mean(axis=1)) > 0.005
        assert area[air].sum() < 0.005 * area.sum()


def test_a_known_hole_is_filled_within_2mm_of_the_surface():
    """A bulging column r(theta, h) = 5 cm + 0.5 cm sin(h / 10 cm) + 0.3 cm cos(2 theta) seen on
    a 3 mm grid, a 6 cm x 8 cm patch missing: the filled cells lie within 2 mm of it (the
    harmonic fill is flatter than the surface: twice these bulges, 3.1 mm)."""
    def radius(t, h):
        return 0.05 + 0.005 * np.sin(h / 0.1) + 0.003 * np.cos(2 * t)

    t, h = np.meshgrid(np.arange(0, 2 * np.pi, 0.003 / 0.05), np.arange(0, 0.4, 0.003), indexing="ij")
    t, h = t.ravel(), h.ravel()
    hole = (np.abs(t - np.pi) * 0.05 < 0.03) & (np.abs(h - 0.2) < 0.04)
    t, h = t[~hole], h[~hole]
    r = radius(t, h)
    local = np.column_stack([r * np.cos(t), r * np.sin(t), h])
    cell = 0.009
    R, h0 = radial_field(local, cell)
    n_t, n_h = R.shape
    tc = (np.arange(n_t)[:, None] + 0.5) * 2 * np.pi / n_t
    hc = h0 + (np.arange(n_h)[None, :] + 0.5) * cell
    in_hole = (np.abs(tc - np.pi) * 0.05 < 0.025) & (np.abs(hc - 0.2) < 0.035)
    assert in_hole.sum() >= 20 and np.isfinite(R[in_hole]).all()
    assert np.abs(R - radius(tc, hc))[in_hole].max() < 0.002


def test_grid_surface_closes_a_sphere_and_labels_its_halves():
    g = np.indices((24, 24, 24)).astype(float) * 0.01
    d = 0.08 - np.sqrt(((g - 0.115) ** 2).sum(axis=0))
    labels = (g[2] > 0.115).astype(np.int8)      # the upper half 1, the lower 0
    v, f, lab = grid_surface(d, np.zeros(3), 0.01, labels)
    c = v[f].mean(axis=1)
    assert (lab[c[:, 2] > 0.125] == 1).all() and (lab[c[:, 2] < 0.105] == 0).all()
    m = trimesh.Trimesh(v, f, process=False)
    assert is_watertight(f) and m.is_watertight and m.is_winding_consistent
    assert m.volume > 0 and abs(m.volume / (4 / 3 * np.pi * 0.08 ** 3) - 1) < 0.05
    assert np.abs(np.linalg.norm(v - 0.115, axis=1) - 0.08).max() < 0.002


def test_grid_surface_of_a_box_on_grid_points_is_closed():
    """A cube whose faces lie exactly on grid points (values 0 there count as inside): one closed
    surface between those points and the next ones out, not duplicated vertices on the level."""
    g = np.indices((12, 12, 12)).astype(float)
    d = 3.0 - np.abs(g - 5.0).max(axis=0)            # 0 on the cube |g - 5| = 3
    v, f, _ = grid_surface(d, np.zeros(3), 0.01)
    m = trimesh.Trimesh(v, f, process=False)
    assert is_watertight(f) and m.is_watertight and m.is_winding_consistent
    assert 0.999 * 0.06 ** 3 <= m.volume <= 0.08 ** 3 and len(m.split(only_watertight=False)) == 1


def test_seen_distance_is_the_signed_distance_to_a_sphere_and_stops_at_a_hole():
    """An open sphere mesh of radius 10 cm (its cap z > 6 cm removed): the signed distance along
    its normals within 0.5 mm of the analytic one over the mesh, and `beside` past the rim."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    keep = m.triangles_center[:, 2] < 0.06
    v, f = m.vertices, m.faces[keep]
    spacing = float(m.edges_unique_length.mean())
    rng = np.random.default_rng(0)
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u = u[u[:, 2] < 0.4]
    r = rng.uniform(0.085, 0.115, len(u))
    dist, beside, _ = seen_distance(v, f, u * r[:, None], spacing)
    assert np.abs(dist - (0.1 - r)).max() < 0.0005 and beside.max() < spacing
    # the weighted mean within 5 mm of the surface only: the same there, the sign right beyond
    quick, _, _ = seen_distance(v, f, u * r[:, None], spacing, exact=0.005)
    close = np.abs(0.1 - r) < 0.004
    assert (quick[close] == dist[close]).all() and (~close).sum() > 50
    assert (np.sign(quick[~close]) == np.sign(0.1 - r[~close])).all() and np.abs(quick - (0.1 - r)).max() < 0.002
    _, beside, _ = seen_distance(v, f, np.array([[0, 0, 0.1], [0, 0, 0.0995]]), spacing)
    assert beside.min() > 0.03    # over the hole: beside the mesh, by the hole's radius


def _wall(camera):
    """A wall y = 0 on a 5 mm grid with a 3 cm hole, seen from -y: parallel (``camera`` None) or
    from the point ``camera``; (points (n, 3), view directions (n, 3))."""
    g = np.indices((41, 41)).reshape(2, -1).T * 0.005 - 0.1
    g = g[np.abs(g + 0.05).max(axis=1) > 0.015]
    pts = np.column_stack([g[:, 0], np.zeros(len(g)), g[:, 1]])
    if camera is None:
        vd = np.tile([0.0, -1.0, 0.0], (len(pts), 1))
    else:
        vd = np.asarray(camera) - pts
        vd /= np.linalg.norm(vd, axis=1, keepdims=True)
    return pts, vd


@pytest.mark.parametrize("camera", [None, (0.0, -2.0, 0.1)])
def test_seen_air_is_the_depth_in_front_of_the_seen_surface(camera):
    """A wall y = 0 with a 3 cm hole seen from -y (parallel, or from a camera 2 m away): a point in
    front of the wall is air by its depth; behind it, not; beside the wall or over the hole, unknown
    (over the hole, air when the silhouettes count)."""
    pts, vd = _wall(camera)
    at = np.array([[0.02, -0.03, 0.01], [0.02, 0.03, 0.01], [0.5, -0.03, 0.0], [-0.05, -0.01, -0.05]])
    air = seen_air(pts, vd, None, at, 0.005)
    if camera is None:
        expect = 0.03
    else:   # the ray from the camera through at[0] meets the wall at t = c_y / (c_y - x_y)
        c = np.asarray(camera)
        expect = (c[1] / (c[1] - at[0, 1]) - 1) * np.linalg.norm(at[0] - c)
    assert abs(air[0] - expect) < 0.002 and air[1] < -0.025 and (air[2:] == -np.inf).all()


def test_seen_air_has_no_holes_where_the_pixel_is_finer_than_the_scan():
    """A wall y = 0 sampled every 10 mm, seen from -y through pixels of 8 mm: every fifth row and
    column of pixels holds no point of its own, and a position 3 cm in front of the wall is air
    there too (its neighbours' depth), not unknown."""
    g = np.arange(-0.1, 0.1001, 0.01)
    x, z = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    vd = np.tile([0.0, -1.0, 0.0], (len(pts), 1))
    u = np.linspace(-0.09, 0.09, 181)
    at = np.column_stack([np.repeat(u, len(u)), np.full(u.size ** 2, -0.03), np.tile(u, len(u))])
    air = seen_air(pts, vd, None, at, 0.008)
    assert np.allclose(air, 0.03, atol=1e-9)


@pytest.mark.parametrize("camera", [None, (0.0, -2.0, 0.1)])
def test_beside_is_the_distance_to_the_silhouette_with_its_gaps_closed(camera):
    """The same wall (5 mm grid, a 3 cm hole whose nearest points are 2 cm from its middle):
    `Views.beside` is 2 cm in the hole's middle (the hole stays open when the closing is narrower
    than it, and closes when wider), 0 between neighbouring points once their gaps are closed, and
    at least the picture's margin far beside the wall."""
    from bodyscan.recon.views import Views

    pts, vd = _wall(camera)
    cams = Views(pts, vd, None, 0.005)
    at = np.array([[-0.05, -0.01, -0.05], [0.0025, -0.03, 0.0025], [0.5, -0.03, 0.0], [0.0, 0.05, 0.0]])
    scale = 1.0 if camera is None else 2.0 / 1.97     # the perspective image is at the wall's distance
    open_ = cams.beside(at)
    assert abs(open_[0] - 0.02 * scale) < 0.0015 and 0.0015 < open_[1] < 0.005
    assert open_[2] >= cams.PAD * 0.005 and open_[3] < 0.004     # far beside; behind the wall: within a gap
    closed = cams.beside(at, close=0.005)
    assert abs(closed[0] - open_[0]) < 0.0015 and closed[1] == 0 and closed[3] == 0
    assert cams.beside(at, close=0.03)[0] == 0
    projected = cams.project(at)     # projected once for both: the same values
    assert np.array_equal(cams.beside(at, close=0.005, projected=projected), closed)
    assert np.array_equal(cams.air(at, projected), cams.air(at))


def test_disc_dilation_and_closing_are_the_distance_transforms_thresholds():
    """`disc_dilation` and `disc_closing` (the silhouettes' closing in `Views.beside`) give the
    pixels of the Euclidean distance transform's thresholds, on random images, radii (some exactly
    on a pixel distance) and pixel sizes, and images smaller than the disc."""
    from scipy.ndimage import distance_transform_edt

    from bodyscan.recon.views import disc_closing, disc_dilation

    rng = np.random.default_rng(3)
    for _ in range(200):
        img = rng.random(tuple(rng.integers(1, 40, 2))) < rng.uniform(0.002, 0.9)
        step = rng.uniform(0.5, 3.0)
        r = step * rng.integers(0, 6) if rng.random() < 0.3 else rng.uniform(0.0, 12.0)
        if img.any() and (~img).any():
            assert np.array_equal(disc_dilation(img, r, step), distance_transform_edt(~img) * step <= r)
            want = distance_transform_edt(distance_transform_edt(~img) * step <= r) * step > r
            assert np.array_equal(disc_closing(img, r, step), want)


def test_closed_output_is_watertight_and_inside_the_body(with_hand_and_foot):
    P, L, vd, fit, shapes = with_hand_and_foot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(P, "proposed-closed", view_dir=vd, fit=fit)
    m = trimesh.Trimesh(rec.vertices, rec.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert (rec.point_index[:len(P)] == np.arange(len(P))).all() and (rec.point_index[len(P):] == -1).all()
    # it covers the bodies' surface: true surface points within 5 mm of it
    truth = np.concatenate([s.surface_points(48, 24) for s in shapes])
    truth = truth[outside(shapes, truth) > -1e-4]
    _, d, _ = trimesh.proximity.closest_point(m, truth)
    assert np.mean(d < 0.005) > 0.9
    # and little of it stands in the air (the strict bound: next test)
    air = outside(shapes, m.triangles_center) > 0.005
    assert m.area_faces[air].sum() < 0.06 * m.area


def test_closed_output_keeps_the_seen_surface_within_2mm(with_hand_and_foot):
    """The closed surface is as precise as the data where the scanner saw: 99 % of the true
    surface within 4 mm of a scan point lies within 2 mm of it (the height fields alone: 96.9 %,
    their 99th percentile 5 mm)."""
    P, L, vd, fit, shapes = with_hand_and_foot
    from scipy.spatial import cKDTree

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(P, "proposed-closed", view_dir=vd, fit=fit)
    m = trimesh.Trimesh(rec.vertices, rec.faces, process=False)
    truth = np.concatenate([s.surface_points(64, 32) for s in fit.sections.values()])
    truth = truth[outside(shapes, truth) > -1e-4]
    seen = truth[cKDTree(P).query(truth)[0] < 0.004]
    seen = seen[np.random.default_rng(0).choice(len(seen), 1000, replace=False)]
    _, dist, _ = trimesh.proximity.closest_point(m, seen)
    assert np.mean(dist < 0.002) > 0.99


@pytest.mark.xfail(strict=True, reason="issue 15, open: 0.003 % of the closed surface's area stands more "
                   "than 5 mm outside (max 5.9 mm), on the thigh's top beside the hip and under the "
                   "hand, where the cameras' view grazes: there the nearest depth of a pixel's "
                   "neighbours lies in front of the surface, so the carve does not reach it. Closing "
                   "the curved open surface instead brings it to 4.7 mm, but costs spurious area "
                   "on noisy scans (TUNE, scanner preset: .0520 -> .0607)")
def test_closed_output_has_no_triangle_5mm_outside_the_body(with_hand_and_foot):
    P, L, vd, fit, shapes = with_hand_and_foot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(P, "proposed-closed", view_dir=vd, fit=fit)
    v = rec.vertices[rec.faces].mean(axis=1)
    assert outside(shapes, v).max() < 0.005


def _normal_error(rec, shapes):
    """(area fraction of faces more than 30 degrees off the analytic surface's normal, most
    outside the body, metres) of a reconstruction of the capsule body."""
    t = rec.vertices[rec.faces]
    c = t.mean(axis=1)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = np.linalg.norm(n, axis=1)
    d = np.array([s.coords(c)[0] for s in shapes])
    on = np.argmin(d, axis=0)                # the shape whose surface bounds the union there
    true = np.zeros_like(c)
    for k, s in enumerate(shapes):
        true[on == k] = model_outward(s, c[on == k])
    off = np.einsum("ij,ij->i", n, true) < np.cos(np.radians(30)) * area
    return area[off].sum() / area.sum(), d.min(axis=0).max()


def test_closed_surface_smoothing_turns_the_faces_to_the_true_normals_without_moving_off(with_hand_and_foot):
    """Taubin's steps on the marching-cubes surface (`close_smooth`, twelve by default) take out
    the grid's facets and the creases of the cuts: the area more than 30 degrees off the capsule
    body's normal falls (12.2 % to 9.2 %), and the surface moves no farther out of the body (its
    farthest triangle 7.2 mm out before, 6.2 mm after)."""
    P, L, vd, fit, shapes = with_hand_and_foot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = reconstruct(P, "proposed-closed", ReconParams.from_overrides({"close_smooth": 0}),
                          view_dir=vd, fit=fit)
        smooth = reconstruct(P, "proposed-closed", view_dir=vd, fit=fit)
    assert np.array_equal(raw.faces, smooth.faces) and not np.allclose(raw.vertices, smooth.vertices)
    (off0, out0), (off2, out2) = _normal_error(raw, shapes), _normal_error(smooth, shapes)
    assert off2 < 0.8 * off0
    assert out2 < out0 + 0.0005


def test_closed_surface_of_a_flat_column_seen_edge_on_stays_within_its_silhouette():
    """A flat elliptic column (semi-axes 1.5 cm across the cameras' view, 4.5 cm along it, like a
    wrist seen from the thumb side), scanned front and rear on a 10 mm grid: its broad sides are
    unseen and the height field fills them from the rims' radii, about 3.5 cm. Beside the
    silhouettes that fill is air: the closed surface stays within 7 mm (half a spacing beside the
    outermost points, plus the grid) of the column; without that cut it stands 1.5 cm out."""
    from bodyscan.recon.surface.closed import closed_surface

    truth = SectionShape("forearm_l", np.array([0.0, 0, 0.3]), np.array([0.0, 0, 0.0]),
                         np.array([0.015, 0.045]), np.array([1.0, 0, 0]))
    p = truth.surface_points(n_theta=int(2 * np.pi * 0.045 / 0.002), n_h=int(0.3 / 0.002))
    p = p[(p[:, 2] > 0.001) & (p[:, 2] < 0.299)]               # the column, not its caps
    keep, vd = front_rear_zbuffer(p, model_outward(truth, p), 0.01)
    P, vd = p[keep], vd[keep]
    from scipy.spatial import cKDTree

    spacing = float(np.median(cKDTree(P).query(P, 2)[0][:, 1]))
    solids = [(SECTIONS.index("forearm_l"), np.arange(len(P)), truth)]
    out = {}
    for bg in (0.0, 0.5):
        v, f, _ = closed_surface(P, solids, spacing, band=0.0, view=(vd, None), background=bg)
        c = v[f].mean(axis=1)
        assert is_watertight(f)
        mid = (c[:, 2] > 0.05) & (c[:, 2] < 0.25)
        out[bg] = truth.coords(c[mid])[0].max()
    assert out[0.5] < 0.007 < 0.015 < out[0.0]


def test_the_closed_surface_has_no_cavity_inside_the_body():
    """A column of radius 6 cm seen all round, and a piece of the open mesh inside it (a sphere
    of 2.5 cm at its middle, wound inward): the seen surface's band makes a hollow shell around
    that piece, a cavity within the solid. The closed surface has none: every face in the
    column's middle lies within 1 mm of its surface (the code before it: 536 faces 6 cm inside)."""
    from scipy.spatial import cKDTree

    from bodyscan.recon.surface.closed import closed_surface

    truth = SectionShape("thigh_l", np.array([0.0, 0, 0.4]), np.array([0.0, 0, 0.0]),
                         np.array([0.06, 0.06]), np.array([1.0, 0, 0]))
    p = truth.surface_points(n_theta=int(2 * np.pi * 0.06 / 0.005), n_h=int(0.4 / 0.005))
    P = p[(p[:, 2] > 0.001) & (p[:, 2] < 0.399)]
    spacing = float(np.median(cKDTree(P).query(P, 2)[0][:, 1]))
    ball = trimesh.creation.icosphere(3, radius=0.025)
    seen = (ball.vertices + (0, 0, 0.2), ball.faces[:, ::-1], np.full(len(ball.faces), SECTIONS.index("thigh_l")))
    v, f, _ = closed_surface(P, [(SECTIONS.index("thigh_l"), np.arange(len(P)), truth)], spacing, seen=seen)
    assert is_watertight(f)
    c = v[f].mean(axis=1)
    mid = (c[:, 2] > 0.05) & (c[:, 2] < 0.35)
    assert np.abs(truth.coords(c[mid])[0]).max() < 0.001
    # the band's KD-tree queries in two threads: the same surface, to the bit
    v2, f2, _ = closed_surface(P, [(SECTIONS.index("thigh_l"), np.arange(len(P)), truth)], spacing, seen=seen,
                               workers=2)
    assert np.array_equal(v2, v) and np.array_equal(f2, f)


def test_a_foot_seen_from_above_rests_its_sole_on_the_floor():
    """A foot (an extremity, fitted column of semi-axes 3 cm down and 4.5 cm across) whose instep
    rises 1 cm over the column's axis and whose sole, 3 cm under it, no camera sees (the points
    stop 8 mm over it): the closed surface's sole lies flat on the floor (the lowest point), within
    0.1 mm of it under the foot's middle. A foot is filled to its column, not as thin as its
    thinnest seen side like a hand (as a hand, its sole stands 8.6-11.3 mm over the floor)."""
    from scipy.spatial import cKDTree

    from bodyscan.recon.surface.closed import closed_surface

    x, y = np.meshgrid(np.arange(0.0, 0.2, 0.004), np.linspace(-0.045, 0.045, 40), indexing="ij")
    x, y = x.ravel(), y.ravel()
    s = np.sqrt(np.clip(1 - (y / 0.045) ** 2, 0, 1))
    top = np.column_stack([x, y, 0.03 + 0.01 * s])
    low = np.column_stack([x, y, 0.03 - 0.03 * s])
    P = np.concatenate([top, low[low[:, 2] > 0.008]])
    spacing = float(np.median(cKDTree(P).query(P, 2)[0][:, 1]))
    floor = P[:, 2].min()
    for name in ("foot_l", "hand_l"):
        shape = SectionShape(name, np.array([0.0, 0, 0.03]), np.array([0.2, 0, 0.03]), np.array([0.03, 0.045]),
                             np.array([0.0, 0, 1.0]))
        job = (LOWER_LEG, np.arange(len(P)), shape, {}, np.arange(len(P)))
        v, f, _ = closed_surface(P, [job], spacing, band=0.0)
        assert is_watertight(f)
        c = v[f].mean(axis=1)
        sole = (c[:, 0] > 0.06) & (c[:, 0] < 0.14) & (np.abs(c[:, 1]) < 0.008) & (c[:, 2] < 0.03)
        if name == "foot_l":
            assert np.abs(c[sole, 2] - floor).max() < 0.0001
        else:
            assert (c[sole, 2] - floor).min() > 0.008


def test_the_closed_surface_grid_is_no_finer_than_the_points():
    """A column of radius 7 cm sampled every 12 mm: any grid step up to the spacing gives the same
    surface (the grid is the spacing's), watertight and within 2.5 mm of the column (median); a
    coarser step is its own."""
    from scipy.spatial import cKDTree

    from bodyscan.recon.surface.closed import closed_surface

    solid = SectionShape("thigh_l", np.array([0.0, 0, 0.4]), np.array([0.0, 0, 0.0]), np.array([0.07, 0.07]),
                         np.array([1.0, 0, 0]))
    p = solid.surface_points(n_theta=int(2 * np.pi * 0.07 / 0.012), n_h=int(0.4 / 0.012))
    P = p[(p[:, 2] > 0.001) & (p[:, 2] < 0.399)]
    spacing = float(np.median(cKDTree(P).query(P, 2)[0][:, 1]))
    assert 0.011 < spacing < 0.013
    job = [(SECTIONS.index("thigh_l"), np.arange(len(P)), solid)]
    v4, f4, _ = closed_surface(P, job, spacing, voxel=0.004, band=0.0)
    v8, f8, _ = closed_surface(P, job, spacing, voxel=0.008, band=0.0)
    assert np.array_equal(f4, f8) and np.allclose(v4, v8)
    assert is_watertight(f8)
    c = v8[f8].mean(axis=1)
    side = (c[:, 2] > 0.05) & (c[:, 2] < 0.35)
    assert np.median(np.abs(np.hypot(c[side, 0], c[side, 1]) - 0.07)) < 0.0025
    v16, f16, _ = closed_surface(P, job, spacing, voxel=0.016, band=0.0)
    assert len(f16) < 0.8 * len(f8)


def test_on_a_dense_scan_the_seen_surface_still_comes_out_where_the_open_mesh_has_it():
    """A solid of radius 7 cm and an open mesh, 2 mm apart, on the front half of a 6 cm column
    (spacing 2 mm, grid step 8 mm): two spacings of band outside the open mesh and one inside are
    under a grid step, so without `BAND_MIN_STEPS` the grid keeps the solid's values around the
    seen surface and its front comes out at 6.9 cm (median); with it, at 6 cm within 0.5 mm."""
    from bodyscan.recon.surface.closed import closed_surface

    solid = SectionShape("thigh_l", np.array([0.0, 0, 0.4]), np.array([0.0, 0, 0.0]), np.array([0.07, 0.07]),
                         np.array([1.0, 0, 0]))
    p = solid.surface_points(n_theta=int(2 * np.pi * 0.07 / 0.005), n_h=int(0.4 / 0.005))
    P = p[(p[:, 2] > 0.001) & (p[:, 2] < 0.399)]
    t, h = np.meshgrid(np.linspace(np.pi, 2 * np.pi, 95), np.arange(0.05, 0.35, 0.002), indexing="ij")
    V = np.column_stack([0.06 * np.cos(t.ravel()), 0.06 * np.sin(t.ravel()), h.ravel()])
    nt, nh = t.shape
    i = (np.arange(nt - 1)[:, None] * nh + np.arange(nh - 1)[None]).ravel()
    F = np.concatenate([np.column_stack([i, i + nh, i + 1]), np.column_stack([i + 1, i + nh, i + nh + 1])])
    seen = (V, F, np.full(len(F), SECTIONS.index("thigh_l")))
    v, f, _ = closed_surface(P, [(SECTIONS.index("thigh_l"), np.arange(len(P)), solid)], 0.002, voxel=0.008,
                             seen=seen)
    assert is_watertight(f)
    c = v[f].mean(axis=1)
    front = (c[:, 1] < -0.04) & (c[:, 2] > 0.1) & (c[:, 2] < 0.3)
    assert front.sum() > 300
    assert np.abs(np.hypot(c[front, 0], c[front, 1]) - 0.06).max() < 0.0005
