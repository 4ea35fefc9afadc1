"""Per-section surfaces by 2D Delaunay on the model surface, and their merge (paper section 3.3).

Each section's points are projected onto its model surface: onto the column as ``u = R*theta,
v = h``, onto a closed cap as ``u = R*phi*cos(theta), v = R*phi*sin(theta)`` (``phi`` the polar
angle from the cap's pole); an open end projects onto the extended column. Each chart is
triangulated in 2D with `scipy.spatial.Delaunay` (Qhull) and the triangles are applied to the 3D
points.

Seams, as in the paper: the points within ``seam_overlap`` of theta = 0 are copied past 2*pi (and
back; at most `SEAM_SPACINGS` point spacings), triangulated with the others, and a column
triangle is kept only when its centroid lies in ``0 <= u < 2*pi*R`` (and, at a closed end,
``0 <= v <= length``), so each seam triangle is kept once; triangles around half the column or
more (hull artefacts of the copies) are dropped. The column and cap charts overlap: a cap chart
holds the points beyond the column's end that no column triangle uses, plus the vertices of the
column's boundary loop at that end (the overlap), and keeps the triangles inside that loop, so
the cap closes the column along shared edges; overlapping triangles are not kept.

Where the surface folds back over its chart (curled fingers over the palm, at 10 mm one layer
of points over another in the forearm's chart), Delaunay joins the two layers with triangles in
the air; with ``fold_cos`` set, the long triangles that are flipped against their chart are
removed (`chart_agreement`). Then `peel_boundary` removes long triangles from the section's
boundary inwards (Delaunay's convex-hull slivers), `merge_sections` joins the sections through
their shared points and removes the triangles made only of multi-section points (paper 3.3),
`view_consistency` removes the long triangles that face away from the camera of one of their
vertices (points seen from opposite sides joined across a gap, ``facing_cos``),
`over_concavity` removes the long triangles whose centroid stands in front of the surface's
tangent planes at their vertices (covers over concave holes, ``concave_height``; covers of
holes in convex surface, inside the body, stay as in the paper), `normal_agreement` removes
the long triangles that stand across the surface the points' estimated normals show
(``tilt_cos``: spurious surface the data do not support), `seen_through`
removes the triangles that a camera ray crossed in front of its point (free space,
``carve_margin``), and `orient_faces` turns every triangle outward.

The hands and feet of the body model are charts like the sections' (`recon.surface.complete.
extremity_charts`); the parts no section's chart fits (`recon.surface.complete.far_charts`) are
triangulated as the range images their cameras took (`view_surface`: Delaunay across each
camera's view, the rims between the images closed by their own chart's faces).
"""

from __future__ import annotations

import dataclasses
import warnings
from itertools import chain

import numpy as np

from ..model import ADJACENT, SECTIONS, BodyFit, SectionShape
from ..params import PAPER, SurfaceParams

TWO_PI = 2 * np.pi

#: The surface settings the simple baseline takes from the paper's (`recon.params.PAPER`), whatever
#: ``proposed`` uses: no fold rule, the paper's boundary peel in 3D, faces turned by the view alone.
SIMPLE_SURFACE = ("fold_cos", "hull_edge_factor", "hull_edge_min", "max_edge_min", "cover_max_edge",
                  "orient_model_weight")

#: The seam copies reach at most this many median point spacings past theta = 0 and 2*pi: enough
#: for Delaunay to see the same neighbourhoods on both sides, few copies on dense scans.
SEAM_SPACINGS = 10.0


def median_spacing(points: np.ndarray, sample: int = 20000, seed: int = 0, tree=None,
                   repeats: int = 4) -> float:
    """Median distance (metres) from each of ``points`` (m, 3) to its nearest other point at
    another position (over a seeded sample of ``sample`` points when there are more; ``tree``: a
    `scipy.spatial.cKDTree` of ``points``, if already built). Repeated points (heads whose fields
    overlap measure the same grid position twice) are skipped, up to ``repeats`` copies of a
    point; a point with more copies does not count."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 0.0
    q = points
    if len(points) > sample:
        q = points[np.random.default_rng(seed).choice(len(points), sample, replace=False)]
    k = int(min(repeats + 1, len(points)))
    d, _ = (tree if tree is not None else cKDTree(points)).query(q, k=k)
    d = np.where(d[:, 1:] > 0, d[:, 1:], np.inf).min(axis=1)
    d = d[np.isfinite(d)]
    return float(np.median(d)) if len(d) else 0.0


#: Faces measured at a time by the per-face rules (speed only: a chunk's corner coordinates, about
#: 3 MB, are reused from one chunk to the next instead of a whole surface's fresh arrays).
FACE_CHUNK = 32768


def _chunks(k: int):
    """Slices of at most `FACE_CHUNK` of ``k`` rows."""
    return (slice(a, a + FACE_CHUNK) for a in range(0, k, FACE_CHUNK))


def max_edge_length(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k,) longest 3D edge (metres) of each of ``faces`` (k, 3) over ``points`` (n, 3)."""
    out = np.empty(len(faces))
    for c in _chunks(len(faces)):
        p = points[faces[c]]
        e = p - p[:, [1, 2, 0]]
        out[c] = np.einsum("ijk,ijk->ij", e, e).max(axis=1)
    return np.sqrt(out)


def edge_keys(faces: np.ndarray) -> np.ndarray:
    """(k, 3) int64 key of each face's edges (v1 v2, v2 v3, v3 v1), equal for shared edges."""
    f = np.asarray(faces, dtype=np.int64)
    n = int(f.max()) + 1 if len(f) else 1
    a = np.stack([f[:, 0], f[:, 1], f[:, 2]], axis=1)
    b = np.stack([f[:, 1], f[:, 2], f[:, 0]], axis=1)
    return np.minimum(a, b) * n + np.maximum(a, b)


def face_keys(faces: np.ndarray) -> np.ndarray:
    """(k,) int64 key of each face's vertex set (equal for the same three vertices in any order)."""
    f = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    n = int(f.max()) + 1 if len(f) else 1
    return (f[:, 0] * n + f[:, 1]) * n + f[:, 2]


