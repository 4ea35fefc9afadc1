"""The slit-laser simulator against analytic scenes and independent trimesh ray queries."""

import math
import warnings

import numpy as np
import pytest
import trimesh

from bodyscan import simulator
from bodyscan.poses import BodyError, load_body, save_body
from bodyscan.simulator import Head, ScanError, Scanner, ScanWarning, preset, read_scan, scan, write_cloud

FRONT = (Head("front", 0.0),)


def _plane(y, x=(-0.8, 0.8), z=(0.2, 1.8)):
    """A rectangle at depth ``y`` facing -y (toward the front camera)."""
    v = np.array([[x[0], y, z[0]], [x[1], y, z[0]], [x[1], y, z[1]], [x[0], y, z[1]]])
    return trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def _scene(*meshes):
    return trimesh.util.concatenate(meshes)


@pytest.fixture(scope="module")
def body():
    """The shipped standing body (anny average adult male)."""
    return load_body("standing")


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(5, radius=0.5)
    m.apply_translation([0.03, -0.02, 1.0])
    return m


def _pixel_grid(res, cx, head=Head()):
    """Pixel centres (x, z) of a front head: a grid at ``res`` centred on (scene centre x, head height)."""
    nw, nh = round(head.field_width / res), round(head.field_height / res)
    return np.meshgrid((np.arange(nw) + 0.5 - nw / 2) * res + cx, (np.arange(nh) + 0.5 - nh / 2) * res + head.height)


def _tan(k):
    return math.tan(k * math.pi / 12)


# --- analytic scenes ---------------------------------------------------------------------------

@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_sphere_points_on_surface_and_count_matches_lit_visible_area(sphere, k):
    cfg = preset("paper", k=k, resolution=0.008)
    s = scan(sphere, cfg)
    c, r = np.array([0.03, -0.02, 1.0]), 0.5
    dist = np.linalg.norm(s.points - c, axis=1)
    # faceted sphere: points lie between the nearest face plane and the circumscribed sphere
    tri = sphere.triangles
    inner = np.abs(np.einsum("ij,ij->i", sphere.face_normals, tri[:, 0] - c)).min()
    assert dist.min() >= inner - 1e-6 and dist.max() <= r + 1e-6
    # each point lies on its gt face, seen from the side facing its camera
    v0 = tri[s.gt_face, 0]
    assert np.abs(np.einsum("ij,ij->i", s.points - v0, s.gt_normal)).max() < 1e-5
    assert (np.einsum("ij,ij->i", s.view_dir, s.gt_normal) > 0).all()
    # seen and lit part of a sphere, projected on the image: half disc + half ellipse (R, R cos t)
    expected = math.pi * r ** 2 * (1 + math.cos(k * math.pi / 12)) / 2 / cfg.resolution ** 2
    for count in s.meta["points_per_head"]:
        assert count == pytest.approx(expected, rel=0.015)


@pytest.mark.parametrize("k", [1, 3])
def test_horizontal_cylinder_lit_band(k):
    r, length = 0.3, 1.2
    cyl = trimesh.creation.cylinder(radius=r, height=length, sections=256)
    cyl.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], [1, 0, 0]))
    cyl.apply_translation([0, 0, 1.0])
    cfg = preset("paper", k=k, resolution=0.01, heads=FRONT)
    s = scan(cyl, cfg)
    radial = np.hypot(s.points[:, 1], s.points[:, 2] - 1.0)
    sagitta = r * (1 - math.cos(math.pi / 256))
    assert radial.min() >= r - sagitta - 1e-6 and radial.max() <= r + 1e-6
    assert np.abs(s.points[:, 0]).max() <= length / 2 + 1e-9
    # the laser from above lights the front down to z = -r cos(theta): band height r (1 + cos theta)
    low = 1.0 - r * math.cos(k * math.pi / 12)
    assert s.points[:, 2].min() == pytest.approx(low, abs=cfg.resolution)
    expected = length * r * (1 + math.cos(k * math.pi / 12)) / cfg.resolution ** 2
    assert len(s) == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("k", [1, 2])
