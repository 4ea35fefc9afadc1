"""Per-section Delaunay surfaces against analytic cylinders and capsules."""

import numpy as np
import pytest

from bodyscan.recon.model import SECTIONS, BodyFit, SectionShape
from bodyscan.recon.params import SurfaceParams
from bodyscan.recon.surface import mesh as S
from views import ellipsoid, front_rear_zbuffer


def edge_counts(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u, c


def cylinder_points(n=3000, radius=0.05, length=0.4, seed=0):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, length, n)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t), z])


def test_open_cylinder_gives_a_tube_of_its_points():
    P = cylinder_points()
    shape = SectionShape("upper_arm_l", [0, 0, 0], [0, 0, 0.4], [0.05, 0.05], [1, 0, 0], closed=(False, False))
    # the peel in spacings alone (our floor, hull_edge_min, keeps rim slivers up to it: below)
    f = S.section_surface(P, shape, SurfaceParams(hull_edge_min=0.0))
    floor = S.section_surface(P, shape)
    assert S.max_edge_length(P, floor).max() <= SurfaceParams().hull_edge_min
    u, c = edge_counts(f)
    assert len(np.unique(f)) >= 0.99 * len(P)            # (almost) every point is a vertex
    assert (c <= 2).all()                                # manifold
    boundary = u[c == 1]
    zb = P[boundary][:, :, 2].mean(axis=1)
    near_rim = (zb < 0.03) | (zb > 0.37)
    assert near_rim.mean() > 0.9                         # open only at the two rims
    # the tube goes all the way round: edges cross the theta seam, and no edge is long
    theta = np.arctan2(P[:, 1], P[:, 0])
    ef = u[c == 2]
    assert (np.abs(np.diff(theta[ef], axis=1)) > np.pi).any()
    assert np.linalg.norm(P[ef[:, 0]] - P[ef[:, 1]], axis=1).max() < 0.03
    # normals, once oriented with the model, point away from the axis
    fit = BodyFit(sections={"upper_arm_l": shape}, joints={})
    fo = S.orient_faces(P, f, np.full(len(f), 3, np.int8), fit)
    p = P[fo]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    radial = p.mean(axis=1) * [1, 1, 0]
    assert (np.einsum("ij,ij->i", n, radial) > 0).all()


def capsule_points(n=4000, seed=0):
    import trimesh

    mesh = trimesh.creation.capsule(height=0.4, radius=0.06, count=[64, 64])
    P, _ = trimesh.sample.sample_surface_even(mesh, n, seed=seed)
    return np.asarray(P)


@pytest.mark.parametrize("seed", [0, 1])
def test_closed_capsule_is_nearly_watertight(seed):
    P = capsule_points(seed=seed)
    shape = SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0])
    f = S.section_surface(P, shape)
    u, c = edge_counts(f)
    assert len(np.unique(f)) == len(P)
    assert (c != 2).sum() < 0.005 * len(u)               # seams between column and caps close
    # no overlapping cap/column triangles: total area close to the capsule's
    true_area = 2 * np.pi * 0.06 * 0.4 + 4 * np.pi * 0.06 ** 2
    assert abs(S.face_areas(P, f).sum() / true_area - 1) < 0.03


def test_peel_removes_only_long_boundary_triangles():
    from scipy.spatial import Delaunay

    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    g = g[~((g[:, 0] >= 4) & (g[:, 0] <= 5) & (g[:, 1] >= 4) & (g[:, 1] <= 5))]  # interior hole
    g = np.vstack([g, [[4.5, 30.0]]])                                           # far point: slivers
    tri = Delaunay(g)
    P = np.column_stack([g, np.zeros(len(g))])
    long = S.max_edge_length(P, tri.simplices) > 2.0
    alive = S.peel_boundary(tri.simplices, long)
    kept = tri.simplices[alive]
    assert not (kept == len(g) - 1).any()                  # the far point's slivers went
    hole = long & ~np.isin(tri.simplices, [len(g) - 1]).any(axis=1)
    assert hole.any() and alive[hole].all()                # the interior hole stays covered


def test_max_edge_factor_opens_holes():
    P = cylinder_points(n=4000)
    P = P[~((np.abs(P[:, 2] - 0.2) < 0.04) & (P[:, 0] > 0.02))]  # a hole in the data
    shape = SectionShape("upper_arm_l", [0, 0, 0], [0, 0, 0.4], [0.05, 0.05], [1, 0, 0], closed=(False, False))
    covered = S.section_surface(P, shape)
    opened = S.section_surface(P, shape, SurfaceParams(max_edge_factor=3.0))
    assert len(opened) < len(covered)
    assert S.max_edge_length(P, covered).max() > 0.05      # paper default: the hole is covered
    assert S.max_edge_length(P, opened).max() < 3.0 * 0.02


def test_column_chart_copies_the_seam():
    theta = np.array([0.1, 3.0, 6.2])
    uv, src = S.column_chart(theta, np.zeros(3), 1.0, 0.5)
    assert sorted(src.tolist()) == [0, 0, 1, 2, 2]
    assert np.isclose(uv[3, 0], 0.1 + 2 * np.pi) and np.isclose(uv[4, 0], 6.2 - 2 * np.pi)


def test_merge_drops_inner_and_duplicate_faces():
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0], [2, 2, 0]])
    member = np.zeros((5, 11), bool)
    member[:, 1] = True
    member[[1, 2, 3], 2] = True                     # points 1, 2, 3 in two sections
    per = {1: np.array([[0, 1, 2], [1, 3, 2]]), 2: np.array([[2, 1, 0], [1, 2, 3]])}
    faces, sec = S.merge_sections(P, per, member)
    assert faces.tolist() == [[0, 1, 2]] and sec.tolist() == [1]


def test_orientation_follows_view_dir():
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1.0]])
    fit = BodyFit(sections={"chest": SectionShape("chest", [0, 1, 0], [0, 1, 1], [0.5, 0.5], [1, 0, 0])},
                  joints={})
    for vd in ((0, -1, 0), (0, 1, 0)):
        f = S.orient_faces(P, np.array([[0, 1, 2]]), np.array([1], np.int8), fit, np.array(vd, float))
        p = P[f[0]]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        assert n @ np.array(vd) > 0