def view_edge_length(points: np.ndarray, faces: np.ndarray, view_dir=None,
                     same_side: float = 0.9, stretch: float = np.inf) -> np.ndarray:
    """(k,) longest edge (metres) of each of ``faces`` (k, 3) as its vertices' cameras saw it:
    measured across their mean viewing direction when the three were seen along one axis (the
    mean of their unit ``view_dir`` (n, 3) or (3,), each turned to the first vertex's side, at
    least ``same_side`` long), but at least the 3D length over ``stretch``; in 3D otherwise.

    The scanner samples the surface on a grid across its viewing direction, so neighbouring
    samples of one surface patch are a grid step apart across it however steeply the surface
    turns away (the flanks of a limb, the sides of the trunk: long in 3D, short to the camera);
    a hole in what the camera saw is wide across the view. The front and rear heads look along one
    axis from either side: where their samples meet at a flank, both sampled it on the same grid
    across the view, so a triangle joining them is measured across it too. Two surfaces one
    behind the other are also near across the view: ``stretch`` bounds how much steeper than the
    view a triangle may stand. Without ``view_dir``: 3D.
    """
    longest = max_edge_length(points, faces)
    if view_dir is None or len(faces) == 0 or same_side > 1:
        return longest
    vd = np.asarray(view_dir, dtype=np.float64)
    for c in _chunks(len(faces)):
        f = faces[c]
        if vd.ndim == 2:   # up to sign: the heads face each other along one axis
            d = vd[f]
            m = np.einsum("kij,ki->kj", d, np.where(np.einsum("kij,kj->ki", d, d[:, 0]) < 0, -1.0, 1.0)) / 3
        else:
            m = np.broadcast_to(vd, (len(f), 3))
        ln = np.sqrt(np.einsum("ij,ij->i", m, m))
        one = ln >= same_side
        if not one.any():
            continue
        m = m[one] / ln[one, None]
        p = points[f[one]]
        e = p - p[:, [1, 2, 0]]
        e -= np.einsum("kij,kj->ki", e, m)[..., None] * m[:, None, :]
        out = longest[c]  # a view
        out[one] = np.maximum(np.sqrt(np.einsum("ijk,ijk->ij", e, e).max(axis=1)), out[one] / stretch)
    return longest


def peel_boundary(faces: np.ndarray, too_long: np.ndarray) -> np.ndarray:
    """(k,) bool alive mask after repeatedly removing boundary triangles flagged ``too_long``.

    A triangle of ``faces`` (k, 3) is on the boundary when one of its edges belongs to no other
    alive triangle. Delaunay triangulates the convex hull of the projected points; peeling from
    the boundary inwards removes the hull's long slivers at open ends and the long triangles of
    concavities open to the boundary, but keeps those covering interior holes (as the paper does).
    """
    k = len(faces)
    alive = np.ones(k, dtype=bool)
    if k == 0 or not too_long.any():
        return alive
    _, edge = np.unique(edge_keys(faces).ravel(), return_inverse=True)
    edge = edge.reshape(k, 3)
    use = np.bincount(edge.ravel())
    cand = np.flatnonzero(too_long)
    for _ in range(k):
        out = (use[edge[cand]] == 1).any(axis=1)
        if not out.any():
            break
        gone = cand[out]
        alive[gone] = False
        np.subtract.at(use, edge[gone].ravel(), 1)
        cand = cand[~out]
    return alive


def _delaunay(uv):
    """(k, 3) int Delaunay triangles of ``uv`` (m, 2), or None when there are none.

    Always `scipy.spatial.Delaunay` (Qhull), never an optional faster library: a scan's grid
    points are often co-circular, where the Delaunay triangulation is not unique, and the
    benchmark's numbers must not depend on what else is installed. Repeated points are in no
    triangle.
    """
    if len(uv) < 3:
        return None
    from scipy.spatial import Delaunay, QhullError

    try:
        simp = Delaunay(np.ascontiguousarray(uv, dtype=np.float64)).simplices
    except (QhullError, ValueError):  # all points collinear or coincident
        return None
    # Qhull's point at infinity (option Qz, scipy's default) can leak into the triangles of a few
    # degenerate points (seen: 6 points of a cap, index 6): no such triangle is a surface
    simp = simp[(simp < len(uv)).all(axis=1)]
    return simp if len(simp) else None


def column_chart(theta: np.ndarray, h: np.ndarray, radius: float, seam_overlap: float):
    """Column projection with seam copies.

    Parameters
    ----------
    theta, h : (m,) float
        Section coordinates, radians and metres.
    radius : float
        Radius R of the projection column, metres.
    seam_overlap : float
        Points within this angle of theta = 0 (of 2*pi) are also copied past 2*pi (before 0).

    Returns
    -------
    uv : (m', 2) float
        ``u = R*theta``, ``v = h``, originals first, then copies.
    src : (m',) int
        Index into the m inputs of each row.
    """
    lo = np.flatnonzero(theta < seam_overlap)
    hi = np.flatnonzero(theta > TWO_PI - seam_overlap)
    src = np.concatenate([np.arange(len(theta)), lo, hi])
    t = np.concatenate([theta, theta[lo] + TWO_PI, theta[hi] - TWO_PI])
    return np.column_stack([radius * t, h[src]]), src


def cap_chart(local: np.ndarray, shape: SectionShape, end: int):
    """Cap projection ``u = R*phi*cos(theta), v = R*phi*sin(theta)`` around one end.

    Parameters
    ----------
    local : (m, 3) float
        Points in the section frame (`SectionShape.local`).
    shape : SectionShape
    end : {0, 1}
        Start or end cap.

    Returns
    -------
    uv : (m, 2) float
        Chart coordinates, metres (R is the mean radius).
    phi : (m,) float
        Polar angle from the cap's pole, radians (pi/2 on the column's end circle).
    """
    a, b = shape.radii
    c = shape.caps[end]
    x, y = local[:, 0] / a, local[:, 1] / b
    e = (-local[:, 2] if end == 0 else local[:, 2] - shape.length) / c
    phi = np.arctan2(np.hypot(x, y), e)
    theta = np.arctan2(local[:, 1], local[:, 0])
    R = float(shape.radii.mean())
    return np.column_stack([R * phi * np.cos(theta), R * phi * np.sin(theta)]), phi