def test_box_before_plane_casts_camera_and_laser_shadows(k):
    """A box hanging between camera and plane: nothing behind it, nothing in its laser shadow."""
    res, t = 0.01, _tan(k)
    mesh = _scene(_plane(0.3), _box([-0.1, -0.3, 0.9], [0.1, -0.1, 1.1]))
    s = scan(mesh, preset("paper", k=k, resolution=res, heads=FRONT))
    on_plane = np.abs(s.points[:, 1] - 0.3) < 1e-6
    x, z = s.points[on_plane, 0], s.points[on_plane, 2]
    behind = np.abs(x) < 0.1
    assert not (behind & (z > 0.9) & (z < 1.1)).any()                       # camera's shadow
    assert not (behind & (z > 0.9 - 0.6 * t) & (z < 1.1 - 0.4 * t)).any()   # laser's shadow
    # everything else on the plane is measured: compare with the pixel grid, counted independently
    gx, gz = _pixel_grid(res, 0.0)
    inside = (np.abs(gx) < 0.8) & (gz > 0.2) & (gz < 1.8)
    shadow = (np.abs(gx) < 0.1) & (((gz > 0.9) & (gz < 1.1)) | ((gz > 0.9 - 0.6 * t) & (gz < 1.1 - 0.4 * t)))
    assert on_plane.sum() == (inside & ~shadow).sum()
    # the box's front face is measured
    assert (np.abs(s.points[:, 1] + 0.3) < 1e-6).sum() == pytest.approx((0.2 / res) ** 2, rel=0.15)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_laser_shadow_below_a_ledge_grows_with_tan_k(k):
    """A ledge on a wall hides the wall below it from the laser only: shadow = depth * tan(k pi/12)."""
    res, depth = 0.004, 0.1
    mesh = _scene(_plane(0.0), _box([-0.2, -depth, 1.0], [0.2, 0.05, 1.2]))
    s = scan(mesh, preset("paper", k=k, resolution=res, heads=FRONT))
    wall = (np.abs(s.points[:, 1]) < 1e-6) & (np.abs(s.points[:, 0]) < 0.2 - res)
    below = s.points[wall & (s.points[:, 2] < 1.0), 2]
    shadow_top = 1.0 - depth * _tan(k)
    assert not ((below > shadow_top + 1e-6)).any()
    assert 1.0 - below.max() == pytest.approx(depth * _tan(k), abs=res)
    # the camera itself sees the wall right under the ledge: the gap is the laser's alone
    seen = scan(mesh, preset("paper", k=0, resolution=res, heads=FRONT))
    wall0 = (np.abs(seen.points[:, 1]) < 1e-6) & (np.abs(seen.points[:, 0]) < 0.2 - res)
    assert 1.0 - seen.points[wall0 & (seen.points[:, 2] < 1.0), 2].max() <= res + 1e-6


def test_laser_beside_the_camera_shades_the_side_of_the_ledge():
    """laser_roll_deg = 90: the laser sits to the camera's right (+x), so the shadow falls to -x."""
    res, depth, k = 0.004, 0.1, 2
    mesh = _scene(_plane(0.0), _box([-0.2, -depth, 1.0], [0.2, 0.05, 1.2]))
    s = scan(mesh, preset("paper", k=k, resolution=res, heads=(Head("front", laser_roll_deg=90.0),)))
    wall = np.abs(s.points[:, 1]) < 1e-6
    x, z = s.points[wall, 0], s.points[wall, 2]
    band = (z > 1.0 + res) & (z < 1.2 - res)
    assert 1.0 - z[(np.abs(x) < 0.2 - res) & (z < 1.0)].max() <= res + 1e-6   # nothing shaded below
    left = x[band & (x < -0.2)]
    assert -0.2 - left.max() == pytest.approx(depth * _tan(k), abs=res)          # shadow on the left
    assert x[band & (x > 0.2)].min() - 0.2 <= res + 1e-6                        # lit on the right