def test_orientation_of_a_face_edge_on_to_its_camera_follows_the_model():
    # a thigh column along z, radius 0.1; a triangle on its +x flank, seen edge-on from the camera
    # at +y (view_dir +y) and tilted slightly away from it: the view alone turns it inward
    fit = BodyFit(sections={"thigh_l": SectionShape("thigh_l", [0, 0, 0], [0, 0, 1], [0.1, 0.1], [1, 0, 0])},
                  joints={})
    tilt = 0.1                                         # the normal is (1, -tilt, 0), outward
    P = np.array([[0.1, 0, 0.4], [0.1 + tilt * 0.02, 0.02, 0.4], [0.1, 0, 0.45]])
    sec = np.array([SECTIONS.index("thigh_l")], np.int8)
    vd = np.array([0, 1.0, 0])

    def normal(w):
        p = P[S.orient_faces(P, np.array([[0, 1, 2]]), sec, fit, vd, model_weight=w)[0]]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        return n / np.linalg.norm(n)

    assert normal(0.0)[0] < 0                          # the paper's rule: toward the camera, inward
    assert normal(0.5)[0] > 0.99                       # with the model: outward
    assert normal(0.05)[0] < 0                         # a weight under the tilt: the camera decides


def test_small_section_is_skipped_with_a_warning():
    P = np.vstack([capsule_points(n=800), [[1.0, 1.0, 1.0], [1.01, 1.0, 1.0], [1.0, 1.01, 1.0]]])
    fit = BodyFit(sections={
        "thigh_l": SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0]),
        "head": SectionShape("head", [1, 1, 0.9], [1, 1, 1.1], [0.05, 0.05], [1, 0, 0])}, joints={})
    member = np.zeros((len(P), 11), bool)
    member[:800, SECTIONS.index("thigh_l")] = True
    member[800:, 0] = True
    with pytest.warns(UserWarning, match="head"):
        faces, sec, skipped = S.reconstruct_surfaces(P, member, fit)
    assert skipped == ["head"] and len(faces) > 1000 and (sec == SECTIONS.index("thigh_l")).all()


def test_points_no_section_took_are_meshed_and_outliers_are_not():
    """A patch of a capsule's points the clustering left in no section, though within T_d (no far
    chart took them either: the toes of a foot placed wrongly), is meshed on a chart of its own,
    joined to the surface around it and lying on the capsule (no face in the air); so is a piece
    apart from it (a cap of a sphere 10 cm off: a piece of a limb the fit missed); the points
    marked as outliers stay out of every face."""
    P = capsule_points(n=4000)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(150, 3))
    d = d[d[:, 0] > 0] / np.linalg.norm(d[d[:, 0] > 0], axis=1)[:, None]
    piece = np.array([0.2, 0.0, 0.0]) + 0.03 * d          # a hemisphere of radius 3 cm facing +x
    P = np.vstack([P, piece])
    thigh = SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0])
    fit = BodyFit(sections={"thigh_l": thigh}, joints={})
    member = np.zeros((len(P), 11), bool)
    apart = np.arange(len(P)) >= len(P) - len(piece)
    patch = (P[:, 2] > 0.0) & (P[:, 2] < 0.12) & (P[:, 0] > 0.02) & ~apart
    member[~patch & ~apart, SECTIONS.index("thigh_l")] = True
    outliers = patch & (P[:, 2] > 0.1)
    faces, sec, _ = S.reconstruct_surfaces(P, member, fit, outliers=outliers)
    used = np.zeros(len(P), bool)
    used[faces.ravel()] = True
    assert used[patch & ~outliers].mean() > 0.97
    assert used[apart].mean() > 0.9
    assert not used[outliers].any()
    # the piece is meshed on its own: no face joins it to the capsule through the air
    on_piece = faces[np.isin(faces, np.flatnonzero(apart)).any(axis=1)]
    assert apart[on_piece].all()
    off = np.linalg.norm(P[on_piece].mean(axis=1) - [0.2, 0.0, 0.0], axis=1) - 0.03
    assert off.max() < 0.001 and off.min() > -0.006
    c = P[faces[np.isin(faces, np.flatnonzero(patch)).any(axis=1)]].mean(axis=1)
    # distance of each face's centre from the capsule's surface (axis z in -0.2..0.2, radius 0.06)
    off = np.hypot(np.hypot(c[:, 0], c[:, 1]), np.clip(np.abs(c[:, 2]) - 0.2, 0, None)) - 0.06
    assert len(c) > 200 and off.max() < 0.001 and off.min() > -0.005


def test_delaunay_of_degenerate_charts():
    """Too few, collinear or coincident points give no triangle rather than an error."""
    from bodyscan.recon.surface.mesh import _delaunay

    assert _delaunay(np.zeros((2, 2))) is None
    assert _delaunay(np.array([[0.0, 0], [1, 1], [2, 2]])) is None   # collinear
    assert _delaunay(np.zeros((5, 2))) is None                         # coincident
    square = _delaunay(np.array([[0.0, 0], [1, 0], [0, 1], [1, 1]]))
    assert square.shape == (2, 3)


def skirt_points(step=0.01, R=0.05, L=0.4, gap=0.05, z0=0.15, z1=0.27, width=1.2, seed=0):
    """A tube (radius ``R``) with a skirt over part of its circumference: a roof at ``z1`` out to
    ``R + gap`` and a sheet hanging from it down to ``z0``, like curled fingers over the palm.
    Jittered grid of ``step`` metres. Returns the points and the number of tube points (first)."""
    rng = np.random.default_rng(seed)

    def sheet(u0, u1, v0, v1):
        u, v = np.meshgrid(np.arange(u0, u1, step), np.arange(v0, v1, step))
        q = np.column_stack([u.ravel(), v.ravel()])
        return q + rng.uniform(-0.3, 0.3, q.shape) * step

    q = sheet(0, 2 * np.pi * R, 0, L)
    tube = np.column_stack([R * np.cos(q[:, 0] / R), R * np.sin(q[:, 0] / R), q[:, 1]])
    Rl = R + gap
    q = sheet(-width / 2 * Rl, width / 2 * Rl, z0, z1)
    lip = np.column_stack([Rl * np.cos(q[:, 0] / Rl), Rl * np.sin(q[:, 0] / Rl), q[:, 1]])
    q = sheet(-width / 2 * R, width / 2 * R, R + step / 2, Rl)
    t = q[:, 0] / R
    roof = np.column_stack([q[:, 1] * np.cos(t), q[:, 1] * np.sin(t), np.full(len(q), z1)])
    return np.vstack([tube, lip, roof]), len(tube)


