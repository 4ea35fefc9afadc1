"""Metrics on meshes with known answers: analytic spheres, a torso-and-arm pair of cylinders."""

import json

import numpy as np
import pytest
import trimesh

from bodyscan.benchmarks import BenchError
from bodyscan.benchmarks.metrics import (
    GroundTruth, MetricParams, SurfaceIndex, closest_point_on_triangles, exterior_faces,
    face_normals, head_misregistration, joint_errors, sample_surface, score_mesh, section_accuracy,
)

PARAMS = MetricParams(n_samples=20_000)

# the torso (chest, section 1) and a left upper arm (section 3): vertical cylinders 6 cm apart
TORSO_R, ARM_R, ARM_X, Z0, Z1 = 0.15, 0.04, 0.25, 0.0, 0.6


def _cylinder(radius, x, sections=64):
    m = trimesh.creation.cylinder(radius=radius, segment=[[x, 0, Z0], [x, 0, Z1]], sections=sections)
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.fixture(scope="module")
def torso_arm():
    tv, tf = _cylinder(TORSO_R, 0.0)
    av, af = _cylinder(ARM_R, ARM_X)
    v = np.concatenate([tv, av])
    f = np.concatenate([tf, af + len(tv)])
    sec = np.concatenate([np.full(len(tf), 1), np.full(len(af), 3)])
    joints = {"shoulder_l": np.array([0.2, 0.0, 0.55]), "pelvis": np.array([0.0, 0.0, 0.1])}
    truth = GroundTruth.from_arrays(v, f, sec, joints, PARAMS, name="torso_arm")
    assert truth.mesh.is_watertight
    return truth


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    return GroundTruth.from_arrays(m.vertices, m.faces, params=PARAMS, name="sphere")


def test_closest_point_matches_trimesh_on_random_triangles():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(20000, 3, 3))
    p = rng.normal(size=(20000, 3)) * 2
    ours = np.linalg.norm(closest_point_on_triangles(tri, p) - p, axis=1)
    ref = np.linalg.norm(trimesh.triangles.closest_point(tri, p) - p, axis=1)
    np.testing.assert_allclose(ours, ref, atol=1e-12)


@pytest.mark.parametrize("backend, atol", [("numpy", 1e-9), ("open3d", 2e-6)])
def test_surface_distances_match_point_cloud_utils(torso_arm, backend, atol):
    pcu = pytest.importorskip("point_cloud_utils")
    if backend == "open3d":
        pytest.importorskip("open3d")
    index = SurfaceIndex(torso_arm.vertices, torso_arm.faces, backend=backend)
    rng = np.random.default_rng(1)
    near, _ = sample_surface(torso_arm.vertices, torso_arm.faces, 6000, seed=5)
    near += rng.normal(scale=0.01, size=near.shape)
    far = rng.uniform([-0.3, -0.3, -0.1], [0.4, 0.3, 0.7], size=(1500, 3))
    q = np.concatenate([near, far])
    d, fid, c = index.query(q)
    _, fi, bc = pcu.closest_points_on_mesh(q, torso_arm.vertices, torso_arm.faces)
    ref = np.linalg.norm(pcu.interpolate_barycentric_coords(torso_arm.faces, fi, bc, torso_arm.vertices) - q, axis=1)
    np.testing.assert_allclose(d, ref, atol=atol)
    np.testing.assert_allclose(np.linalg.norm(c - q, axis=1), d)
    # the reported face holds the closest point
    on_face = closest_point_on_triangles(torso_arm.vertices[torso_arm.faces[fid]], q)
    np.testing.assert_allclose(np.linalg.norm(on_face - q, axis=1), d, atol=atol)