def test_tilted_head_sees_the_floor_foreshortened():
    """A head looking 30 degrees down sees a floor patch, foreshortened by sin(30 deg)."""
    res, side = 0.01, 0.6
    floor = trimesh.Trimesh([[-side / 2, -side / 2, 0.5], [side / 2, -side / 2, 0.5], [side / 2, side / 2, 0.5],
                             [-side / 2, side / 2, 0.5]], [[0, 1, 2], [0, 2, 3]])
    head = Head("down", tilt_deg=-30.0, height=0.5)
    s = scan(floor, preset(resolution=res, k=1, heads=(head,)))
    assert np.abs(s.points[:, 2] - 0.5).max() < 1e-6
    assert np.allclose(s.view_dir, [0, -math.cos(math.pi / 6), math.sin(math.pi / 6)], atol=1e-6)
    assert len(s) == pytest.approx(side * side * math.sin(math.pi / 6) / res ** 2, rel=0.03)
    with pytest.raises(ScanError, match="no surface point"):
        scan(floor, preset(resolution=res, heads=FRONT))   # a level camera sees the floor edge-on


def test_perspective_points_see_their_pinhole(sphere):
    cfg = preset("scanner", noise_sigma=0.0, resolution=0.01)
    s = scan(sphere, cfg)
    center = np.array(s.meta["scanner_center"])
    for h, head in enumerate(cfg.heads):
        az = math.radians(head.azimuth_deg)
        axis = np.array([-math.sin(az), math.cos(az), 0.0])
        pinhole = np.array([center[0], center[1], head.height]) - cfg.camera_distance * axis
        p, vd = s.points[s.head == h], s.view_dir[s.head == h]
        to_cam = (pinhole - p) / np.linalg.norm(pinhole - p, axis=1, keepdims=True)
        assert np.abs(to_cam - vd).max() < 1e-6
        # the laser source sits above the camera by the baseline: every lit normal faces it
        source = pinhole + [0, 0, cfg.camera_distance * math.tan(math.radians(cfg.laser_angle_deg))]
        assert (np.einsum("ij,ij->i", source - p, s.gt_normal[s.head == h]) > 0).all()
    dist = np.linalg.norm(s.points - [0.03, -0.02, 1.0], axis=1)
    assert np.abs(dist - 0.5).max() < 1e-3


# --- bodies: independent re-check with trimesh -------------------------------------------------

def _camera_origin_dirs(s):
    """Per point: origin and unit direction of a camera ray that should first hit the point."""
    vd = s.view_dir.astype(np.float64)
    vd /= np.linalg.norm(vd, axis=1, keepdims=True)
    return s.points + 3.0 * vd, -vd


def _laser_dirs(s, cfg):
    center = np.array(s.meta["scanner_center"])
    dirs = np.empty_like(s.points)
    reach = np.full(len(s), np.inf)
    t = math.radians(cfg.laser_angle_deg)
    for h, head in enumerate(cfg.heads):
        az, roll = math.radians(head.azimuth_deg), math.radians(head.laser_roll_deg)
        axis = np.array([-math.sin(az), math.cos(az), 0.0])
        up, right = np.array([0, 0, 1.0]), np.cross(axis, [0, 0, 1.0])
        side = math.cos(roll) * up + math.sin(roll) * right
        sel = s.head == h
        if cfg.projection == "parallel":
            dirs[sel] = -math.cos(t) * axis + math.sin(t) * side
        else:
            src = np.array([center[0], center[1], head.height]) - cfg.camera_distance * axis \
                + cfg.camera_distance * math.tan(t) * side
            d = src - s.points[sel]
            reach[sel] = np.linalg.norm(d, axis=1)
            dirs[sel] = d / reach[sel, None]
    return dirs, reach