def _tilt():
    """A rotation (3, 3) taking +z to a tilted axis, so that the section frame is not the identity."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", [0.7, -0.4, 1.1]).as_matrix()


def test_fold_rule_removes_the_triangles_across_a_fold():
    """Under the skirt the tube's and the skirt's points interleave in the column chart: Delaunay
    joins the two layers with triangles in the air (centroid between the tube and the skirt).
    The fold rule removes them; switched off (fold_cos = -1), the paper's surface keeps them."""
    P, nt = skirt_points()
    Rm = _tilt()
    shape = SectionShape("forearm_l", Rm @ [0, 0, 0], Rm @ [0, 0, 0.4], [0.05, 0.05], Rm @ [1, 0, 0],
                         closed=(False, False))
    Pw = P @ Rm.T

    def air_area(faces):
        c = P[faces].mean(axis=1)
        r = np.hypot(c[:, 0], c[:, 1])
        air = (r > 0.055) & (r < 0.095) & (c[:, 2] < 0.265)
        return S.face_areas(P, faces[air]).sum()

    paper = S.section_surface(Pw, shape, SurfaceParams(fold_cos=-1.0))
    folded = S.section_surface(Pw, shape)
    assert air_area(paper) > 0.05                    # m^2: hundreds of cm^2 across the fold
    assert air_area(folded) < 0.05 * air_area(paper)
    # the tube away from the skirt is untouched
    far = lambda f: f[(P[f][:, :, 2].min(axis=1) > 0.3) | (P[f][:, :, 2].max(axis=1) < 0.12)]
    assert S.face_keys(far(paper)).tolist() == S.face_keys(far(folded)).tolist()


@pytest.mark.parametrize("closed", [(False, False), (True, True)])
def test_fold_rule_keeps_convex_tubes_whole(closed):
    """On a convex tube or capsule nothing folds: the rule removes no triangle."""
    Rm = _tilt()
    if closed[0]:
        P = capsule_points() @ Rm.T
        shape = SectionShape("thigh_l", Rm @ [0, 0, -0.2], Rm @ [0, 0, 0.2], [0.06, 0.06], Rm @ [1, 0, 0])
    else:
        P = cylinder_points() @ Rm.T
        shape = SectionShape("upper_arm_l", [0, 0, 0], Rm @ [0, 0, 0.4], [0.05, 0.05], Rm @ [1, 0, 0],
                             closed=closed)
    on = S.section_surface(P, shape, SurfaceParams(fold_cos=0.0, fold_edge_factor=0.0))
    off = S.section_surface(P, shape, SurfaceParams(fold_cos=-1.0))
    assert len(on) > 1000 and on.tolist() == off.tolist()


def test_chart_agreement_sign():
    """+1 for a counter-clockwise chart triangle whose normal points along the chart's direction,
    -1 when flipped, 0 for one standing on edge."""
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 1, 2], [0, 1, 2], [0, 1, 3]])
    uv = np.array([[[0, 0], [1, 0], [0, 1]], [[0, 0], [0, 1], [1, 0]], [[0, 0], [1, 0], [0, 1]]], float)
    d = np.array([[0, 0, 1.0]] * 3)
    assert np.allclose(S.chart_agreement(P, f, uv, d), [1, -1, 0])


def test_seen_through_removes_only_what_a_ray_crossed():
    """A sheet of points seen from +z: a triangle floating 3 cm above points is air (their rays
    cross it); the same triangle over a hole in the data (no point below) stays, as does a
    triangle of the sheet itself, even with noise."""
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.arange(0, 0.3, 0.01), np.arange(0, 0.3, 0.01)), -1).reshape(-1, 2)
    hole = (np.abs(g[:, 0] - 0.22) < 0.045) & (np.abs(g[:, 1] - 0.15) < 0.045)
    g = g[~hole]
    P = np.column_stack([g, rng.normal(0, 0.0005, len(g))])
    extra = np.array([[0.05, 0.10, 0.03], [0.10, 0.10, 0.03], [0.07, 0.15, 0.03],     # over points
                      [0.20, 0.13, 0.03], [0.24, 0.13, 0.03], [0.22, 0.17, 0.03]])    # over the hole
    P = np.vstack([P, extra])
    n = len(P)
    in_sheet = np.array([np.argmin(np.linalg.norm(g - [0.1, 0.1], axis=1)),
                         np.argmin(np.linalg.norm(g - [0.13, 0.1], axis=1)),
                         np.argmin(np.linalg.norm(g - [0.1, 0.13], axis=1))])
    faces = np.array([[n - 6, n - 5, n - 4], [n - 3, n - 2, n - 1], in_sheet])
    vd = np.tile([0.0, 0.0, 1.0], (n, 1))
    got = S.seen_through(P, faces, vd, 0.01, margin=0.5, min_edge=0.0)
    assert got.tolist() == [True, False, False]
    # seen from the side instead, no ray crosses the floating triangle
    side = S.seen_through(P, faces, np.tile([1.0, 0, 0], (n, 1)), 0.01, margin=0.5, min_edge=0.0)
    assert not side.any()