def chart_agreement(points: np.ndarray, faces: np.ndarray, uv: np.ndarray,
                    direction: np.ndarray) -> np.ndarray:
    """(k,) cosine between each triangle's 3D normal and its chart's projection direction, signed
    by the triangle's orientation in the chart.

    A chart maps the surface onto the model along ``direction`` (the column's radial direction,
    a cap's direction from its centre). Where the surface is a graph over the chart (a limb, the
    head), a triangle that is counter-clockwise in the chart has its 3D normal along that
    direction: the value is near +1. Where the surface folds back over the chart (curled fingers,
    a fold of skin), Delaunay joins points of the two layers: such a triangle stands on edge to
    the chart (value near 0) or is flipped (negative).

    Parameters
    ----------
    points : (m, 3) float
        3D points, metres.
    faces : (k, 3) int
        Triangles over ``points`` (and over ``uv``: the same vertex order).
    uv : (k, 3, 2) float
        Chart coordinates of each triangle's vertices.
    direction : (k, 3) float
        Unit projection direction of the chart at each triangle (outward).
    """
    n = face_normals(points, faces)
    ln = np.sqrt(np.einsum("ij,ij->i", n, n))
    a = uv[:, 1] - uv[:, 0]
    b = uv[:, 2] - uv[:, 0]
    ccw = np.sign(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = ccw * np.einsum("ij,ij->i", n, direction) / ln
    return np.where(ln > 0, cos, 0.0)


def _column_direction(shape: SectionShape, local: np.ndarray) -> np.ndarray:
    """(k, 3) unit outward normal (world frame) of the (elliptic) column at the points ``local``
    (section frame)."""
    a, b = shape.radii
    d = np.column_stack([local[:, 0] / a ** 2, local[:, 1] / b ** 2, np.zeros(len(local))])
    d = d @ shape.frame
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def _cap_direction(shape: SectionShape, local: np.ndarray, end: int) -> np.ndarray:
    """(k, 3) unit outward normal (world frame) of the (ellipsoidal) cap ``end`` at the points
    ``local`` (section frame), in chart orientation: the start cap's chart is seen from inside
    (its u, v turn like x, y while its outside is -h), so its direction is flipped."""
    a, b = shape.radii
    c = shape.caps[end]
    e = -local[:, 2] if end == 0 else local[:, 2] - shape.length
    d = np.column_stack([local[:, 0] / a ** 2, local[:, 1] / b ** 2, e / c ** 2])
    if end == 0:
        d[:, :2] *= -1  # outward is (x, y, -e); the chart turns the other way: -(outward)
    d = d @ shape.frame
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def section_surface(points: np.ndarray, shape: SectionShape,
                    params: SurfaceParams = SurfaceParams(), spacing: float | None = None,
                    view_dir: np.ndarray | None = None) -> np.ndarray:
    """Triangulate one section's points by Delaunay on its model surface.

    Parameters
    ----------
    points : (m, 3) float, metres
        The points clustered into the section.
    shape : SectionShape
    params : SurfaceParams
    spacing : float, optional
        Median point spacing, metres (default: measured on ``points``).
    view_dir : (m, 3) or (3,) float, optional
        Unit directions of ``points`` toward their cameras: the boundary peel measures a
        triangle's length as its camera saw it (`view_edge_length`, ``params.peel_same_side``).

    Returns
    -------
    faces : (k, 3) int
        Triangles over ``points`` (unoriented; see `orient_faces`).
    """
    m = len(points)
    if m < 3:
        return np.zeros((0, 3), dtype=np.int64)
    spacing = max(median_spacing(points) if spacing is None else spacing, 1e-9)
    R = float(shape.radii.mean())
    L = shape.length
    _, theta, h = shape.coords(points)
    local = shape.local(points)
    band = params.cap_overlap * R
    h_lo = 0.0 if shape.closed[0] else -np.inf
    h_hi = L if shape.closed[1] else np.inf

    parts = []
    agree = []  # per part, `chart_agreement` of its triangles
    # column chart
    sel = np.flatnonzero((h >= h_lo - band) & (h <= h_hi + band))
    if len(sel) >= 3:
        overlap = min(params.seam_overlap, SEAM_SPACINGS * spacing / R)
        uv, src = column_chart(theta[sel], h[sel], R, overlap)
        simp = _delaunay(uv)
        if simp is not None:
            faces = sel[src[simp]]
            u, v = uv[:, 0][simp], uv[:, 1][simp]
            cu, cv = u.sum(axis=1) / 3, v.sum(axis=1) / 3
            own = (cu >= 0) & (cu < TWO_PI * R) & (cv >= h_lo) & (cv <= h_hi)
            # a triangle around half the column or more is a hull artefact that would close an
            # open end into a fan (its copies make the seam region look like a closed loop)
            narrow = u.max(axis=1) - u.min(axis=1) < np.pi * R
            keep = own & narrow
            faces = faces[keep]
            parts.append(faces)
            cen = local[faces].mean(axis=1)
            agree.append(chart_agreement(points, faces, uv[simp[keep]], _column_direction(shape, cen)))
    # cap charts: each fills the column's end loop
    col_faces = parts[0] if parts else np.zeros((0, 3), dtype=np.int64)
    used = np.zeros(m, dtype=bool)
    used[col_faces.ravel()] = True
    loops = _end_loops(col_faces, h, L)
    for end in (0, 1):
        if not shape.closed[end]:
            continue
        uv_all, phi = cap_chart(local, shape, end)
        beyond = (h < 0) if end == 0 else (h > L)
        loop = loops[end]
        sel = np.flatnonzero((beyond & ~used & (phi <= np.pi / 2 + params.cap_overlap)))
        sel = np.union1d(sel, loop)
        if len(sel) < 3:
            continue
        simp = _delaunay(uv_all[sel])
        if simp is None:
            continue
        faces = sel[simp]
        cen = uv_all[faces].mean(axis=1)
        if len(loop) >= 3:
            # inside the column's end loop, seen from the pole (the loop is star-shaped about it)
            lt = np.arctan2(uv_all[loop, 1], uv_all[loop, 0])
            lr = np.hypot(uv_all[loop, 0], uv_all[loop, 1])
            o = np.argsort(lt)
            limit = np.interp(np.arctan2(cen[:, 1], cen[:, 0]), lt[o], lr[o], period=TWO_PI)
            own = np.hypot(cen[:, 0], cen[:, 1]) < limit
        else:  # no column to join: the cap keeps what lies beyond the column's end
            hc = h[faces].mean(axis=1)
            own = hc < 0 if end == 0 else hc > L
        faces = faces[own]
        parts.append(faces)
        agree.append(chart_agreement(points, faces, uv_all[faces],
                                     _cap_direction(shape, local[faces].mean(axis=1), end)))
    if parts and params.fold_cos > -1:
        # folds (see `chart_agreement`), after the caps were built on the whole column's end loop
        allf = np.concatenate(parts)
        folded = np.flatnonzero(np.concatenate(agree) < params.fold_cos)   # the long ones of these
        folded = folded[max_edge_length(points, allf[folded]) > params.fold_edge_factor * spacing]
        keep = np.ones(len(allf), dtype=bool)
        keep[folded] = False
        parts = [allf[keep]]
    faces = unique_faces(np.concatenate(parts)) if parts else np.zeros((0, 3), dtype=np.int64)
    return _trim(points, faces, view_dir, params, spacing)


def _trim(points: np.ndarray, faces: np.ndarray, view_dir, params: SurfaceParams, spacing: float) -> np.ndarray:
    """``faces`` (k, 3) of a chart's Delaunay triangulation without its hull's long slivers (the
    boundary peel, ``hull_edge_factor`` / ``hull_edge_min``) and, with ``max_edge_factor`` or
    ``cover_max_edge``, without its long triangles; lengths as the camera saw them
    (`view_edge_length`). Each limit has a floor in metres (``hull_edge_min``, ``max_edge_min``):
    what the cameras left unseen between their samples (the silhouettes, the flanks of a foot
    along the view, the rims of a hand) is as wide on a dense scan as on a coarse one."""
    hull_limit = max(params.hull_edge_factor * spacing, params.hull_edge_min)
    seen_len = view_edge_length(points, faces, view_dir, params.peel_same_side, params.peel_stretch)
    faces, seen_len = faces[peel := peel_boundary(faces, seen_len > hull_limit)], seen_len[peel]
    limit = np.inf if params.max_edge_factor <= 0 else max(params.max_edge_factor * spacing, params.max_edge_min)
    if params.cover_max_edge > 0:
        limit = min(limit, max(params.cover_max_edge, hull_limit))
    if np.isfinite(limit) and len(faces):
        faces = faces[seen_len <= limit]
    return faces


def view_surface(points: np.ndarray, view_dir: np.ndarray, params: SurfaceParams = SurfaceParams(),
                 spacing: float | None = None, shape: SectionShape | None = None) -> np.ndarray:
    """Triangulate points as the range images their cameras took: per camera, by Delaunay across
    its viewing direction.

    A camera measures one point per ray, so what one camera saw of a part is a height field over
    the plane across its view, whatever the part's shape (a hand's fingers, a foot turned out from
    its leg): Delaunay in that plane joins each point to its neighbours in the image, and never
    one layer of the surface to another behind it the same camera saw (a chart around a fitted
    axis folds there). Depth steps and the hull's slivers are removed as on any chart
    (`view_edge_length`, with ``peel_stretch``; the boundary peel and ``max_edge_factor``). The
    cameras are told apart by the sign of the viewing direction along the points' principal
    viewing axis (the scanner's heads face each other).

    Parameters
    ----------
    points : (m, 3) float, metres
    view_dir : (m, 3) or (3,) float
        Unit directions of ``points`` toward their cameras.
    params : SurfaceParams
    spacing : float, optional
        Median point spacing, metres (default: measured on ``points``).
    shape : SectionShape, optional
        A chart around the points (`section_surface`): its faces that join the two cameras' points
        and lie along no inner edge of their images close the rims between the images (the sides
        of a foot, whose length runs along the view; the edge of a hand).

    Returns
    -------
    faces : (k, 3) int
        Triangles over ``points`` (unoriented; see `orient_faces`).
    """
    m = len(points)
    if m < 3:
        return np.zeros((0, 3), dtype=np.int64)
    spacing = max(median_spacing(points) if spacing is None else spacing, 1e-9)
    vd = np.broadcast_to(np.asarray(view_dir, dtype=np.float64), (m, 3))
    _, vec = np.linalg.eigh(vd.T @ vd)
    side = vd @ vec[:, 2] >= 0
    parts = []
    for s in (True, False):
        sel = np.flatnonzero(side == s)
        if len(sel) < 3:
            continue
        d = vd[sel].sum(axis=0)
        d /= max(float(np.linalg.norm(d)), 1e-300)
        e1 = np.cross(d, np.eye(3)[int(np.argmin(np.abs(d)))])
        e1 /= np.linalg.norm(e1)
        simp = _delaunay(points[sel] @ np.column_stack([e1, np.cross(d, e1)]))
        if simp is not None:
            parts.append(sel[simp])
    faces = _trim(points, np.concatenate(parts).astype(np.int64), view_dir, params, spacing) if parts \
        else np.zeros((0, 3), dtype=np.int64)
    if shape is None or side.all() or not side.any():
        return faces
    # the rims: the chart's faces joining two cameras' points, along no inner edge of the images
    rim = section_surface(points, shape, params, spacing, view_dir)
    rim = rim[side[rim].any(axis=1) & ~side[rim].all(axis=1)]
    keys = edge_keys(np.concatenate([faces, rim]))
    u, c = np.unique(keys[:len(faces)], return_counts=True)
    rim = rim[~np.isin(keys[len(faces):], u[c >= 2]).any(axis=1)]
    return np.concatenate([faces, rim])


def _end_loops(faces: np.ndarray, h: np.ndarray, length: float):
    """Vertices of the boundary edges of column ``faces`` near the start and near the end."""
    if len(faces) == 0:
        return [np.zeros(0, dtype=np.int64)] * 2
    n = int(faces.max()) + 1
    key = np.sort(edge_keys(faces).ravel())
    single = np.ones(len(key), dtype=bool)        # keys seen once: boundary edges
    dup = key[1:] == key[:-1]
    single[1:] &= ~dup
    single[:-1] &= ~dup
    b = np.column_stack([key[single] // n, key[single] % n])
    hb = h[b].mean(axis=1)
    return [np.unique(b[hb < length / 2]), np.unique(b[hb >= length / 2])]


def unique_faces(faces: np.ndarray) -> np.ndarray:
    """``faces`` (k, 3) without repeats of the same vertex set (first kept, order preserved)."""
    if len(faces) == 0:
        return faces.reshape(0, 3).astype(np.int64)
    _, first = np.unique(face_keys(faces), return_index=True)
    return faces[np.sort(first)].astype(np.int64)


def face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3) ``(p1 - p0) x (p2 - p0)`` of each of ``faces`` (k, 3) over ``points`` (n, 3): the
    normal by the winding, twice the area long (unnormalised)."""
    out = np.empty((len(faces), 3))
    for c in _chunks(len(faces)):
        p0 = points[faces[c, 0]]
        out[c] = np.cross(points[faces[c, 1]] - p0, points[faces[c, 2]] - p0)
    return out


def face_areas(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k,) area of each face, square metres."""
    c = face_normals(points, faces)
    return 0.5 * np.sqrt(np.einsum("ij,ij->i", c, c))


def model_outward(shape: SectionShape, at: np.ndarray) -> np.ndarray:
    """(k, 3) unit outward direction of the section model at points ``at`` (k, 3)."""
    q = shape.local(at)
    e = np.zeros(len(q))
    if shape.closed[0]:
        e = np.where(q[:, 2] < 0, q[:, 2], e)
    if shape.closed[1]:
        e = np.where(q[:, 2] > shape.length, q[:, 2] - shape.length, e)
    d = np.column_stack([q[:, 0], q[:, 1], e]) @ shape.frame
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def orient_faces(points: np.ndarray, faces: np.ndarray, face_section: np.ndarray, fit: BodyFit,
                 view_dir: np.ndarray | None = None, min_agreement: float = 0.5,
                 model_weight: float = 0.0) -> np.ndarray:
    """Faces (k, 3) with their winding flipped where needed so that normals point outward.

    The outward side is the one the sensor saw: the mean viewing direction of the face's vertices
    (``view_dir`` (n, 3) or (3,), unit, toward the camera) when it is clear (length at least
    ``min_agreement``, i.e. the vertices were seen from about the same side), otherwise the
    model's outward direction at the face's centroid. With ``model_weight`` w > 0, a clear face
    faces the side of the unit viewing direction plus w times the model's outward direction:
    the model decides where the face turns more than 1 / w times as much toward or away from it
    as toward or away from the camera (a face nearly edge-on to its camera, whose small tilt
    toward it is noise; ``SurfaceParams.orient_model_weight``).
    """
    faces = faces.copy()
    if len(faces) == 0:
        return faces
    normal = face_normals(points, faces)
    unclear = np.ones(len(faces), dtype=bool)
    if view_dir is not None:
        vd = np.asarray(view_dir, dtype=float)
        if vd.ndim == 2:  # the sum of the three directions: 3 times their mean
            ref = vd[faces[:, 0]] + vd[faces[:, 1]] + vd[faces[:, 2]]
        else:
            ref = np.repeat(vd[None, :], len(faces), axis=0)
        length = np.sqrt(np.einsum("ij,ij->i", ref, ref))
        unclear = length < (3 if vd.ndim == 2 else 1) * min_agreement
        if model_weight > 0:
            ref /= np.maximum(length, 1e-300)[:, None]
    else:
        ref = np.zeros_like(normal)
    model = unclear
    if model_weight > 0:   # the model can overturn the view only where |cos| to it is under the weight
        area2 = np.einsum("ij,ij->i", normal, normal)
        model = unclear | (np.einsum("ij,ij->i", normal, ref) ** 2 < model_weight ** 2 * area2)
    for j, name in enumerate(SECTIONS):
        sel = np.flatnonzero(model & (face_section == j))
        if len(sel) and name in fit.sections:
            f = faces[sel]
            out = model_outward(fit.sections[name], (points[f[:, 0]] + points[f[:, 1]] + points[f[:, 2]]) / 3)
            ref[sel] = np.where(unclear[sel, None], out, ref[sel] + model_weight * out)
    flip = np.einsum("ij,ij->i", normal, ref) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _child_end(name: str, fit: BodyFit, present) -> list:
    """Ends (0: start, 1: end) of section ``name`` where a present child section continues it
    (an end joint: the joint lies within `recon.clustering.cluster.SIDE_JOINT` mean radii of its axis)."""
    from ..clustering.cluster import SIDE_JOINT

    P = fit.sections[name]
    ends = []
    for (p, d), joint in ADJACENT.items():
        if p != name or d not in present or not fit.seams or joint not in fit.seams:
            continue
        j = np.asarray(fit.seams[joint], dtype=float)
        along = (j - P.start) @ P.axis
        if np.linalg.norm(j - P.start - along * P.axis) <= SIDE_JOINT * float(P.radii.mean()):
            ends.append(1 if along > P.length / 2 else 0)
    return ends


def _has_parent(name: str, fit: BodyFit) -> bool:
    """Whether ``name`` is the distal section of a joint whose proximal section is fitted."""
    return any(d == name and p in fit.sections for p, d in ADJACENT)


def seen_through(points: np.ndarray, faces: np.ndarray, view_dir: np.ndarray, spacing: float,
                 margin: float = 0.5, min_edge: float = 2.0, reach: float = 1.0, min_rays: int = 1,
                 tree=None, workers: int = 1, chunk: int = 200000,
                 longest: np.ndarray | None = None) -> np.ndarray:
    """(k,) bool: faces that the sensor saw through (free-space evidence).

    Every point was measured along a ray from the point toward its camera (``view_dir``), and
    that ray crossed only air: a triangle that it crosses, in front of the point, is not surface
    (the space carving argument). A covered hole that no ray looked through is not affected.

    Parameters
    ----------
    points : (n, 3) float, metres
        All measured points (meshed or not: each one is evidence).
    faces : (k, 3) int
    view_dir : (n, 3) or (3,) float
        Unit direction from each point toward its camera (one for all: a parallel projection).
    spacing : float
        Median point spacing, metres.
    margin : float
        A point counts only when it lies more than ``margin`` spacings behind the triangle's plane
        (noise, and the chords of a concave surface, lie within a fraction of a spacing).
    min_edge : float
        Only triangles with an edge longer than ``min_edge`` spacings are tested (a smaller one
        lies within a spacing of its vertices' surface and cannot hide a point ``margin`` behind it).
    reach : float
        Points farther than the triangle's circumradius plus ``reach`` spacings from its centroid
        are not tested.
    min_rays : int
        A triangle is air when at least this many points' rays cross it (2: a stray point
        behind the surface, an outlier, does not open a hole by itself).
    tree : scipy.spatial.cKDTree, optional
        Of ``points``, if already built.
    workers : int
        Threads of the neighbour query (speed only).
    chunk : int
        Pairs of (triangle, point) tested at a time (memory only).
    longest : (k,) float, optional
        `max_edge_length` of ``faces``, if already computed (speed only).
    """
    from scipy.spatial import cKDTree

    out = np.zeros(len(faces), dtype=bool)
    if len(faces) == 0 or view_dir is None:
        return out
    longest = max_edge_length(points, faces) if longest is None else longest
    cand = np.flatnonzero(longest > min_edge * spacing)
    if len(cand) == 0:
        return out
    v = points[faces[cand]]
    cen = v.mean(axis=1)
    rad = np.sqrt(((v - cen[:, None]) ** 2).sum(axis=2).max(axis=1)) + reach * spacing
    if tree is None:
        tree = cKDTree(points)
    near = tree.query_ball_point(cen, rad, workers=workers)
    cnt = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
    tri = np.repeat(np.arange(len(cand)), cnt)
    pts = np.fromiter(chain.from_iterable(near), dtype=np.int64, count=int(cnt.sum()))
    d = np.broadcast_to(np.asarray(view_dir, dtype=np.float64), points.shape)
    e1 = v[:, 1] - v[:, 0]
    e2 = v[:, 2] - v[:, 0]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    hits = np.zeros(len(cand), dtype=np.int64)
    for a in range(0, len(tri), chunk):  # Moller-Trumbore on the pairs, in chunks
        t_, p_ = tri[a:a + chunk], pts[a:a + chunk]
        tvec = points[p_] - v[t_, 0]
        deep = np.abs(np.einsum("ij,ij->i", tvec, n[t_])) > margin * spacing  # also drops vertices
        t_, p_, tvec = t_[deep], p_[deep], tvec[deep]
        dd = d[p_]
        pvec = np.cross(dd, e2[t_])
        det = np.einsum("ij,ij->i", e1[t_], pvec)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        u = np.einsum("ij,ij->i", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[t_])
        w = np.einsum("ij,ij->i", dd, qvec) * inv
        t = np.einsum("ij,ij->i", e2[t_], qvec) * inv
        h = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
        hits += np.bincount(t_[h], minlength=len(cand))
    out[cand[hits >= min_rays]] = True
    return out


def view_consistency(points: np.ndarray, faces: np.ndarray, view_dir: np.ndarray) -> np.ndarray:
    """(k,) how well each triangle faces the cameras that measured its vertices: the larger, over
    the triangle's two orientations, of the smallest cosine between its unit normal and its
    vertices' viewing directions.

    A point is measured only where the surface faces its camera, so a triangle of real surface,
    which approximates the surface at each of its vertices, faces every one of its vertices'
    cameras, up to the turn of the surface across the triangle (the value is positive, or a little
    below 0 where the triangle turns around a silhouette). A triangle joining a point seen from
    the front to one seen from behind across a gap (thighs, armpit, a forearm beside the hip)
    faces away from one of them whichever way it is turned: the value is well below 0.

    Parameters
    ----------
    points : (n, 3) float, metres
    faces : (k, 3) int
    view_dir : (n, 3) or (3,) float
        Unit direction from each point toward its camera (one for all: every triangle faces it
        one way or the other, the value is >= 0).
    """
    if len(faces) == 0:
        return np.zeros(0)
    n = face_normals(points, faces)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    vd = np.asarray(view_dir, dtype=np.float64)
    d = vd[faces] if vd.ndim == 2 else np.broadcast_to(vd, (len(faces), 3, 3))
    c = np.einsum("ikj,ij->ik", d, n)
    return np.maximum(c.min(axis=1), -c.max(axis=1))


def point_normals(points: np.ndarray, idx: np.ndarray, view_dir: np.ndarray, k: int = 12,
                  tree=None) -> np.ndarray:
    """(m, 3) unit normals of the surface at the points ``idx`` (m,), turned toward their cameras.

    The normal is the direction of least spread of each point's ``k`` nearest points (including
    itself), turned so that it faces the point's viewing direction (a point is measured only where
    the surface faces its camera).

    Parameters
    ----------
    points : (n, 3) float, metres
    idx : (m,) int
    view_dir : (n, 3) or (3,) float
        Unit directions toward the cameras.
    k : int
        Neighbours per point (at least 3).
    tree : scipy.spatial.cKDTree, optional
        Of ``points``, if already built.
    """
    from scipy.spatial import cKDTree

    if len(idx) == 0:
        return np.zeros((0, 3))
    tree = cKDTree(points) if tree is None else tree
    k = int(min(max(k, 3), len(points)))
    _, nb = tree.query(points[idx], k=k)
    q = points[nb]
    q -= q.mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", q, q))
    n = vec[:, :, 0]
    vd = np.asarray(view_dir, dtype=np.float64)
    d = vd[idx] if vd.ndim == 2 else np.broadcast_to(vd, n.shape)
    return n * np.where(np.einsum("ij,ij->i", n, d) < 0, -1.0, 1.0)[:, None]


def over_concavity(points: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k, 3) height (metres) of each triangle's centroid above the surface's tangent plane at
    each of its vertices (``normals`` (k, 3, 3): the unit outward surface normal at each face's
    vertices, e.g. `point_normals`).

    A triangle of the surface lies in the tangent planes at its vertices, up to the surface's
    curvature: behind them on a convex surface (a cover of a hole in convex surface, which the
    paper keeps, lies inside the body), at most a fraction of an edge times the edge's turn in
    front of them on a concave one. A triangle whose centroid stands in front of the tangent planes
    at its vertices (at every one, or clearly on average) bridges a concavity: a cover over a hole
    in concave surface (under the chin, the armpit, between the thighs), or surface spanning a gap
    between two parts.
    """
    if len(faces) == 0:
        return np.zeros((0, 3))
    v = points[faces]
    c = v.mean(axis=1)
    return np.einsum("ikj,ikj->ik", normals, c[:, None, :] - v)


def normal_agreement(points: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k,) mean over each triangle's vertices of ``|cos|`` between the triangle's normal and the
    surface's normal estimated at the vertex (``normals`` (k, 3, 3), unit, e.g. `point_normals`).

    A triangle of the surface lies in the tangent planes at its vertices up to the surface's
    turn across it: near 1 on a patch sampled densely enough. A long triangle that stands across
    the surface (a cover spanning a curved hole, a rim face joining two views around a thin part,
    fingers joined across their gaps) does not, and the data do not support it. Degenerate
    triangles give 1 (nothing to judge).
    """
    if len(faces) == 0:
        return np.zeros(0)
    n = face_normals(points, faces)
    ln = np.sqrt(np.einsum("ij,ij->i", n, n))
    cos = np.abs(np.einsum("ikj,ij->ik", normals, n)).mean(axis=1)
    return np.divide(cos, ln, out=np.ones(len(faces)), where=ln > 0)


def merge_sections(points: np.ndarray, section_faces: dict, member: np.ndarray, drop_inner: bool = True):
    """Join the section surfaces through their shared points.

    Parameters
    ----------
    points : (n, 3) float, metres
    section_faces : dict of int to (k, 3) int
        Per section index, faces over global point indices.
    member : (n, 11) bool
        Final memberships; triangles made only of points in two or more sections lie inside the
        body (paper 3.3) and are removed when ``drop_inner``.
    drop_inner : bool
        False for the simple baseline, where half the points are in several sections and the
        paper's Fig. 11 shows a whole body: there the sections' surfaces are simply united.

    Returns
    -------
    faces : (m, 3) int
    face_section : (m,) int8
        Duplicates across sections, and faces of zero area, removed.
    """
    fs = [f for f in section_faces.values() if len(f)]
    if not fs:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int8)
    faces = np.concatenate(fs).astype(np.int64)
    sec = np.concatenate([np.full(len(f), j, dtype=np.int8) for j, f in section_faces.items() if len(f)])
    multi = member.sum(axis=1) >= 2
    if drop_inner:
        keep = ~multi[faces].all(axis=1)
        faces, sec = faces[keep], sec[keep]
    _, first = np.unique(face_keys(faces), return_index=True)
    first = np.sort(first)
    faces, sec = faces[first], sec[first]
    keep = face_areas(points, faces) > 1e-12
    return faces[keep], sec[keep]


def reconstruct_surfaces(points: np.ndarray, member: np.ndarray, fit: BodyFit,
                         params: SurfaceParams = SurfaceParams(), view_dir: np.ndarray | None = None,
                         drop_inner: bool = True, spacing: float | None = None, extra=(), outliers=None):
    """Per-section surfaces, merged and oriented outward.

    Parameters
    ----------
    points : (n, 3) float, metres
    member : (n, 11) bool
        Section memberships from `recon.clustering.cluster.cluster_points`.
    fit : BodyFit
    params : SurfaceParams
    view_dir : (n, 3) or (3,) float, optional
        Unit directions toward the sensor, for orientation and for ``params.carve_margin``
        (`seen_through`; without them nothing is carved).
    drop_inner : bool
        Remove triangles made only of points in several sections (see `merge_sections`) and,
        with ``params.open_joint_ends``, leave open the ends where a child section continues
        (both keep the inside of the body out of the surface); also apply the fold rule
        (``params.fold_cos``), the view consistency (``params.facing_cos``), the concavity
        covers (``params.concave_height``) and the free-space carving (``params.carve_margin``).
        False (the simple baseline): the paper's surface.
    spacing : float, optional
        Median point spacing of ``points``, metres (default: `median_spacing`).
    extra : list of (int, (k,) int, SectionShape[, dict[, (k',) int]])
        More charts: section index, point indices, chart, changes of ``params`` for it and the
        points two of each of its faces' corners must be (`recon.surface.complete.far_charts`: a far
        part's own points; its faces on the points it joins would overlap its section's chart's,
        edges in three faces); their faces join the section's.
    outliers : (n,) bool, optional
        Points rejected as outliers: in no face. Every other point a chart left out is meshed
        afterwards (`left_out_charts`, with ``drop_inner`` and ``params.far_charts``).

    Returns
    -------
    faces : (m, 3) int
        Triangles over ``points``, outward winding.
    face_section : (m,) int8
    skipped : list of str
        Sections skipped for having fewer than ``params.min_section_points`` points (warned).
    """
    per = {}
    skipped = []
    tree = None   # one KD-tree of the points for the spacing and the rules beyond the paper
    if spacing is None or (drop_inner and view_dir is not None
                           and (params.concave_height > 0 or params.tilt_cos > 0 or params.carve_margin > 0)):
        from scipy.spatial import cKDTree

        tree = cKDTree(points)
    spacing = median_spacing(points, tree=tree) if spacing is None else spacing
    jobs = []
    for j, name in enumerate(SECTIONS):
        if name not in fit.sections:
            continue
        idx = np.flatnonzero(member[:, j])
        if len(idx) < params.min_section_points:
            warnings.warn(f"section {name}: only {len(idx)} points (fewer than "
                          f"min_section_points={params.min_section_points}); skipped", stacklevel=2)
            skipped.append(name)
            continue
        shape = fit.sections[name]
        jobs.append((j, idx, shape))
    present = {SECTIONS[j] for j, _, _ in jobs}
    for k, (j, idx, shape) in enumerate(jobs):
        closed = list(shape.closed)
        if params.open_joints and _has_parent(shape.name, fit):
            closed[0] = False
        if params.open_joint_ends and drop_inner:  # a way of removing the inside (paper 3.3)
            for end in _child_end(shape.name, fit, present):
                closed[end] = False
        jobs[k] = (j, idx, shape.replace(closed=tuple(closed)))
    jobs += list(extra)

    # the simple baseline keeps the paper's surface: no fold rule (as for the inner triangles), the
    # paper's boundary peel, and faces turned by the view alone
    sp = params if drop_inner else dataclasses.replace(params, **{k: PAPER[k] for k in SIMPLE_SURFACE})

    def run(job):
        own = dataclasses.replace(sp, **job[3]) if len(job) > 3 else sp
        return job[0], _chart_faces(points, job[1], job, own, spacing, view_dir if drop_inner else None)

    if params.workers > 1 and len(jobs) > 1:  # numpy (and Qhull) release the GIL: in parallel
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=params.workers) as pool:
            done = list(pool.map(run, jobs))
    else:
        done = [run(job) for job in jobs]
    per = {}
    for j, f in done:
        per[j] = np.concatenate([per[j], f]) if j in per else f
    faces, sec = merge_sections(points, per, member, drop_inner)
    if drop_inner and view_dir is not None:
        faces, sec = remove_air(points, faces, sec, view_dir, spacing, params, tree)
    if drop_inner and params.rejoin_edge > 0:
        more, more_sec = rejoin_left_out(points, faces, jobs, sp, spacing, params.rejoin_edge, view_dir, tree)
        inner = (member.sum(axis=1) >= 2)[more].all(axis=1)     # as in the merge (paper 3.3)
        more, more_sec = more[~inner], more_sec[~inner]
        if view_dir is not None:
            more, more_sec = remove_air(points, more, more_sec, view_dir, spacing, params, tree)
        faces, sec = np.concatenate([faces, more]), np.concatenate([sec, more_sec])
    faces = orient_charts(points, faces, sec, fit, extra, view_dir, sp.orient_model_weight)
    if drop_inner and params.far_charts:
        more, more_sec = left_out_charts(points, faces, sec, fit, sp, spacing, view_dir, tree, outliers)
        faces, sec = np.concatenate([faces, more]), np.concatenate([sec, more_sec])
    return faces, sec, skipped