def _recheck(caster, s, cfg):
    """Points of ``s`` that a trimesh ray query finds not first on their camera ray, and shaded."""
    o, d = _camera_origin_dirs(s)
    face, ray, loc = caster.intersects_id(o, d, multiple_hits=False, return_locations=True)
    first = np.full(len(s), -1)
    first[ray] = face
    where = np.full((len(s), 3), np.nan)
    where[ray] = loc
    hidden = (first != s.gt_face) & ~(np.linalg.norm(where - s.points, axis=1) < 1e-6)
    ld, reach = _laser_dirs(s, cfg)
    start = s.points + 1e-4 * s.gt_normal * np.sign(np.einsum("ij,ij->i", s.gt_normal, s.view_dir))[:, None]
    face, ray, loc = caster.intersects_id(start, ld, multiple_hits=False, return_locations=True)
    shaded = np.zeros(len(s), bool)
    shaded[ray] = np.linalg.norm(loc - start[ray], axis=1) < reach[ray]
    return hidden.sum(), shaded.sum()


@pytest.mark.parametrize("name", ["paper", "scanner"])
def test_every_body_point_is_seen_and_lit_by_independent_trimesh_rays(body, name):
    cfg = preset(name, resolution=0.01, noise_sigma=0.0, k=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # the whole body is in the field
        s = scan(body, cfg)
    assert set(np.unique(s.head)) == {0, 1}
    mesh = body.to_trimesh()
    # every point, with trimesh's own Embree engine (not the simulator's wrapper)
    from trimesh.ray.ray_pyembree import RayMeshIntersector as EmbreeEngine
    hidden, shaded = _recheck(EmbreeEngine(mesh), s, cfg)
    assert hidden <= len(s) // 2000 and shaded <= len(s) // 2000, (hidden, shaded)
    # a sample, with trimesh's pure-numpy engine (no Embree at all)
    from trimesh.ray.ray_triangle import RayMeshIntersector
    pick = np.random.default_rng(1).choice(len(s), min(len(s), 800), replace=False)
    sub = simulator.Scan(*(getattr(s, f)[pick] for f in ("points", "head", "view_dir", "gt_face",
                                                          "gt_section", "gt_normal")), meta=s.meta)
    assert max(_recheck(RayMeshIntersector(mesh), sub, cfg)) <= 1
    # ground truth: each point lies on its face, whose normal and section are the body's
    normal = mesh.face_normals[s.gt_face]
    assert np.abs(s.gt_normal - normal).max() < 1e-5
    assert np.abs(np.einsum("ij,ij->i", s.points - mesh.triangles[s.gt_face, 0], normal)).max() < 1e-5
    assert np.array_equal(s.gt_section, body.face_section()[s.gt_face])


def test_body_scan_finds_every_seen_and_lit_pixel(body):
    """Converse: cast the front camera's pixel grid independently; every seen, lit hit is in the scan."""
    res = 0.02
    cfg = preset("paper", resolution=res, k=1, heads=FRONT)
    s = scan(body, cfg)
    lo, hi = body.vertices.min(0), body.vertices.max(0)
    gx, gz = _pixel_grid(res, (lo[0] + hi[0]) / 2)
    keep = (gx > lo[0] - res) & (gx < hi[0] + res) & (gz > lo[2] - res) & (gz < hi[2] + res)
    o = np.stack([gx[keep], np.full(keep.sum(), lo[1] - 1.0), gz[keep]], axis=1)
    mesh = body.to_trimesh()
    from trimesh.ray.ray_triangle import RayMeshIntersector
    caster = RayMeshIntersector(mesh)
    face, ray, loc = caster.intersects_id(o, np.tile([0, 1.0, 0], (len(o), 1)), multiple_hits=False,
                                          return_locations=True)
    normal = mesh.face_normals[face] * np.where(mesh.face_normals[face, 1] < 0, 1, -1)[:, None]
    light = np.array([0, -math.cos(math.pi / 12), math.sin(math.pi / 12)])
    facing = normal @ light > 0
    shade = caster.intersects_any(loc + 1e-4 * normal, np.tile(light, (len(loc), 1)))
    expected = loc[facing & ~shade]
    from scipy.spatial import cKDTree
    gap, _ = cKDTree(s.points).query(expected)
    assert (gap < 1e-5).mean() > 0.995
    assert len(s) == pytest.approx(len(expected), rel=0.005)
    assert len(s) < len(loc)   # the body shadows itself


# --- reproducibility and imperfections ---------------------------------------------------------

def test_same_seed_same_cloud_bit_for_bit(body):
    cfg = preset("paper", noise_sigma=0.002, outlier_fraction=0.02, misalign_deg=1.0, misalign_mm=3.0)
    a, b = scan(body, cfg, seed=7), Scanner(body).scan(cfg, seed=7)
    for f in ("points", "head", "view_dir", "gt_face", "gt_section", "gt_normal"):
        assert getattr(a, f).tobytes() == getattr(b, f).tobytes(), f
    c = scan(body, cfg, seed=8)
    assert not np.array_equal(a.points, c.points)
    assert np.array_equal(a.gt_face, c.gt_face)
    assert a.meta["seed"] == 7 and a.meta["config"]["seed"] == 7


def test_cached_scanner_matches_fresh_scans(sphere):
    scanner = Scanner(sphere)
    for k in (1, 2, 3):
        cached, fresh = scanner.scan(preset(k=k)), scan(sphere, preset(k=k))
        assert cached.points.tobytes() == fresh.points.tobytes()


def test_noise_outliers_and_misalignment_statistics(sphere, tmp_path):
    scanner = Scanner(sphere)
    base = preset("paper", resolution=0.005)
    clean = scanner.scan(base)
    sigma = 0.002
    noisy = scanner.scan(base.replace(noise_sigma=sigma), seed=3)
    along = np.einsum("ij,ij->i", noisy.points - clean.points, -clean.view_dir.astype(float))
    across = noisy.points - clean.points + along[:, None] * clean.view_dir
    assert along.std() == pytest.approx(sigma, rel=0.03)
    assert abs(along.mean()) < 4 * sigma / math.sqrt(len(along))
    assert np.abs(across).max() < 1e-6
    # outliers: exactly the fraction, uniform along the ray within the spread
    out = scanner.scan(base.replace(outlier_fraction=0.05, outlier_spread=0.04), seed=3)
    moved = np.linalg.norm(out.points - clean.points, axis=1)
    for h, count in enumerate(clean.meta["points_per_head"]):
        assert (moved[clean.head == h] > 0).sum() == round(0.05 * count)
    off = moved[moved > 0]
    assert off.max() <= 0.04 + 1e-9 and off.mean() == pytest.approx(0.02, rel=0.1)
    # misalignment: each head moved rigidly by exactly the stated rotation and translation
    mis = scanner.scan(base.replace(misalign_deg=2.0, misalign_mm=5.0), seed=3)
    c = np.array(mis.meta["scanner_center"])
    rotations = []
    for h in (0, 1):
        p, q = clean.points[clean.head == h] - c, mis.points[mis.head == h] - c
        pm, qm = p.mean(0), q.mean(0)
        u, _, vt = np.linalg.svd((p - pm).T @ (q - qm))
        rot = (u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt).T
        angle = math.degrees(math.acos((np.trace(rot) - 1) / 2))
        assert angle == pytest.approx(2.0, abs=1e-6)
        shift = (q - p @ rot.T).mean(0)
        assert np.linalg.norm(shift) == pytest.approx(0.005, abs=1e-9)
        assert np.abs(q - p @ rot.T - shift).max() < 1e-9
        view = clean.view_dir[clean.head == h] @ rot.T.astype(np.float32)
        assert np.abs(view - mis.view_dir[mis.head == h]).max() < 1e-5
        rotations.append(rot)
        # the ground truth it records is that motion
        assert np.abs(np.array(mis.meta["misalign_rotation"][h]) - rot).max() < 1e-6
        assert np.abs(np.array(mis.meta["misalign_translation"][h]) - shift).max() < 1e-9
    assert not np.allclose(rotations[0], rotations[1])
    assert "misalign_rotation" not in clean.meta
    back = read_scan(write_cloud(mis, tmp_path / "mis.ply"))
    assert np.array(back.meta["misalign_rotation"]) == pytest.approx(np.array(mis.meta["misalign_rotation"]), abs=1e-12)
    assert np.array_equal(mis.gt_normal, clean.gt_normal)


def test_max_incidence_drops_oblique_points(sphere):
    s = scan(sphere, preset("paper", k=2, max_incidence_deg=60.0))
    cos_cam = np.einsum("ij,ij->i", s.view_dir, s.gt_normal)
    assert cos_cam.min() > math.cos(math.radians(60)) - 1e-6
    assert len(s) < 0.8 * len(scan(sphere, preset("paper", k=2)))


@pytest.mark.parametrize("layout, n_heads", [("two_towers", 4), ("four_towers", 8)])
def test_head_layouts_each_measure_their_part(body, layout, n_heads):
    cfg = preset("paper", resolution=0.02, heads=simulator.head_layout(layout))
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # the fields together cover the whole body
        s = scan(body, cfg)
    assert len(s.meta["heads"]) == n_heads and all(c > 0 for c in s.meta["points_per_head"])
    for h, head in enumerate(cfg.heads):
        z = s.points[s.head == h, 2]
        assert z.min() >= head.height - head.field_height / 2 - 1e-9
        assert z.max() <= head.height + head.field_height / 2 + 1e-9


# --- files -------------------------------------------------------------------------------------

def test_ply_roundtrip_and_third_party_readers(body, tmp_path):
    s = scan(body, preset("paper", noise_sigma=0.001), seed=5)
    path = write_cloud(s, tmp_path / "cloud.ply")
    back = read_scan(path)
    for f in ("points", "head", "view_dir", "gt_face", "gt_section", "gt_normal"):
        a, b = getattr(s, f), getattr(back, f)
        assert a.dtype == b.dtype and np.array_equal(a, b), f
    assert back.meta == s.meta and back.config == preset("paper", noise_sigma=0.001, seed=5)
    header = path.read_bytes()[:4000].split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in header and "comment bodyscan seed 5" in header
    props = [ln.split()[-1] for ln in header.splitlines() if ln.startswith("property")]
    assert props == ["x", "y", "z", "head", "vx", "vy", "vz", "gt_face", "gt_section", "gt_nx", "gt_ny", "gt_nz"]
    assert np.array_equal(np.asarray(trimesh.load(path).vertices), s.points)
    assert max(len(line) for line in header.splitlines()) < 500          # MeshLab's header limit
    o3d = pytest.importorskip("open3d")
    assert np.array_equal(np.asarray(o3d.io.read_point_cloud(str(path)).points), s.points)
    pymeshlab = pytest.importorskip("pymeshlab")
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    assert np.array_equal(ms.current_mesh().vertex_matrix(), s.points)


# --- bad input ---------------------------------------------------------------------------------

def test_bad_meshes_give_clear_errors(sphere):
    with pytest.raises(BodyError, match="non-empty"):
        scan(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)))
    v = sphere.vertices.copy()
    v[3] = np.nan
    with pytest.raises(BodyError, match="NaN"):
        scan(trimesh.Trimesh(v, sphere.faces, process=False))
    with pytest.raises(ScanError, match="divide millimetres by 1000"):
        scan(trimesh.Trimesh(sphere.vertices * 1000, sphere.faces, process=False))
    far = sphere.copy().apply_translation([0, 0, 20.0])
    with pytest.raises(ScanError, match="outside the field"):
        scan(far)
    with pytest.warns(ScanWarning, match="outside every head's field"):
        scan(sphere, preset(heads=(Head("front", field_height=0.5),)))