def test_carving_keeps_a_convex_capsule_whole():
    """Points seen from outside a convex body: no ray crosses its surface, nothing is carved."""
    P = capsule_points()
    shape = SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0])
    fit = BodyFit(sections={"thigh_l": shape}, joints={})
    member = np.zeros((len(P), 11), bool)
    member[:, SECTIONS.index("thigh_l")] = True
    normal = P - np.column_stack([np.zeros((len(P), 2)), np.clip(P[:, 2], -0.2, 0.2)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    vd = normal + [0.4, -0.3, 0.5]                   # cameras off the normal, on the outside
    vd /= np.linalg.norm(vd, axis=1, keepdims=True)
    vd = np.where(np.einsum("ij,ij->i", vd, normal)[:, None] > 0.3, vd, normal)
    on = S.reconstruct_surfaces(P, member, fit, SurfaceParams(carve_margin=0.1, carve_min_edge=0.0), vd)[0]
    off = S.reconstruct_surfaces(P, member, fit, SurfaceParams(carve_margin=0.0), vd)[0]
    assert len(on) > 1000 and S.face_keys(on).tolist() == S.face_keys(off).tolist()


def test_view_consistency_flags_triangles_facing_away_from_a_camera():
    """Front camera -y, rear camera +y. A triangle of the front surface faces its cameras (+1); an
    edge-on triangle at a silhouette, vertices seen from both sides, is on the limit (0); a triangle
    from two front points of one thigh to a rear point of the other, tilted 45 degrees, faces away
    from one camera whichever way it is turned (-0.71); one camera for all: never below 0."""
    P = np.array([[0.00, -0.05, 0.00], [0.02, -0.05, 0.00], [0.00, -0.05, 0.02],    # front sheet
                  [0.05, -0.01, 0.00], [0.05, 0.01, 0.00], [0.05, 0.00, 0.02],      # silhouette
                  [0.00, 0.00, 0.00], [0.00, 0.00, 0.03], [0.03, 0.03, 0.01]])       # across a gap
    vd = np.array([[0, -1, 0]] * 3 + [[0, -1, 0], [0, 1, 0], [0, -1, 0]] + [[0, -1, 0]] * 2 + [[0, 1, 0]],
                  dtype=float)
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    c = S.view_consistency(P, faces, vd)
    assert np.allclose(c, [1.0, 0.0, -np.sqrt(0.5)])
    assert np.allclose(S.view_consistency(P, faces[::-1, ::-1], vd), c[::-1])   # orientation-free
    assert (S.view_consistency(P, faces, np.array([0.0, -1.0, 0.0])) >= 0).all()


def test_view_consistency_keeps_a_convex_capsule_seen_front_and_rear_whole():
    """Every point of a convex capsule seen by the front or the rear camera, whichever faces it:
    the triangles around its silhouettes turn with the surface and are kept, nothing is removed."""
    P = capsule_points()
    shape = SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0])
    fit = BodyFit(sections={"thigh_l": shape}, joints={})
    member = np.zeros((len(P), 11), bool)
    member[:, SECTIONS.index("thigh_l")] = True
    vd = np.column_stack([np.zeros(len(P)), np.where(P[:, 1] >= 0, 1.0, -1.0), np.zeros(len(P))])
    base = dict(carve_margin=0.0, workers=1)
    on = S.reconstruct_surfaces(P, member, fit, SurfaceParams(facing_min_edge=0.0, **base), vd)[0]
    off = S.reconstruct_surfaces(P, member, fit, SurfaceParams(facing_cos=-1.0, **base), vd)[0]
    assert len(on) > 1000 and S.face_keys(on).tolist() == S.face_keys(off).tolist()


def _groove(sign, t=0.6, step=0.01):
    """Grid points on z = sign * t * |x| (sign +1: a V-groove, concave seen from +z; -1: a ridge),
    seen from +z, and a triangle from the two sides' points at x = -5 and +5 cm."""
    g = np.stack(np.meshgrid(np.arange(-0.1, 0.1001, step), np.arange(-0.1, 0.1001, step)), -1).reshape(-1, 2)
    P = np.column_stack([g, sign * t * np.abs(g[:, 0])])
    at = lambda x, y: int(np.argmin(np.linalg.norm(g - [x, y], axis=1)))
    return P, np.array([[at(-0.05, -0.02), at(0.05, 0.0), at(-0.05, 0.02)]])


def test_point_normals_face_the_camera():
    P, _ = _groove(1)
    idx = np.flatnonzero((np.abs(P[:, 0] - 0.05) < 1e-9) & (np.abs(P[:, 1]) < 0.05))
    n = S.point_normals(P, idx, np.array([0.0, 0.0, 1.0]), k=8)
    expect = np.array([-0.6, 0.0, 1.0]) / np.hypot(0.6, 1.0)       # right side of the groove
    assert np.allclose(n, expect, atol=1e-6)


def test_over_concavity_sign():
    """A triangle across a V-groove (a cover over a concave hole) stands in front of the tangent
    planes at all its vertices (here by 1.7 cm); across a ridge (a convex hole's cover, inside the
    body) behind them; on a plane it lies in them."""
    up = np.array([0.0, 0.0, 1.0])
    heights = []
    for sign in (1, -1, 0):
        P, f = _groove(sign)
        nrm = S.point_normals(P, f.ravel(), up, k=8).reshape(-1, 3, 3)
        heights.append(S.over_concavity(P, f, nrm)[0])
    lift = (0.1 / 3) * 0.6 / np.hypot(0.6, 1.0)                   # centroid 3.3 cm in from a side
    assert np.allclose(heights[0], [lift, 2 * lift, lift], atol=1e-6)
    assert np.allclose(heights[1], [-lift, -2 * lift, -lift], atol=1e-6)
    assert np.allclose(heights[2], 0.0, atol=1e-6)


def test_concave_rule_keeps_the_cover_of_a_hole_in_convex_surface():
    """A capsule seen from outside with a 6 cm hole in the data: the paper covers it; the cover
    lies inside the body, behind the tangent planes, and the concavity rule keeps it."""
    P = capsule_points()
    P = P[np.linalg.norm(P - [0.06, 0.0, 0.0], axis=1) > 0.03]
    shape = SectionShape("thigh_l", [0, 0, -0.2], [0, 0, 0.2], [0.06, 0.06], [1, 0, 0])
    fit = BodyFit(sections={"thigh_l": shape}, joints={})
    member = np.zeros((len(P), 11), bool)
    member[:, SECTIONS.index("thigh_l")] = True
    axis = np.column_stack([np.zeros((len(P), 2)), np.clip(P[:, 2], -0.2, 0.2)])
    vd = (P - axis) / np.linalg.norm(P - axis, axis=1, keepdims=True)
    base = dict(carve_margin=0.0, facing_cos=-1.0, workers=1)
    on = S.reconstruct_surfaces(P, member, fit, SurfaceParams(concave_min_edge=0.0, **base), vd)[0]
    off = S.reconstruct_surfaces(P, member, fit, SurfaceParams(concave_height=0.0, **base), vd)[0]
    longest = S.max_edge_length(P, off)
    assert longest.max() > 4 * S.median_spacing(P)                 # the hole is covered ...
    assert S.face_keys(on).tolist() == S.face_keys(off).tolist()   # ... and stays covered