def left_out_charts(points: np.ndarray, faces: np.ndarray, face_section: np.ndarray, fit: BodyFit,
                    params: SurfaceParams, spacing: float, view_dir=None, tree=None, outliers=None):
    """Faces for the points that every chart left out: parts of their own (`far_charts`).

    A section's chart is one height field around its axis, so it holds one layer: the points of
    a limb the fit listed unfitted, clustered into the trunk beside it, lie at the same angle and
    height as the trunk's own surface, and no rule keeps a triangle between the two layers. A
    point within T_d of a section that the clustering left in none (the toes of a foot placed
    wrongly, beyond its section's end) has no chart at all. The points no face uses, outliers
    apart, are grouped into connected parts and meshed like the points beyond T_d
    (`recon.surface.complete.far_charts`: each part's range images, joined to the surface made so
    far around it, a hand's or a foot's too), under the same air rules, and turned by their own
    charts (`orient_charts`: the fitted section nearest them is not their surface). A part apart
    from that surface is meshed too (a piece of a limb the fit listed unfitted); with no surface
    at all (a fit off the cloud) nothing is.

    Parameters
    ----------
    points : (n, 3) float, metres
    faces : (k, 3) int
        The surface so far.
    face_section : (k,) int
        Its faces' sections.
    fit : BodyFit
    params : SurfaceParams
    spacing : float
    view_dir : (n, 3) or (3,) float, optional
    tree : scipy.spatial.cKDTree, optional
        Of ``points``.
    outliers : (n,) bool, optional
        Points left out of the surface (default: none).

    Returns
    -------
    faces : (k', 3) int
    face_section : (k',) int8
    """
    from .complete import far_charts

    around = np.zeros((len(points), len(SECTIONS)), dtype=bool)   # the surface so far, by section
    around[np.asarray(faces, dtype=np.int64).ravel(), np.repeat(np.asarray(face_section, dtype=np.int64), 3)] = True
    left = ~around.any(axis=1)
    if outliers is not None:
        left &= ~np.asarray(outliers, dtype=bool)
    none = (np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int8))
    if left.sum() < params.far_min_points or not len(faces):   # no surface to complete: a fit off the cloud
        return none
    jobs = far_charts(points, left, fit.sections, around, spacing, params.far_link,
                      params.far_join, params.far_min_points, params.far_max_edge, tree, alone=True)
    if not jobs:
        return none
    more = [_chart_faces(points, job[1], job, dataclasses.replace(params, **job[3]), spacing, view_dir)
            for job in jobs]
    sec = np.concatenate([np.full(len(f), job[0], dtype=np.int8) for f, job in zip(more, jobs)])
    more = np.concatenate(more)
    if view_dir is not None:
        more, sec = remove_air(points, more, sec, view_dir, spacing, params, tree)
    return orient_charts(points, more, sec, fit, jobs, view_dir, params.orient_model_weight), sec