def test_scan_records_the_part_of_the_body_outside_the_field(sphere):
    # a parallel head at height 1.1 with a field 0.5 m high sees z in 0.85..1.35: the sphere
    # (centre z = 1.0, radius 0.5) reaches out of it above and below
    with pytest.warns(ScanWarning, match="outside every head's field"):
        cut = scan(sphere, preset(heads=(Head("front", height=1.1, field_height=0.5),)))
    z = sphere.vertices[:, 2]
    assert cut.meta["outside_field"] == pytest.approx(np.mean(np.abs(z - 1.1) > 0.25), abs=1e-3)
    assert 0.2 < cut.meta["outside_field"] < 0.6
    assert cut.points[:, 2].max() <= 1.35 + 1e-6 and cut.points[:, 2].min() >= 0.85 - 1e-6
    assert "outside_field" not in scan(sphere).meta   # the whole sphere in the field: no key
    with pytest.raises(ScanError, match="resolution"):
        preset(resolution=-1)
    with pytest.raises(ScanError, match="unknown scanner preset"):
        preset("nope")
    with pytest.raises(ScanError, match="noise_sigma.*must be a finite number"):
        preset(noise_sigma=float("nan"))
    numpy_typed = preset(resolution=np.float32(0.01), seed=np.int64(3))   # stored as plain Python numbers
    assert type(numpy_typed.resolution) is float and type(numpy_typed.seed) is int
    assert simulator.ScannerConfig.from_dict(numpy_typed.to_dict()) == numpy_typed