def test_median_spacing_skips_repeated_points():
    """Heads whose fields overlap can measure the same position twice: the spacing is that of the
    distinct positions (a 1 cm grid), not 0, which would make every triangle "long"."""
    g = np.stack(np.meshgrid(np.arange(0, 0.3, 0.01), np.arange(0, 0.3, 0.01)), -1).reshape(-1, 2)
    P = np.column_stack([g, np.zeros(len(g))])
    assert np.isclose(S.median_spacing(P), 0.01)
    assert np.isclose(S.median_spacing(np.vstack([P, P, P])), 0.01)


def test_view_edge_length_is_the_gap_the_camera_saw():
    # a steep plane (y = 5 x) sampled on the camera's 1 cm grid across its view (-y): 5 cm apart
    # in 3D along x, 1 cm to the camera; a triangle with a vertex seen along another axis: in 3D
    x, z = np.meshgrid(np.arange(0, 0.05, 0.01), np.arange(0, 0.05, 0.01))
    P = np.column_stack([x.ravel(), 5 * x.ravel(), z.ravel()])
    f = np.array([[0, 1, 5], [1, 6, 5]])          # x steps 0->1, z steps 0->5
    front = np.tile([0.0, -1.0, 0.0], (len(P), 1))
    assert np.allclose(S.view_edge_length(P, f, front), np.hypot(0.01, 0.01))
    assert np.allclose(S.view_edge_length(P, f, None), S.max_edge_length(P, f))
    # a vertex seen from behind, along the same axis (the rear head): measured across it as well
    rear = front.copy()
    rear[6] *= -1
    assert np.allclose(S.view_edge_length(P, f, rear), np.hypot(0.01, 0.01))
    # a vertex seen along another axis: in 3D
    side = front.copy()
    side[6] = [1.0, 0.0, 0.0]
    assert np.allclose(S.view_edge_length(P, f, side), [np.hypot(0.01, 0.01), S.max_edge_length(P, f)[1]])
    # bounded by the 3D length over the stretch: steeper than 1.5 counts as a depth step
    assert np.allclose(S.view_edge_length(P, f, front, stretch=1.5), S.max_edge_length(P, f) / 1.5)


def front_rear_cylinder(R, x, z):
    """Points (2m, 3) of the cylinder of radius ``R`` about the z axis that parallel cameras in
    front (-y) and behind (+y) sample on the grid of columns ``x`` and rows ``z``, and their unit
    view directions (2m, 3)."""
    x, z = np.meshgrid(x, z)
    x, z = x.ravel(), z.ravel()
    y = np.sqrt(R ** 2 - x ** 2)
    P = np.concatenate([np.column_stack([x, -y, z]), np.column_stack([x, y, z])])
    return P, np.repeat([[0, -1.0, 0], [0, 1.0, 0]], len(x), axis=0)


def test_peel_keeps_the_steep_flanks_the_camera_saw():
    # a cylinder scanned from front and back by parallel projection: columns 6 mm apart across
    # the view, rows 2 mm apart along the axis (median spacing 2 mm, peel limit 8 mm). Toward the
    # silhouettes the columns are more than 8 mm apart in 3D: a 3D peel eats the flanks through
    # the hull's boundary; measured as the camera saw them (6 mm) they stay, on the cylinder
    R = 0.05
    P, vd = front_rear_cylinder(R, np.arange(-0.048, 0.0481, 0.006), np.arange(0, 0.3, 0.002))
    shape = SectionShape("upper_arm_l", [0, 0, 0], [0, 0, 0.3], [R, R], [1, 0, 0], closed=(False, False))
    params = SurfaceParams(hull_edge_min=0.0, peel_stretch=3.0)    # flanks up to 2.4 cm in 3D
    flat = S.section_surface(P, shape, params)
    seen = S.section_surface(P, shape, params, view_dir=vd)
    assert len(np.setdiff1d(np.arange(len(P)), flat)) > 0.1 * len(P)     # the 3D peel leaves out flanks
    assert len(np.unique(seen)) == len(P)                                 # every point in a face
    c = P[seen].mean(axis=1)
    # on the surface: chords, the deepest across the 2.8 cm gap between the two heads' images
    # (sagitta 2 mm), which both sampled on the same columns: closed too, the whole tube
    assert (R - np.hypot(c[:, 0], c[:, 1])).max() < 0.002
    assert S.face_areas(P, seen).sum() > 0.97 * 2 * np.pi * R * 0.298


def test_chart_edge_limit_keeps_unseen_rims_up_to_max_edge_min():
    # a cylinder (R 5 cm) scanned front and rear on a 5 mm grid: each camera's image stops 2.5 mm
    # inside the silhouette, so the rims between the two images are 3.1 cm wide and unseen. An
    # edge limit of 4 spacings (2 cm, a hand's or a foot's chart) leaves them open, whatever the
    # peel keeps; at least max_edge_min (4 cm), as on a 1 cm scan, they are closed by faces on the
    # surface
    R = 0.05
    P, vd = front_rear_cylinder(R, np.linspace(-0.0475, 0.0475, 20), np.arange(0, 0.2, 0.005))
    front = vd[:, 1] < 0
    shape = SectionShape("foot_l", [0, 0, 0], [0, 0, 0.2], [R, R], [1, 0, 0], closed=(False, False))
    spacings = S.section_surface(P, shape, SurfaceParams(max_edge_factor=4.0, max_edge_min=0.0), view_dir=vd)
    floor = S.section_surface(P, shape, SurfaceParams(max_edge_factor=4.0), view_dir=vd)
    rim = lambda f: f[front[f].any(axis=1) & ~front[f].all(axis=1)]
    assert len(rim(spacings)) == 0                                      # the rims stay open
    assert len(rim(floor)) > 2 * 0.9 * 0.2 / 0.005                      # both rims closed along z
    assert S.max_edge_length(P, floor).max() <= SurfaceParams().max_edge_min
    c = P[floor].mean(axis=1)
    assert (R - np.hypot(c[:, 0], c[:, 1])).max() < 0.003                # chords of the cylinder
    assert S.face_areas(P, floor).sum() > 0.97 * 2 * np.pi * R * 0.195    # the whole tube