def test_chamfer_matches_independent_implementations(torso_arm):
    """Chamfer-L1 from our distances equals point-cloud-utils' exact distances on the same samples,
    and Open3D's point-to-point distances to dense samples within the sampling tolerance."""
    pcu = pytest.importorskip("point_cloud_utils")
    v = torso_arm.vertices * 1.02 + [0.004, -0.002, 0.0]   # a distorted copy
    f = torso_arm.faces
    row = score_mesh(v, f, torso_arm)
    pts, _ = sample_surface(v, f, PARAMS.n_samples, PARAMS.seed + 2)   # the samples score_mesh draws
    d_p = pcu.closest_points_on_mesh(pts, torso_arm.vertices, torso_arm.faces)
    d_r = pcu.closest_points_on_mesh(torso_arm.samples, v, f)

    def dist(q, res, vv, ff):
        return np.linalg.norm(pcu.interpolate_barycentric_coords(ff, res[1], res[2], vv) - q, axis=1)

    dp, dr = dist(pts, d_p, torso_arm.vertices, torso_arm.faces), dist(torso_arm.samples, d_r, v, f)
    assert row["chamfer_l1_mm"] == pytest.approx(500 * (dp.mean() + dr.mean()), rel=1e-5)
    assert row["precision@5mm"] == pytest.approx(np.mean(dp < 0.005))
    assert row["recall_full@5mm"] == pytest.approx(np.mean(dr < 0.005))

    o3d = pytest.importorskip("open3d")
    dense_true, _ = sample_surface(torso_arm.vertices, torso_arm.faces, 400_000, seed=9)
    dense_mine, _ = sample_surface(v, f, 400_000, seed=10)
    pc = lambda x: o3d.geometry.PointCloud(o3d.utility.Vector3dVector(x))  # noqa: E731
    a = np.asarray(pc(pts).compute_point_cloud_distance(pc(dense_true)))
    b = np.asarray(pc(torso_arm.samples).compute_point_cloud_distance(pc(dense_mine)))
    # point-to-point distances exceed point-to-surface ones by well under a millimetre here
    assert 500 * (a.mean() + b.mean()) == pytest.approx(row["chamfer_l1_mm"], abs=0.7)
    assert 500 * (a.mean() + b.mean()) >= row["chamfer_l1_mm"] - 1e-6


def test_true_mesh_against_itself(torso_arm):
    row = score_mesh(torso_arm.vertices, torso_arm.faces, torso_arm)
    assert row["spurious_count"] == 0 and row["spurious_area_fraction"] == 0
    assert row["bridging_area_fraction"] == 0 and json.loads(row["bridging_pairs"]) == {}
    for tau in ("5mm", "10mm"):
        assert row[f"precision@{tau}"] == 1 and row[f"recall_full@{tau}"] == 1
        assert row[f"fscore_full@{tau}"] == 1
    assert row["chamfer_l1_mm"] < 1e-3
    assert row["normal_consistency"] == pytest.approx(1.0)


def test_planted_quad_across_the_armpit_is_bridging_exactly(torso_arm):
    """A 6 cm x 10 cm quad from the torso to the arm: all of it in the air, joining chest and arm."""
    x0, x1, za, zb = TORSO_R, ARM_X - ARM_R, 0.3, 0.4
    quad = np.array([[x0, 0, za], [x1, 0, za], [x1, 0, zb], [x0, 0, zb]])
    n = len(torso_arm.vertices)
    v = np.concatenate([torso_arm.vertices, quad])
    f = np.concatenate([torso_arm.faces, [[n, n + 1, n + 2], [n, n + 2, n + 3]]])
    row = score_mesh(v, f, torso_arm)
    quad_area = (x1 - x0) * (zb - za)
    total = face_normals(torso_arm.vertices, torso_arm.faces)[1].sum() + quad_area
    assert row["bridging_area_cm2"] == pytest.approx(quad_area * 1e4, rel=1e-9)
    assert row["bridging_area_fraction"] == pytest.approx(quad_area / total, rel=1e-9)
    assert json.loads(row["bridging_pairs"]) == {"chest+upper_arm_l": pytest.approx(quad_area * 1e4, abs=1e-3)}
    # its normal (+-y) is perpendicular to the true normals of its corners (+-x): spurious too
    assert row["spurious_count"] == 2
    # a quad lying on the torso (within 5 mm of it) is not in the air
    flat = np.array([[0, -TORSO_R - 0.003, za], [0.01, -TORSO_R - 0.003, za],
                     [0.01, -TORSO_R - 0.003, zb], [0, -TORSO_R - 0.003, zb]])
    v2 = np.concatenate([torso_arm.vertices, flat])
    assert score_mesh(v2, f, torso_arm)["bridging_area_fraction"] == 0