def orient_charts(points: np.ndarray, faces: np.ndarray, face_section: np.ndarray, fit: BodyFit, extra,
                  view_dir=None, model_weight: float = 0.0) -> np.ndarray:
    """`orient_faces`, each face by the model of the chart it was made on.

    A hand's, a foot's or a far part's chart carries its section's label, but that section's model
    is not its surface (a foot points forward from its lower leg's axis; the foot of a lower leg
    listed unfitted lies under its thigh's cap, whose outward direction points down there). Their
    faces (two corners among a chart's own points) face their cameras alone, and where the cameras
    disagree (a chord between the front and the rear view) the outward direction of the chart's
    own column; the other faces are turned with their fitted section (``model_weight``).

    Parameters
    ----------
    points : (n, 3) float, metres
    faces : (k, 3) int
    face_section : (k,) int
    fit : BodyFit
    extra : list of (int, (m,) int, SectionShape[, dict[, (m',) int]])
        The charts beyond the fitted sections (`reconstruct_surfaces`).
    view_dir : (n, 3) or (3,) float, optional
    model_weight : float

    Returns
    -------
    (k, 3) int
        ``faces``, some of them flipped.
    """
    owner = np.full(len(points), -1)
    for k, job in enumerate(extra):
        owner[job[4] if len(job) > 4 else job[1]] = k
    o = owner[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
    chart = np.where((o[:, 0] == o[:, 1]) | (o[:, 0] == o[:, 2]), o[:, 0], np.where(o[:, 1] == o[:, 2], o[:, 1], -1))
    out = faces.copy()
    on = chart < 0
    out[on] = orient_faces(points, faces[on], face_section[on], fit, view_dir, model_weight=model_weight)
    for k in np.unique(chart[~on]):
        j, shape = extra[k][0], extra[k][2]
        sel = chart == k
        out[sel] = orient_faces(points, faces[sel], face_section[sel],
                                BodyFit(sections={SECTIONS[j]: shape}, joints={}), view_dir)
    return out


def _chart_faces(points: np.ndarray, idx: np.ndarray, job, params: SurfaceParams, spacing: float,
                 view_dir=None) -> np.ndarray:
    """(k, 3) faces, global indices, of chart ``job`` (`reconstruct_surfaces`' jobs) triangulated
    over the points ``idx``; a far part's chart keeps only faces with an edge between its own
    points (the rest are other charts')."""
    vd = None if view_dir is None else (view_dir[idx] if np.ndim(view_dir) == 2 else view_dir)
    if len(job) > 4 and params.far_view and vd is not None:   # a far part: its range images
        f = idx[view_surface(points[idx], vd, params, spacing, job[2])]
    else:
        f = idx[section_surface(points[idx], job[2], params, spacing, vd)]
    if len(job) > 4:
        f = f[np.isin(f, job[4]).sum(axis=1) >= 2]
    return f


def rejoin_left_out(points: np.ndarray, faces: np.ndarray, jobs, params: SurfaceParams, spacing: float,
                    edge: float, view_dir=None, tree=None):
    """Short triangles that put back the points the rules left out of every face.

    The boundary peel and the air rules remove long triangles, and with them the points that had
    no short one: strips of seen surface beside a hole, a flank's last row. Each chart is
    triangulated again on its left-out points and the chart's points within ``edge`` spacings of
    them, and the triangles with a left-out corner and no edge longer than ``edge`` spacings in
    3D are kept: so short, they lie on the surface between neighbouring samples of one section
    (air is wider than that; the caller passes them through the air rules too).

    Parameters
    ----------
    points : (n, 3) float, metres
    faces : (k, 3) int
        The surface so far.
    jobs : list of (int, (m,) int, SectionShape[, dict[, (m',) int]])
        The charts (`reconstruct_surfaces`).
    params : SurfaceParams
    spacing : float
        Median point spacing, metres.
    edge : float
        Spacings: the longest edge of a rejoining triangle.
    view_dir : (n, 3) or (3,) float, optional
    tree : scipy.spatial.cKDTree, optional
        Of ``points``.

    Returns
    -------
    faces : (k', 3) int
        New triangles (none of ``faces``' vertex sets).
    face_section : (k',) int8
    """
    from scipy.spatial import cKDTree

    from .complete import _joined

    used = np.zeros(len(points), dtype=bool)
    used[np.asarray(faces, dtype=np.int64).ravel()] = True
    tree = cKDTree(points) if tree is None else tree
    out, out_sec = [], []
    r = edge * spacing
    for job in jobs:
        j, idx = job[:2]
        left = idx[~used[idx]]
        if len(left) == 0:
            continue
        sub = np.union1d(left, np.intersect1d(_joined(tree, points, left, r), idx))
        if len(sub) < 3:
            continue
        own = dataclasses.replace(params, **(job[3] if len(job) > 3 else {}))
        own = dataclasses.replace(own, max_edge_factor=edge, hull_edge_factor=edge, hull_edge_min=0.0,
                                  max_edge_min=0.0)
        f = _chart_faces(points, sub, job, own, spacing, view_dir)
        f = f[(~used[f]).any(axis=1)]
        out.append(f)
        out_sec.append(np.full(len(f), j, dtype=np.int8))
    if not out:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int8)
    # each has a corner in no face of ``faces``: none of their vertex sets
    f, s = np.concatenate(out).astype(np.int64), np.concatenate(out_sec)
    first = np.sort(np.unique(face_keys(f), return_index=True)[1]) if len(f) else np.zeros(0, dtype=np.int64)
    f, s = f[first], s[first]
    keep = face_areas(points, f) > 1e-12
    return f[keep], s[keep]