def test_coarse_scan_keeps_the_flanks_between_front_and_rear_views():
    # a thigh-sized cylinder (R 6 cm) scanned front and rear on a 1 cm grid: each camera's image
    # stops 5 mm inside the silhouette, so the flanks between the two images are 4.8 cm wide and
    # unseen. proposed's peel (6 spacings) closes them with chords of the cylinder; the paper's
    # (4 spacings in 3D, no floor: `PAPER`) leaves them open
    R = 0.06
    P, vd = front_rear_cylinder(R, np.arange(-0.055, 0.0551, 0.01), np.arange(0, 0.3, 0.01))
    front = vd[:, 1] < 0
    shape = SectionShape("thigh_l", [0, 0, 0], [0, 0, 0.3], [R, R], [1, 0, 0], closed=(False, False))
    proposed = S.section_surface(P, shape, SurfaceParams(), view_dir=vd)
    paper = S.section_surface(P, shape, SurfaceParams(hull_edge_factor=4.0, peel_same_side=2.0, hull_edge_min=0.0),
                              view_dir=vd)
    flank = lambda f: f[front[f].any(axis=1) & ~front[f].all(axis=1)]
    assert len(flank(paper)) == 0                                        # open flanks
    assert len(flank(proposed)) > 2 * 0.9 * 0.3 / 0.01                   # both flanks closed along z
    c = P[proposed].mean(axis=1)
    assert (R - np.hypot(c[:, 0], c[:, 1])).max() < 0.0051               # chords: 4.8 cm, sagitta 5 mm
    assert S.face_areas(P, proposed).sum() > 0.97 * 2 * np.pi * R * 0.29  # the whole tube


def test_rejoin_puts_left_out_points_back_with_short_triangles():
    # a tube whose faces around a band of points were removed (as the peel or the air rules do):
    # the band's points come back in short triangles on the tube, none repeating a kept face
    P = cylinder_points(n=4000)
    shape = SectionShape("upper_arm_l", [0, 0, 0], [0, 0, 0.4], [0.05, 0.05], [1, 0, 0], closed=(False, False))
    f = S.section_surface(P, shape)
    sp = S.median_spacing(P)
    band = (P[:, 2] > 0.18) & (P[:, 2] < 0.2) & (P[:, 0] > 0)
    kept = f[~band[f].any(axis=1)]
    more, sec = S.rejoin_left_out(P, kept, [(3, np.arange(len(P)), shape)], SurfaceParams(), sp, 2.5)
    short = f[S.max_edge_length(P, f) <= 2.5 * sp]          # points with a short triangle before
    back = np.intersect1d(np.flatnonzero(band), short)
    assert len(back) > 0.75 * band.sum()
    assert len(np.setdiff1d(back, np.concatenate([kept.ravel(), more.ravel()]))) == 0
    assert (S.max_edge_length(P, more) <= 2.5 * sp + 1e-12).all()
    assert (sec == 3).all() and not np.isin(S.face_keys(more), S.face_keys(kept)).any()
    c = P[more].mean(axis=1)
    assert (0.05 - np.hypot(c[:, 0], c[:, 1])).max() < 0.002                 # on the tube


def test_cover_max_edge_leaves_large_holes_open_and_covers_small_ones():
    P = cylinder_points(n=6000)
    big = (np.abs(P[:, 2] - 0.13) < 0.08) & (P[:, 0] < -0.02)      # 16 by 12 cm, off the seam
    small = (np.abs(P[:, 2] - 0.3) < 0.012) & (P[:, 0] > 0.035)    # 2.4 by 3 cm
    P = P[~big & ~small]
    shape = SectionShape("upper_arm_l", [0, 0, 0], [0, 0, 0.4], [0.05, 0.05], [1, 0, 0], closed=(False, False))
    paper = S.section_surface(P, shape, SurfaceParams(cover_max_edge=0.0))
    ours = S.section_surface(P, shape, SurfaceParams(cover_max_edge=0.06))
    assert S.max_edge_length(P, paper).max() > 0.08                    # the paper covers the big hole
    assert S.max_edge_length(P, ours).max() <= 0.06
    hole = 0.16 * 0.05 * 2 * np.arccos(0.02 / 0.05)                     # the big hole's true area
    assert S.face_areas(P, paper).sum() - S.face_areas(P, ours).sum() > 0.5 * hole
    for f in (paper, ours):                                             # the small hole: covered
        c = P[f].mean(axis=1)
        assert ((np.abs(c[:, 2] - 0.3) < 0.006) & (c[:, 0] > 0.045)).any()


def test_view_surface_meshes_a_flat_hand_on_its_surface():
    # a flat ellipsoid (a hand, 9 x 3 x 18 cm) seen front and rear on a 5 mm grid: each camera's
    # range image is triangulated across its view, so every face lies on the surface (a face
    # joining the front to the back would pass 1.5 cm inside) and almost every point is in a face
    a = np.array([0.045, 0.015, 0.09])
    P, N = ellipsoid(a, 300)
    keep, vd = front_rear_zbuffer(P, N, 0.005)
    P, vd = P[keep], vd[keep]
    f = S.view_surface(P, vd, SurfaceParams(), 0.005)
    assert len(np.unique(f)) > 0.95 * len(P)
    c = P[f].mean(axis=1)
    g = ((c / a) ** 2).sum(axis=1)                 # 1 on the surface
    depth = (1 - g) / np.linalg.norm(2 * c / a ** 2, axis=1)
    assert depth.max() < 0.0015
    assert (vd[f][:, :, 1] == vd[f][:, :1, 1]).all()                 # one camera per face
    area = S.face_areas(P, f).sum()
    assert area > 0.85 * 4 * np.pi * (((a[0] * a[1]) ** 1.6 + (a[0] * a[2]) ** 1.6 + (a[1] * a[2]) ** 1.6) / 3) ** (1 / 1.6)


def test_view_surface_does_not_join_a_depth_step():
    # two plates 10 cm apart in depth, the front one hiding half of the rear one: next to each other
    # in the camera's image, 10 cm apart in 3D. Both are meshed, nothing joins them
    x, z = np.meshgrid(np.arange(0, 0.1, 0.01), np.arange(0, 0.1, 0.01))
    front = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    rear = np.column_stack([x.ravel() + 0.1, np.full(x.size, 0.1), z.ravel()])
    P = np.concatenate([front, rear])
    f = S.view_surface(P, np.array([0, -1.0, 0]), SurfaceParams(), 0.01)
    which = (f >= len(front)).sum(axis=1)
    assert ((which == 0) | (which == 3)).all()
    assert len(np.unique(f)) == len(P)