def test_triangle_inside_the_body_is_not_bridging(torso_arm):
    n = len(torso_arm.vertices)
    inner = np.array([[-0.05, 0, 0.2], [0.05, 0, 0.2], [0, 0, 0.3]])
    v = np.concatenate([torso_arm.vertices, inner])
    f = np.concatenate([torso_arm.faces, [[n, n + 1, n + 2]]])
    assert score_mesh(v, f, torso_arm)["bridging_area_fraction"] == 0


def test_flipped_triangles_are_spurious(sphere):
    v, f = sphere.vertices, sphere.faces.copy()
    flip = np.nonzero(v[f].mean(axis=1)[:, 2] > 0.3)[0]   # a cap of the sphere
    f[flip] = f[flip][:, ::-1]
    row = score_mesh(v, f, sphere)
    area = face_normals(v, f)[1]
    assert row["spurious_count"] == len(flip) > 0
    assert row["spurious_area_fraction"] == pytest.approx(area[flip].sum() / area.sum())
    assert row["spurious_area_fraction_unoriented"] == 0
    unoriented = GroundTruth.from_arrays(v, sphere.faces, params=MetricParams(n_samples=20_000, oriented=False))
    assert score_mesh(v, f, unoriented)["spurious_count"] == 0


def test_tilted_triangles_are_spurious_beyond_the_threshold(sphere):
    """Triangles whose normal is rotated by 20 or 40 degrees: only the latter exceed 30 degrees."""
    n = len(sphere.vertices)
    t = sphere.index.normals[0]
    c = sphere.vertices[sphere.faces[0]].mean(axis=0)
    u = np.cross(t, [0, 0, 1.0]); u /= np.linalg.norm(u)
    w = np.cross(t, u)
    tris, faces = [], []
    for k, ang in enumerate((20, 40)):
        nrm = np.cos(np.radians(ang)) * t + np.sin(np.radians(ang)) * w
        a = np.cross(nrm, u)
        tri = c + 0.004 * np.array([u, a, -u - a])   # small, around the face centroid
        if np.cross(tri[1] - tri[0], tri[2] - tri[0]) @ nrm < 0:
            tri = tri[[0, 2, 1]]
        tris.append(tri)
        faces.append([n + 3 * k, n + 3 * k + 1, n + 3 * k + 2])
    v = np.concatenate([sphere.vertices, *tris])
    f = np.concatenate([sphere.faces, faces])
    # the extra vertices take their true normal from the nearest true face: face 0
    row = score_mesh(v, f, sphere, keep_masks=True)
    assert row["spurious_count"] == 1 and row["_spurious"][-1] and not row["_spurious"][-2]


def test_offset_sphere_chamfer_equals_the_offset(sphere):
    s = 0.003
    v = sphere.vertices * (0.4 + s) / 0.4
    row = score_mesh(v, sphere.faces, sphere)
    # homothetic tessellations: face planes are s * cos(half the face's angular size) apart
    assert row["chamfer_l1_mm"] == pytest.approx(s * 1000, rel=2e-3)
    assert row["precision@5mm"] == 1 and row["recall_full@5mm"] == 1
    assert row["precision@10mm"] == 1
    row = score_mesh(sphere.vertices * (0.4 + 0.007) / 0.4, sphere.faces, sphere)
    assert row["precision@5mm"] == 0 and row["recall_full@5mm"] == 0 and row["fscore_full@10mm"] == 1


def test_surface_no_ray_from_outside_reaches_is_not_counted():
    """A sphere (r 0.4 m) holding a sealed pocket (a sphere of r 0.1 m inside it, like the mouth's
    cavity behind closed lips): the pocket is not outer surface, and the outer sphere alone recalls
    all of the truth (counting the pocket, it would recall 0.4^2 / (0.4^2 + 0.1^2) = 94 %)."""
    outer = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    pocket = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    v = np.concatenate([outer.vertices, pocket.vertices])
    f = np.concatenate([outer.faces, pocket.faces + len(outer.vertices)])
    found = exterior_faces(v, f)
    assert found[:len(outer.faces)].all() and not found[len(outer.faces):].any()
    truth = GroundTruth.from_arrays(v, f, params=PARAMS)
    assert score_mesh(outer.vertices, outer.faces, truth)["recall_full@5mm"] == 1
    every = GroundTruth.from_arrays(v, f, params=MetricParams(n_samples=20_000, exterior_rays=0))
    assert score_mesh(outer.vertices, outer.faces, every)["recall_full@5mm"] == pytest.approx(0.941, abs=0.01)