def remove_air(points: np.ndarray, faces: np.ndarray, face_section: np.ndarray, view_dir: np.ndarray,
               spacing: float, params: SurfaceParams, tree=None):
    """The rules of ``proposed`` beyond the paper that remove surface in the air, in order: view
    consistency (``params.facing_cos``, `view_consistency`), covers of concavities
    (``params.concave_height``, `over_concavity`) and tilted triangles (``params.tilt_cos``,
    `normal_agreement`), which share the points' estimated normals (`point_normals`), and
    free-space carving (``params.carve_margin``, `seen_through`); each is tested only on
    triangles longer than its minimum edge.

    Parameters
    ----------
    points : (n, 3) float, metres
    faces : (k, 3) int
    face_section : (k,) int
    view_dir : (n, 3) or (3,) float
        Unit directions toward the cameras.
    spacing : float
        Median point spacing, metres.
    params : SurfaceParams
    tree : scipy.spatial.cKDTree, optional
        Of ``points``, if already built.

    Returns
    -------
    faces : (k', 3) int
    face_section : (k',) int
    """
    longest = max_edge_length(points, faces)
    if params.facing_cos > -1:
        keep = np.ones(len(faces), dtype=bool)
        long_ = np.flatnonzero(longest > params.facing_min_edge * spacing)
        keep[long_] = view_consistency(points, faces[long_], view_dir) >= params.facing_cos
        faces, face_section, longest = faces[keep], face_section[keep], longest[keep]
    concave, tilt = params.concave_height > 0, params.tilt_cos > 0
    if concave or tilt:
        if tree is None:
            from scipy.spatial import cKDTree

            tree = cKDTree(points)
        min_edge = min(params.concave_min_edge if concave else np.inf, params.tilt_min_edge if tilt else np.inf)
        long_ = np.flatnonzero(longest > min_edge * spacing)
        ids, inv = np.unique(faces[long_].ravel(), return_inverse=True)
        nrm = point_normals(points, ids, view_dir, params.concave_neighbours, tree)[inv].reshape(-1, 3, 3)
        ok = np.ones(len(long_), dtype=bool)
        if concave:
            lift = over_concavity(points, faces[long_], nrm)
            ok &= ~(longest[long_] > params.concave_min_edge * spacing) | (
                (lift.min(axis=1) <= params.concave_height * spacing)
                & (lift.mean(axis=1) <= params.concave_mean_height * spacing))
        if tilt:
            ok &= ~(longest[long_] > params.tilt_min_edge * spacing) | (
                normal_agreement(points, faces[long_], nrm) >= params.tilt_cos)
        keep = np.ones(len(faces), dtype=bool)
        keep[long_] = ok
        faces, face_section, longest = faces[keep], face_section[keep], longest[keep]
    if params.carve_margin > 0:
        keep = ~seen_through(points, faces, view_dir, spacing, params.carve_margin,
                             params.carve_min_edge, params.carve_reach, params.carve_min_rays,
                             tree=tree, workers=params.workers, longest=longest)
        faces, face_section = faces[keep], face_section[keep]
    return faces, face_section