def test_view_surface_closes_the_rim_between_the_cameras_images():
    # an ellipsoid (5 x 3 x 18 cm) seen front and rear on a 5 mm grid: the two range images leave
    # the rim between their silhouettes open (a fifth of the area); the faces of a column chart
    # around the points that join the two cameras' points close it, as chords within the rim
    from bodyscan.recon.surface.complete import part_shape

    a = np.array([0.05, 0.03, 0.09])
    P, N = ellipsoid(a, 400)
    keep, vd = front_rear_zbuffer(P, N, 0.005)
    P, vd = P[keep], vd[keep]
    p = 1.6   # Thomsen's approximation of the ellipsoid's area (within about 1 %)
    true = 4 * np.pi * (((a[0] * a[1]) ** p + (a[0] * a[2]) ** p + (a[1] * a[2]) ** p) / 3) ** (1 / p)
    images = S.view_surface(P, vd, SurfaceParams(), 0.005)
    closed = S.view_surface(P, vd, SurfaceParams(), 0.005, part_shape(P, np.zeros((0, 3)), "forearm_l"))
    assert S.face_areas(P, images).sum() < 0.85 * true < 0.9 * true < S.face_areas(P, closed).sum() < true
    assert np.isin(S.face_keys(images), S.face_keys(closed)).all()
    c = P[closed].mean(axis=1)
    depth = (1 - ((c / a) ** 2).sum(axis=1)) / np.linalg.norm(2 * c / a ** 2, axis=1)
    assert depth.max() < 0.005 and depth.min() > -0.0005              # chords, never outside
    rim = closed[~np.isin(S.face_keys(closed), S.face_keys(images))]
    assert len(rim) and (vd[rim][:, :, 1] > 0).any(axis=1).all() and (vd[rim][:, :, 1] < 0).any(axis=1).all()


def test_normal_agreement_is_the_cosine_of_the_tilt():
    """On a plane with its true normals a face lifted at one corner by a known angle agrees by
    that angle's cosine; across a V-groove (vertex normals at +-31 degrees to the horizontal cover)
    by cos(31 degrees); a degenerate face counts as agreeing."""
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    for deg in (0.0, 20.0, 60.0):
        t = np.radians(deg)
        P = np.array([[0.0, 0.0, 0.0], [0.0, 0.02, 0.0], [0.02 * np.cos(t), 0.0, 0.02 * np.sin(t)]])
        assert np.isclose(S.normal_agreement(P, np.array([[0, 1, 2]]), up[None])[0], np.cos(t))
    P, f = _groove(1)
    nrm = S.point_normals(P, f.ravel(), np.array([0.0, 0.0, 1.0]), k=8).reshape(-1, 3, 3)
    assert np.isclose(S.normal_agreement(P, f, nrm)[0], 1 / np.hypot(0.6, 1.0))
    line = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    assert S.normal_agreement(line, np.array([[0, 1, 2]]), up[None])[0] == 1.0


def _dimple(depth, step=0.01):
    """A 1 cm grid on z = 0 seen from +z, its centre point moved ``depth`` along z, and the four
    triangles of 2-cell half-diagonals around it: with ``depth`` < 0 a pit (a cover over it would be
    a convex hole's, behind the tangent planes), the triangles tilted by atan(depth / 2 cm)."""
    g = np.stack(np.meshgrid(np.arange(-0.1, 0.1001, step), np.arange(-0.1, 0.1001, step)), -1).reshape(-1, 2)
    P = np.column_stack([g, np.zeros(len(g))])
    at = lambda x, y: int(np.argmin(np.linalg.norm(g - [x, y], axis=1)))
    c = at(0.0, 0.0)
    P[c, 2] = depth
    ring = [at(0.02, 0.0), at(0.0, 0.02), at(-0.02, 0.0), at(0.0, -0.02)]
    tilted = np.array([[c, ring[i], ring[(i + 1) % 4]] for i in range(4)])
    flat = np.array([[at(0.05, 0.05), at(0.06, 0.05), at(0.05, 0.06)],
                     [at(0.05, 0.05), at(0.08, 0.05), at(0.05, 0.08)]])   # short and long, on the plane
    return P, tilted, flat


@pytest.mark.parametrize("depth,removed", [(-0.03, True), (-0.005, False)])
def test_tilt_rule_removes_long_triangles_standing_across_the_surface(depth, removed):
    """Long triangles into a pit 3 cm deep stand at 56 degrees to the plane around them (mean
    |cosine| with the vertices' estimated normals 0.3 to 0.6, the pit's point tilting its
    neighbours' normals): behind the tangent planes, the concavity rule keeps them; the tilt rule
    at 0.75 removes them. At 5 mm deep (14 degrees, about 0.94) they stay, as do long and short
    triangles on the plane."""
    P, tilted, flat = _dimple(depth)
    faces = np.concatenate([tilted, flat])
    sec = np.zeros(len(faces), dtype=np.int8)
    vd = np.array([0.0, 0.0, 1.0])
    base = dict(facing_cos=-1.0, carve_margin=0.0, tilt_min_edge=2.5, workers=1)
    sp = S.median_spacing(P)
    off, _ = S.remove_air(P, faces, sec, vd, sp, SurfaceParams(tilt_cos=0.0, **base))
    on, _ = S.remove_air(P, faces, sec, vd, sp, SurfaceParams(tilt_cos=0.75, **base))
    assert len(off) == len(faces)                                   # the concavity rule keeps all
    keys = S.face_keys(np.concatenate([faces, on]))
    gone = ~np.isin(keys[:len(faces)], keys[len(faces):])
    assert (gone[:4] == removed).all()
    assert not gone[4:].any()                                       # the plane's triangles stay