def test_translated_sphere_chamfer_is_half_the_shift(sphere):
    """For a sphere moved by s << R, the distance is s |cos(angle to the shift)|, whose mean is s/2."""
    s = 0.004
    row = score_mesh(sphere.vertices + [s, 0, 0], sphere.faces, sphere)
    assert row["chamfer_l1_mm"] == pytest.approx(s * 500, rel=0.02)


def test_recall_seen_counts_only_what_the_scanner_saw(sphere):
    """A hemisphere mesh, scanned from the hemisphere's side: full recall ~1/2, seen recall 1."""
    v, f = sphere.vertices, sphere.faces
    keep = v[f].mean(axis=1)[:, 1] < 0
    scan = sphere.samples[sphere.samples[:, 1] < -0.04]
    row = score_mesh(v, f[keep], sphere, scan_points=scan)
    assert row["recall_full@5mm"] == pytest.approx(0.5, abs=0.02)
    assert row["recall_seen@5mm"] == 1
    assert row["fscore_seen@5mm"] == 1
    assert row["seen_fraction"] == pytest.approx((0.4 - 0.04 + 0.015) / 0.8, abs=0.02)


def test_scan_points_use_their_gt_face(sphere):
    """A vertex that is a scan point takes the scan's gt_face even when another face is nearer."""
    v, f = sphere.vertices, sphere.faces
    gt_face = np.zeros(len(v), dtype=np.int64)   # every vertex claims face 0: most triangles wrong
    row = score_mesh(v, f, sphere, scan_points=v, scan_gt_face=gt_face)
    assert row["spurious_count"] > 0.9 * len(f)
    assert score_mesh(v, f, sphere, scan_points=v, scan_gt_face=gt_face,
                      point_index=np.full(len(v), -1))["spurious_count"] == 0


def test_section_accuracy_and_joint_errors():
    gt = np.array([0, 1, 2, 3])
    ps = np.zeros((4, 11), bool)
    ps[0, 0] = True                  # right
    ps[1, [1, 2]] = True             # two labels, one right: 1/2
    ps[2, 5] = True                  # wrong
    r = section_accuracy(ps, gt)     # point 3 unlabelled
    assert r["section_accuracy"] == pytest.approx(1.5 / 4)
    assert r["section_accuracy_any"] == pytest.approx(2 / 4)
    assert r["unlabelled_fraction"] == 0.25 and r["multi_label_fraction"] == 0.25
    with pytest.raises(BenchError):
        section_accuracy(ps[:, :5], gt)
    true = {"a": np.zeros(3), "b": np.ones(3), "c": np.array([0, 0, 1.0])}
    est = {"a": np.array([0.03, 0, 0]), "b": np.ones(3) + [0, 0.04, 0], "c": np.array([0, 0, 1.01]), "x": np.zeros(3)}
    j = joint_errors(est, true)
    assert j["joint_error_median_m"] == pytest.approx(0.03)
    assert j["joint_error_max_m"] == pytest.approx(0.04) and j["joint_error_worst"] == "b"


def test_samples_are_area_uniform_and_seeded():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [3, 0, 0], [3, 0.5, 0], [3.5, 0, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])      # areas 0.5, 0.5, 0.125
    p, fid = sample_surface(v, f, 90_000, seed=3)
    np.testing.assert_allclose(np.bincount(fid) / 90_000, [0.5 / 1.125, 0.5 / 1.125, 0.125 / 1.125], atol=0.01)
    q, _ = sample_surface(v, f, 90_000, seed=3)
    np.testing.assert_array_equal(p, q)
    assert np.all(p[fid == 0][:, 0] >= p[fid == 0][:, 1] - 1e-12)  # inside their triangle
    idx = SurfaceIndex(v, f, backend="numpy")
    assert idx.query(p)[0].max() < 1e-12