def _run(argv):
    from bodyscan.benchmarks.cli import main
    return main(argv)


def test_cli_writes_cloud_and_preview(body, tmp_path, capsys):
    src = save_body(body, tmp_path / "b.npz")
    out, png = tmp_path / "c.ply", tmp_path / "c.png"
    rc = _run(["scan", str(src), "--out", str(out), "--k", "2", "--resolution", "0.02", "--noise", "0.001",
               "--seed", "4", "--preview", str(png), "--param", "misalign_mm=1"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "points" in err and "front" in err and "rear" in err
    s = read_scan(out)
    cfg = s.config
    assert cfg.laser_angle_deg == 30.0 and cfg.resolution == 0.02 and cfg.noise_sigma == 0.001
    assert cfg.misalign_mm == 1 and s.meta["seed"] == 4 and s.meta["body"] == "b"
    assert png.stat().st_size > 10_000
    again = tmp_path / "again.ply"
    _run(["scan", str(src), "--out", str(again), "--k", "2", "--resolution", "0.02", "--noise", "0.001",
          "--seed", "4", "--param", "misalign_mm=1", "-q"])
    assert again.read_bytes() == out.read_bytes()


def test_cli_errors_are_one_line_with_exit_code_2(sphere, tmp_path, capsys):
    mm = tmp_path / "mm.ply"
    trimesh.Trimesh(sphere.vertices * 1000, sphere.faces).export(mm)
    assert _run(["scan", str(mm), "--out", str(tmp_path / "x.ply")]) == 2
    assert _run(["scan", "no_such_body", "--out", str(tmp_path / "x.ply")]) == 2
    assert _run(["scan", str(mm), "--out", str(tmp_path / "x.ply"), "--param", "bogus=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("bodyscan scan: error:") for line in err)
    assert "1000" in err[0] and "bogus" in err[2]
    ok = tmp_path / "ok.ply"
    sphere.export(ok)
    assert _run(["scan", str(ok), "--out", str(tmp_path / "y.ply"), "--field-height", "0.6", "-q"]) == 0
    assert "warning" in capsys.readouterr().err


def test_help_names_units_and_defaults(capsys):
    with pytest.raises(SystemExit):
        _run(["scan", "--help"])
    text = capsys.readouterr().out
    for word in ("--resolution M", "metres", "--k K", "--noise M", "--preset", "default", "--heads",
                 "--misalign-deg DEG", "--outliers FRACTION", "--preview PNG", "--seed SEED", "degrees"):
        assert word in text, word