def test_a_far_part_faces_its_camera_not_the_nearest_section():
    """The top of a foot whose lower leg the fit missed (a far part, charted on its own): a flat
    patch at the floor seen by the front camera from 6 degrees above. The nearest fitted section,
    the thigh 40 cm above, has its outward direction downward there, so it must not turn the
    patch's faces: they face up, toward the camera (turned down before)."""
    from bodyscan.recon.surface.complete import part_shape

    x, y = np.meshgrid(np.arange(-0.04, 0.04, 0.005), np.arange(-0.12, 0.0, 0.005))
    P = np.column_stack([x.ravel(), y.ravel(), 0.03 + 0.0002 * np.sin(40 * x.ravel())])
    up = np.radians(6)
    vd = np.tile([0.0, -np.cos(up), np.sin(up)], (len(P), 1))    # toward the camera, in front
    thigh = SectionShape("thigh_l", (0.0, 0.0, 0.85), (0.0, 0.0, 0.45), (0.07, 0.07), (1.0, 0, 0))
    fit = BodyFit(sections={"thigh_l": thigh}, joints={})
    idx = np.arange(len(P))
    job = (SECTIONS.index("thigh_l"), idx, part_shape(P, P[:0], "thigh_l"), {"max_edge_factor": 4.0}, idx)
    with pytest.warns(UserWarning, match="thigh_l: only 0 points"):   # the thigh's own points are not here
        faces, sec, _ = S.reconstruct_surfaces(P, np.zeros((len(P), len(SECTIONS)), bool), fit, SurfaceParams(),
                                               view_dir=vd, spacing=0.005, extra=[job])
    assert len(faces) > 0.8 * 2 * len(P)
    tri = P[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(n, axis=1)
    assert area[n[:, 2] > 0].sum() > 0.99 * area.sum()


def test_faces_the_cameras_disagree_on_take_their_own_charts_column_not_their_sections():
    """The top of a foot (its chart's own column, along the foot) under its lower leg, meshed from
    points the front and the rear camera saw in turn, so that no face's cameras agree: each face is
    turned by the foot's column, outward (up); the lower leg's model, whose end cap points forward
    and down there, turned them down."""
    from scipy.spatial import Delaunay

    foot = SectionShape("lower_leg_l", (0.0, 0.03, 0.04), (0.0, -0.15, 0.04), (0.045, 0.035), (1.0, 0, 0))
    leg = SectionShape("lower_leg_l", (0.0, 0.02, 0.48), (0.0, 0.02, 0.09), (0.05, 0.05), (1.0, 0, 0))
    x, y = np.meshgrid(np.arange(-0.04, 0.0401, 0.005), np.arange(-0.14, 0.02, 0.005))
    x, y = x.ravel(), y.ravel()
    P = np.column_stack([x, y, 0.04 + 0.035 * np.sqrt(1 - (x / 0.045) ** 2)])
    F = Delaunay(P[:, :2]).simplices
    vd = np.where((np.arange(len(P)) % 2 == 0)[:, None], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0])
    j = SECTIONS.index("lower_leg_l")
    fit = BodyFit(sections={"lower_leg_l": leg}, joints={})
    idx = np.arange(len(P))
    sec = np.full(len(F), j)

    def outward(faces):
        tri = P[faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        return np.mean(np.einsum("ij,ij->i", n, S.model_outward(foot, tri.mean(axis=1))) > 0)

    assert outward(S.orient_charts(P, F, sec, fit, [(j, idx, foot, {}, idx)], vd, 0.5)) == 1.0
    assert outward(S.orient_faces(P, F, sec, fit, vd, model_weight=0.5)) < 0.5    # the section's model


def test_a_hands_range_image_does_not_span_a_hole_a_few_centimetres_wide():
    # a part seen by the front camera on a 5 mm grid: two rows of knuckles 2 cm apart in depth, a
    # 3.5 cm band between them the camera did not see (3.5 cm across the view, 4 cm in 3D). A
    # hand is a few centimetres across: its chart keeps triangles up to far_max_edge spacings of
    # the coarsest scan meshed as range images (4 x 7.5 mm), so both rows are meshed and nothing
    # spans the band; a foot keeps max_edge_min's 4 cm (the unseen rims along its length) and
    # spans it
    import dataclasses
    from types import SimpleNamespace

    from bodyscan.recon.surface.complete import extremity_charts

    x, z = np.meshgrid(np.arange(0, 0.08, 0.005), np.arange(0, 0.04, 0.005))
    near = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    far = np.column_stack([x.ravel(), np.full(x.size, 0.02), z.ravel() + 0.07])
    P = np.concatenate([near, far])
    vd = np.tile([0.0, -1.0, 0.0], (len(P), 1))
    column = SectionShape("forearm_l", [0.04, 0.01, -0.02], [0.04, 0.01, 0.14], [0.05, 0.02], [1, 0, 0])
    fit = SimpleNamespace(extremities={"hand_l": column, "foot_l": column})
    meshed = np.zeros((len(P), len(SECTIONS)), dtype=bool)
    for k, spans in ((0, False), (2, True)):                        # hand_l, foot_l
        ext = np.full(len(P), k)
        job = extremity_charts(P, ext, fit, meshed, 0.005, join=3.0, max_edge=4.0)[0]
        f = S._chart_faces(P, job[1], job, dataclasses.replace(SurfaceParams(), **job[3]), 0.005, vd)
        c = P[f].mean(axis=1)
        assert ((c[:, 2] > 0.036) & (c[:, 2] < 0.069)).any() == spans
        assert len(np.unique(f)) == len(P)                          # both rows meshed


def test_per_face_measures_are_the_same_in_chunks(monkeypatch):
    # edge lengths, areas and normals of random triangles, measured a few faces at a time (the
    # chunks' boundaries inside the list) and directly
    rng = np.random.default_rng(3)
    P = rng.normal(size=(40, 3))
    f = rng.integers(0, len(P), size=(23, 3))
    vd = rng.normal(size=(len(P), 3)) * [0.1, 0.1, 1.0]
    vd /= np.linalg.norm(vd, axis=1)[:, None]
    whole = [S.max_edge_length(P, f), S.face_areas(P, f), S.face_normals(P, f),
             S.view_edge_length(P, f, vd, 0.5, 2.0)]
    monkeypatch.setattr(S, "FACE_CHUNK", 5)
    chunked = [S.max_edge_length(P, f), S.face_areas(P, f), S.face_normals(P, f),
               S.view_edge_length(P, f, vd, 0.5, 2.0)]
    for a, b in zip(whole, chunked):
        assert np.array_equal(a, b)
    e = P[f] - P[f][:, [1, 2, 0]]
    assert np.allclose(chunked[0], np.linalg.norm(e, axis=2).max(axis=1))
    n = np.cross(P[f[:, 1]] - P[f[:, 0]], P[f[:, 2]] - P[f[:, 0]])
    assert np.allclose(chunked[2], n)
    assert np.allclose(chunked[1], 0.5 * np.linalg.norm(n, axis=1))
    assert (chunked[3] <= chunked[0] + 1e-12).all() and (chunked[3] >= chunked[0] / 2 - 1e-12).all()