def test_empty_mesh_and_bad_input(sphere):
    row = score_mesh(np.zeros((0, 3)), np.zeros((0, 3), int), sphere)
    assert row["recall_full@5mm"] == 0 and row["n_faces"] == 0
    with pytest.raises(BenchError):
        score_mesh(sphere.vertices, sphere.faces + len(sphere.vertices), sphere)
    with pytest.raises(BenchError):
        MetricParams(spurious_angle_deg=0)


@pytest.fixture(scope="module")
def standing():
    from bodyscan.poses.body import load_body
    from bodyscan.poses.library import list_bodies

    assert "standing" in list_bodies(), "the shipped library has no 'standing' body"
    body = load_body("standing")
    return body, GroundTruth.from_body(body, PARAMS)


def test_standing_body_against_itself(standing):
    body, truth = standing
    row = score_mesh(body.vertices, body.faces, truth)
    assert row["spurious_count"] == 0 and row["bridging_area_fraction"] == 0
    assert row["fscore_full@5mm"] == 1 and row["chamfer_l1_mm"] < 1e-3


def test_planted_quad_in_the_standing_body_s_left_armpit(standing):
    """A quad in the plane y = 0 from the chest's side to the left arm's inner side, 5 cm tall:
    exactly its area is in the air, between chest and upper_arm_l."""
    body, truth = standing
    mesh = truth.mesh
    corners = []
    for z in (1.20, 1.25):
        hits, _, tri = mesh.ray.intersects_location([[0.0, 0.0, z]], [[1.0, 0.0, 0.0]])
        order = np.argsort(hits[:, 0])
        assert [_section_of(truth, tri[order[i]]) for i in (0, 1)] == ["chest", "upper_arm_l"]
        corners.append((hits[order[0]], hits[order[1]]))   # torso side, arm side
    (t1, a1), (t2, a2) = corners
    n = len(body.vertices)
    v = np.concatenate([body.vertices, [t1, a1, a2, t2]])
    f = np.concatenate([body.faces, [[n, n + 1, n + 2], [n, n + 2, n + 3]]])
    quad_area = face_normals(v, f[-2:])[1].sum()
    row = score_mesh(v, f, truth)
    assert row["bridging_area_cm2"] == pytest.approx(quad_area * 1e4, rel=1e-9)
    assert list(json.loads(row["bridging_pairs"])) == ["chest+upper_arm_l"]
    assert 30 < quad_area * 1e4 < 60   # a 5-8 cm wide gap, 5 cm tall


def _section_of(truth, face):
    from bodyscan.benchmarks.metrics import SECTIONS

    return SECTIONS[truth.face_section[face]]


def _turn_z(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def test_head_misregistration_is_the_heads_relative_motion_only():
    # head 1 turned 0.5 degrees about the z axis and shifted 2 mm along x; head 0 in place
    rot, shift = np.stack([np.eye(3), _turn_z(0.5)]), np.array([[0, 0, 0], [0.002, 0, 0]])
    on_axis = head_misregistration(rot, shift, at=[0, 0, 1])
    assert on_axis["deg"] == pytest.approx(0.5) and on_axis["mm"] == pytest.approx(2.0)
    # off the axis the turn adds its arc: 1 m out, (cos - 1, sin) m
    a = np.radians(0.5)
    off = head_misregistration(rot, shift, at=[1, 0, 0])["mm"]
    assert off == pytest.approx(1000 * np.hypot(np.cos(a) - 1 + 0.002, np.sin(a)))
    # moving every head alike afterwards (the whole scanner) changes nothing
    m, u = _turn_z(7.0) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]), np.array([0.1, -0.3, 0.05])
    both = head_misregistration(m @ rot, shift @ m.T + u, at=[1, 0, 0])
    assert both["deg"] == pytest.approx(0.5) and both["mm"] == pytest.approx(off)
    # the largest pair of three heads: the two turned opposite ways
    three = head_misregistration(np.stack([np.eye(3), _turn_z(0.3), _turn_z(-0.3)]), np.zeros((3, 3)), [0, 0, 0])
    assert three["deg"] == pytest.approx(0.6) and three["mm"] == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(head_misregistration(np.eye(3)[None], np.zeros((1, 3)), [0, 0, 0])["deg"])
