"""The closed surface beyond the paper (the method ``proposed-closed``).

`closed_surface`: each section's and far part's points (`recon.surface.complete.far_charts`), in
its chart's cylindrical coordinates, give a radial height field r(theta, h) whose holes (what the
scanner did not see) are filled by a discrete Laplace equation within the model's envelope
(`radial_field`); each field bounds a solid, the solids are united (a maximum of their signed
values on a grid) and the union's surface, its cavities filled, is extracted by marching cubes:
one closed, consistently wound 2-manifold. Sections join where their solids overlap at the
seams; no solid holds another section's points, so no surface spans the air between two sections.

The solids only close what the scanner did not see: near the open mesh (`proposed`'s surface, the
same data), the grid takes the signed distance to it (`seen_distance`), so the seen surface comes
out as the open mesh has it (blended into the solids past its rims); and whatever lies in front of
a surface a camera saw, along its line of sight (`recon.views.Views.air`), or beside the
silhouettes of every camera (`recon.views.Views.beside`), is air.
"""

from __future__ import annotations

import numpy as np

from ..views import Views


def grid_surface(values: np.ndarray, origin: np.ndarray, step: float, labels=None):
    """The surface ``values = 0`` of a grid, closed and wound outward: Lewiner's marching cubes
    (scikit-image), whose resolution of the ambiguous cubes makes the surface a 2-manifold.

    Parameters
    ----------
    values : (nx, ny, nz) float
        Positive inside; the grid's border must be outside (negative).
    origin : (3,) float
        Position of ``values[0, 0, 0]``, metres.
    step : float
        Grid spacing, metres.
    labels : (nx, ny, nz) int, optional
        A label per grid point; each face takes the label of the most inside corner of its cube.

    Returns
    -------
    vertices : (v, 3) float
    faces : (f, 3) int
        Outward winding (normals toward decreasing ``values``).
    face_label : (f,) int
        Per face (zeros without ``labels``).
    """
    from skimage.measure import marching_cubes

    # no grid value exactly at the level: every vertex then lies inside one grid edge, so the
    # cubes sharing that edge share the vertex (a level value would put several on one corner)
    # only the box of the inside grid points and one more layer holds cubes that cross the level
    inside = values >= 0
    box = []
    for ax in range(3):
        hit = np.flatnonzero(inside.any(axis=tuple(a for a in range(3) if a != ax)))
        box.append(slice(max(int(hit[0]) - 1, 0), min(int(hit[-1]) + 2, values.shape[ax])) if len(hit)
                   else slice(0, values.shape[ax]))
    box = tuple(box)
    start = np.array([b.start for b in box])
    # scikit-image marches a float32 copy
    v = values[box].astype(np.float32)
    v[values[box] == 0] = np.float32(1e-12)
    vertices, faces, _, _ = marching_cubes(v, 0.0, method="lewiner")
    faces = np.ascontiguousarray(faces[:, ::-1], dtype=np.int64)     # outward (positive inside)
    if labels is None:
        face_label = np.zeros(len(faces), dtype=np.int64)
    else:
        mean = (vertices.take(faces[:, 0], axis=0) + vertices.take(faces[:, 1], axis=0)
                + vertices.take(faces[:, 2], axis=0)) / np.float32(3)      # the faces' centres, as np.mean
        cube = np.minimum(np.floor(mean).astype(np.int64), np.array(v.shape) - 2) + start
        strides = np.array([values.shape[1] * values.shape[2], values.shape[2], 1])
        corner = np.array([[k & 1, k >> 1 & 1, k >> 2 & 1] for k in range(8)]) @ strides
        flat = (cube @ strides)[:, None] + corner[None]      # (f, 8) flat indices of the cube's corners
        at = np.ravel(values).take(flat)
        inner = flat[np.arange(len(flat)), np.argmax(np.where(at == 0, 1e-12, at), axis=1)]
        face_label = np.ravel(labels)[inner]
    return origin + step * (vertices + start), faces, face_label


#: A row's gap in the seen surface is a hole to fill when it spans at most this fraction of the turn.
GAP_TURN = 0.5


def radial_field(local: np.ndarray, cell: float, model_radius=None, envelope: float = np.inf,
                 thin=(-np.inf, np.inf)):
    """A section's surface as a radial height field ``rho = R(theta, h)`` on a grid, its holes filled.

    The points' distances from the axis are averaged per (theta, h) cell. Cells the points leave
    empty are filled where they are holes of the seen surface: between seen cells of the same
    theta column (the column's h extent), or in a row's gap narrower than half the turn. The fill
    interpolates the seen radii harmonically (the smoothest surface through the hole's rim: a
    discrete Laplace equation over the holes, periodic in theta), held within ``envelope`` of the
    model's radius.

    Parameters
    ----------
    local : (m, 3) float
        The section's points in its frame (x, y across, h along the axis), metres.
    cell : float
        Cell size along h and around the mean radius, metres.
    model_radius : callable, optional
        ``theta -> radius`` of the model (a hole with no seen rim takes it); default: the points'
        mean distance from the axis.
    envelope : float
        Largest fill beyond the model radius, metres.
    thin : (2,) float
        Rows outside this range of h (metres) fill no cell beyond the smallest seen radius of the
        row: parts of unknown shape (a far part, a hand) have their unseen side taken as thin as
        their thinnest seen side.

    Returns
    -------
    R : (n_theta, n_h) float
        Radius per cell (NaN outside the surface).
    h0 : float
        h of the first row's centre; rows are ``cell`` apart along h, columns ``2*pi/n_theta``.
    """
    from scipy.sparse import coo_matrix, identity
    from scipy.sparse.linalg import spsolve

    rho = np.hypot(local[:, 0], local[:, 1])
    theta = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi)
    h = local[:, 2]
    n_t = int(max(8, np.ceil(2 * np.pi * max(float(np.median(rho)), cell) / cell)))
    h0 = float(h.min())
    n_h = int(np.floor((float(h.max()) - h0) / cell)) + 1
    ti = np.minimum((theta / (2 * np.pi) * n_t).astype(np.int64), n_t - 1)
    hi = np.minimum(((h - h0) / cell).astype(np.int64), n_h - 1)
    flat = ti * n_h + hi
    cnt = np.bincount(flat, minlength=n_t * n_h).reshape(n_t, n_h)
    tot = np.bincount(flat, weights=rho, minlength=n_t * n_h).reshape(n_t, n_h)
    seen = cnt > 0
    R = np.where(seen, tot / np.maximum(cnt, 1), np.nan)
    rows = np.arange(n_h)
    first = np.where(seen.any(axis=1), np.argmax(seen, axis=1), n_h)
    last = np.where(seen.any(axis=1), n_h - 1 - np.argmax(seen[:, ::-1], axis=1), -1)
    fill = (rows[None, :] >= first[:, None]) & (rows[None, :] <= last[:, None])
    # a row's gaps narrower than half the turn: distance to the nearest seen cell on each side
    idx = np.arange(3 * n_t)[:, None]
    tiled = np.tile(seen, (3, 1))
    left = np.maximum.accumulate(np.where(tiled, idx, -10 ** 9), axis=0)[n_t:2 * n_t]
    right = np.minimum.accumulate(np.where(tiled, idx, 10 ** 9)[::-1], axis=0)[::-1][n_t:2 * n_t]
    fill |= (right - left) <= n_t * GAP_TURN
    fill &= ~seen
    valid = seen | fill
    if fill.any():
        if model_radius is None:
            model = np.full(n_t, float(np.nanmean(R)))
        else:
            model = np.asarray(model_radius((np.arange(n_t) + 0.5) * 2 * np.pi / n_t), dtype=float)
        # the Laplace equation over the valid cells (theta periodic), seen cells fixed
        id_ = np.full((n_t, n_h), -1)
        unk = np.flatnonzero(fill.ravel())
        id_.ravel()[unk] = np.arange(len(unk))
        t_u, h_u = np.divmod(unk, n_h)
        rows_, cols_, rhs = [], [], np.zeros(len(unk))
        deg = np.zeros(len(unk))
        for dt, dh in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            tn, hn = (t_u + dt) % n_t, h_u + dh
            ok = (hn >= 0) & (hn < n_h)
            tn, hn, k = tn[ok], hn[ok], np.flatnonzero(ok)
            vn = valid[tn, hn]
            tn, hn, k = tn[vn], hn[vn], k[vn]
            deg[k] += 1
            other = id_[tn, hn]
            free = other >= 0
            rows_.append(k[free])
            cols_.append(other[free])
            np.add.at(rhs, k[~free], R[tn[~free], hn[~free]])
        eps = 1e-3
        A = coo_matrix((-np.ones(sum(len(r) for r in rows_)), (np.concatenate(rows_), np.concatenate(cols_))),
                       shape=(len(unk), len(unk))).tocsr()
        A = A + coo_matrix((deg + eps, (np.arange(len(unk)), np.arange(len(unk))))).tocsr()
        x = spsolve(A.tocsc(), rhs + eps * model[t_u])
        hc = h0 + (h_u + 0.5) * cell
        lean = (hc < thin[0]) | (hc > thin[1])
        if lean.any():   # no more than the row's thinnest seen radius (a flat hand seen on its back)
            low = np.min(np.where(seen, R, np.inf), axis=0)[h_u]
            x = np.where(lean & np.isfinite(low), np.minimum(x, low), x)
        R[t_u, h_u] = np.minimum(x, model[t_u] + envelope)
    return R, h0


def field_tables(R: np.ndarray, cell: float):
    """Two (n_t, n_h) float tables: per cell of the radial field ``R`` (n_t, n_h), the signed distance
    (metres along the grid, positive within) to the edge of its valid cells and the nearest valid
    radius (`field_value`'s tables, computed once per field)."""
    from scipy.ndimage import distance_transform_edt

    n_t, n_h = R.shape
    valid = np.isfinite(R)
    pad = np.zeros((3 * n_t, n_h + 2), dtype=bool)
    pad[:, 1:-1] = np.tile(valid, (3, 1))
    inner = distance_transform_edt(pad)
    outer, (it, ih) = distance_transform_edt(~pad, return_indices=True)
    S = np.where(pad, inner - 0.5, 0.5 - outer)[n_t:2 * n_t, 1:-1] * cell
    Rn = np.tile(np.where(valid, R, 0.0), (3, 1))
    Rn = np.pad(Rn, ((0, 0), (1, 1)))[it, ih][n_t:2 * n_t, 1:-1]   # nearest valid radius outside
    return S, Rn


def field_value(R: np.ndarray, h0: float, cell: float, local: np.ndarray, h1=None, tables=None) -> np.ndarray:
    """(k,) signed value, positive inside, of the solid ``rho <= R(theta, h)`` at the points
    ``local`` (k, 3) of its frame: ``R - rho`` bilinear in the grid, bounded by the signed distance
    (metres along the grid) to the edge of the surface's cells, so that the solid ends half a cell
    past its last cells (and not past ``h1``, the last point's h, when given). ``tables``:
    `field_tables` of ``R`` (computed here without it)."""
    n_t, n_h = R.shape
    S, Rn = field_tables(R, cell) if tables is None else tables
    rho = np.hypot(local[:, 0], local[:, 1])
    tf = np.arctan2(local[:, 1], local[:, 0])
    tf += (tf < 0) * (2 * np.pi)       # np.mod(., 2 pi) of the angle in [-pi, pi]
    tf = tf / (2 * np.pi) * n_t - 0.5
    hf = np.clip((local[:, 2] - h0) / cell - 0.5, -1.0, n_h)
    t0 = np.floor(tf).astype(np.int64)
    a = tf - t0
    hc = np.clip(hf, 0, n_h - 1)
    r0 = np.minimum(np.floor(hc).astype(np.int64), max(n_h - 2, 0))
    b = np.clip(hc - r0, 0, 1)
    r1 = np.minimum(r0 + 1, n_h - 1)
    ta, tb = t0 % n_t, (t0 + 1) % n_t

    def bil(G):
        return ((1 - a) * ((1 - b) * G[ta, r0] + b * G[ta, r1]) + a * ((1 - b) * G[tb, r0] + b * G[tb, r1]))

    s = bil(S) - np.maximum(-hf, 0) * cell - np.maximum(hf - (n_h - 1), 0) * cell
    if h1 is not None:   # not past the last point's h
        s = np.minimum(s, h1 - local[:, 2])
    return np.minimum(bil(Rn) - rho, s)


#: Grid points per call of `field_value` in `_solid_on_grid`, and of the cameras' cut in `closed_surface`.
FIELD_CHUNK = 16384


def _solid_on_grid(R, h0, h1, cell, shape, lo, voxel, i0, i1):
    """`field_value` of one solid on the grid box ``i0:i1`` (origin ``lo``, step ``voxel``):
    computed on every second grid point, then on every grid point only near the solid's surface
    (within 4 steps; elsewhere only its sign matters, and the coarse value has it). Grid points
    farther from the axis than their rows' largest radius plus 4 steps (coarse) or one step (fine)
    are -inf: their value is at most -4 steps (-1 step), below the grid's initial -``voxel``."""
    from scipy.ndimage import binary_dilation

    D = tuple(int(d) for d in i1 - i0)
    tables = field_tables(R, cell)
    n_h = R.shape[1]
    # per row of cells, a bound of the bilinear radius (field_value's rows r0, r1 of a point)
    top = np.max(tables[1], axis=0) * (1 + 1e-9) + 1e-12

    def value(g, margin):
        local = shape.local(lo + voxel * g)
        hc = np.clip((local[:, 2] - h0) / cell - 0.5, 0, n_h - 1)
        r0 = np.minimum(np.floor(hc).astype(np.int64), max(n_h - 2, 0))
        m = np.maximum(top[r0], top[np.minimum(r0 + 1, n_h - 1)]) + margin
        ask = np.flatnonzero(local[:, 0] ** 2 + local[:, 1] ** 2 <= m * m * (1 + 1e-9))
        out = np.full(len(g), -np.inf)
        for s in range(0, len(ask), FIELD_CHUNK):   # in chunks: field_value's temporaries stay in cache
            part = ask[s:s + FIELD_CHUNK]
            out[part] = field_value(R, h0, cell, local.take(part, axis=0), h1, tables)
        return out

    gc = np.indices(tuple((d + 1) // 2 for d in D)).reshape(3, -1).T * 2 + i0
    vc = value(gc, 4 * voxel).reshape(tuple((d + 1) // 2 for d in D))
    near = binary_dilation(np.abs(vc) < 4 * voxel)
    up = (lambda a: a.repeat(2, 0).repeat(2, 1).repeat(2, 2)[:D[0], :D[1], :D[2]])
    out = np.ascontiguousarray(up(vc))
    todo = up(near)
    todo[::2, ::2, ::2] = False      # the coarse points themselves have their value
    fine = np.flatnonzero(todo)
    g = np.column_stack(np.unravel_index(fine, D)) + i0
    out.ravel()[fine] = value(g, voxel)
    return out


def seen_index(vertices: np.ndarray, faces: np.ndarray):
    """The open mesh's vertices in faces, their unit normals and a KD-tree of them, for
    `seen_distance` (built once for several queries of the same mesh).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
        The open mesh, wound outward.

    Returns
    -------
    used : (u,) int
        The vertices in a face (indices into ``vertices``).
    vpn : (u, 6) float
        Their positions and unit normals (area-weighted mean of their faces' normals).
    tree : scipy.spatial.cKDTree
        Of their positions.
    """
    from scipy.spatial import cKDTree

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = vertices.take(faces, axis=0)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])     # area-weighted
    # the faces' normals summed per vertex, corner by corner in the faces' order (np.add.at's sums)
    corner = faces.T.ravel()
    vn = np.column_stack([np.bincount(corner, np.tile(fn[:, j], 3), len(vertices)) for j in range(3)])
    used = np.flatnonzero(np.bincount(corner, minlength=len(vertices)))     # np.unique(faces)
    vn = vn[used] / np.maximum(np.linalg.norm(vn[used], axis=1, keepdims=True), 1e-30)
    vp = vertices[used]
    return used, np.column_stack([vp, vn]), cKDTree(vp)


def seen_distance(vertices: np.ndarray, faces: np.ndarray, at: np.ndarray, spacing: float, k: int = 8,
                  reach: float = np.inf, exact: float = np.inf, beside_max: float = np.inf, index=None,
                  nearest=None, workers: int = 1):
    """Signed distance to the seen surface (the open mesh), and how far ``at`` lies beside it.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
        The open mesh, wound outward.
    at : (m, 3) float
        Query positions, metres.
    spacing : float
        Median point spacing, metres: the width of the Gaussian weights.
    k : int
        Nearest mesh vertices averaged.
    reach : float
        Queries farther than this (metres) from every vertex are left out (NaN, inf, 0).
    exact : float
        Metres: queries farther than this from the nearest vertex's tangent plane take their
        offset along its normal alone (one nearest-vertex query; the ``k`` nearest are averaged
        only near the zero level).
    beside_max : float
        Metres: queries farther than this beside the nearest vertex's normal take their offset
        along it alone too.

    Returns
    -------
    dist : (m,) float
        Positive inside: the Gaussian-weighted mean of the query's offsets along the ``k`` nearest
        vertices' normals (a smooth signed distance through the vertices' tangent planes).
    beside : (m,) float
        The query's offset across the nearest vertex's normal, metres: small over the seen
        surface, growing past the rim of a hole.
    vertex : (m,) int
        The nearest vertex (index into ``vertices``).
    index : tuple, optional
        `seen_index` of the mesh (built here without it).
    nearest : ((m,) float, (m,) int), optional
        The nearest vertex's distance (inf beyond ``reach``) and index into ``index``'s vertices,
        as ``index``'s tree answers a query bounded by ``reach`` (queried here without it).
    workers : int
        Threads of the KD-tree's queries (the same answers with any number).
    """
    used, vpn, tree = seen_index(vertices, faces) if index is None else index
    k = min(k, len(used))
    dist, beside, vertex = np.full(len(at), np.nan), np.full(len(at), np.inf), np.zeros(len(at), dtype=np.int64)
    d0, i0 = tree.query(at, 1, distance_upper_bound=reach, workers=workers) if nearest is None else nearest
    near = np.flatnonzero(np.isfinite(d0))
    d0, i0 = d0[near], i0[near]
    pn0 = vpn.take(i0, axis=0)     # (take: a faster gather of rows than indexing)
    along0 = np.einsum("mj,mj->m", at.take(near, axis=0) - pn0[:, :3], pn0[:, 3:])
    dist[near] = -along0
    beside[near] = np.sqrt(np.maximum(d0 ** 2 - along0 ** 2, 0))
    vertex[near] = used[i0]
    fine = near[(np.abs(along0) < exact) & (beside[near] < beside_max)]   # the weighted mean near the zero level only
    for s in range(0, len(fine) if k > 1 else 0, CHUNK):   # in chunks: the (m, k, 6) gathers stay in cache
        f = fine[s:s + CHUNK]
        a = at.take(f, axis=0)
        d, i = tree.query(a, k, workers=workers)
        pn = vpn.take(i, axis=0)     # (m, k, 6): one gather of the positions and normals
        along = np.einsum("mkj,mkj->mk", a[:, None, :] - pn[..., :3], pn[..., 3:])
        w = np.exp(-(d / spacing) ** 2) + 1e-300
        dist[f] = -(w * along).sum(axis=1) / w.sum(axis=1)
    return dist, beside, vertex


#: Query positions per chunk of `seen_distance`'s weighted mean.
CHUNK = 4096


#: Spacings beside the open mesh (past a hole's rim): up to BAND_BESIDE the seen surface's band
#: takes the signed distance to it, from there to BAND_BLEND a blend of it and the solids' value
#: (so that the fill meets the rim without a step).
BAND_BESIDE, BAND_BLEND = 1.0, 2.0
#: Grid steps from the nearest vertex's tangent plane within which the signed distance to the open
#: mesh is the smooth weighted mean (`seen_distance`'s ``exact``); farther, the offset along that
#: vertex's normal, as good where marching the grid needs little more than its sign.
EXACT = 1.0
#: Spacings: the silhouettes' gaps between neighbouring points closed up to twice this wide
#: (`recon.views.Views.beside`'s ``close``).
CLOSE = 1.0
#: Sqrt(3) grid steps (a coarse grid point's farthest fine neighbour): the margin of `_seen_band`'s
#: coarse pass over the band's limits.
SLACK = 1.0
#: Grid steps: the seen surface's band reaches at least this far outside the open mesh (and half
#: of it inside), whatever the point spacing: its zero level then lies between grid points of the
#: band on each side (on a 2 mm scan two spacings outside and one inside are under a step).
BAND_MIN_STEPS = 2.0


def closed_surface(points: np.ndarray, solids, spacing: float, voxel: float = 0.008,
                   cell: float = 1.5, envelope: float = 0.3, band: float = 2.0, seen=None,
                   view=None, carve: float = 0.25, background: float = 0.5, smooth: int = 12,
                   workers: int = 1):
    """A closed, manifold surface: the union of the sections' solids, each the inside of its
    radial height field with the holes filled (`radial_field`), by marching cubes.

    Two sections meet where their solids overlap (their seams share points), and nothing joins
    them across the air: each solid holds only its own section's surface and its fill stays
    within ``envelope`` of its model.

    Parameters
    ----------
    points : (n, 3) float, metres
    solids : list of (int, (k,) int, SectionShape[, dict, (k',) int])
        Section index, point indices and chart of each solid: the sections, and the far parts
        (`far_charts`, whose solids take their own points only).
    spacing : float
        Median point spacing, metres.
    voxel : float
        Grid step of the implicit surface, metres; at least ``spacing`` (a grid finer than the
        points gave more spurious area and more air on scans of the tune corpus, and costs the
        cube of its fineness).
    cell : float
        Spacings: cell size of the radial height fields.
    envelope : float
        Fill at most this times the section's width beyond its model radius.
    band : float
        Spacings: grid points over the open mesh, from this far outside it to half of it inside,
        take their signed distance to it (`seen_distance`; 0 = off): the seen surface comes out
        where the open mesh has it, the solids only close what it leaves open. At least
        `BAND_MIN_STEPS` grid steps outside (on a dense scan).
    seen : (vertices (n', 3), faces (f', 3), face_section (f',)), optional
        The open mesh (wound outward) and its faces' sections.
    view : (view_dir (n, 3), head (n,) or None), optional
        How ``points`` were seen (`recon.views.Views`).
    carve : float
        Spacings: grid points farther than this in front of the surface a camera saw are outside
        (0 = off).
    background : float
        Spacings: grid points that every head sees farther than this beside its silhouette (the
        image of its points, the gaps between neighbours closed over ``CLOSE`` spacings) are
        outside too, the surface placed this far beside the outermost points (0 = off;
        `recon.views.Views.beside`).
    smooth : int
        Taubin's smoothing steps (each a shrink and an inflate; 0 = off) on the marching-cubes
        surface: they take out the grid's facets (a face's normal off the smooth surface's by
        up to the angle of one grid step) without shrinking it.
    workers : int
        Threads of the KD-tree queries over the seen surface's band (speed only: the same surface
        with any number).

    Returns
    -------
    vertices : (v, 3) float
    faces : (f, 3) int
        Outward winding; every edge in exactly two faces; no component inside another (the
        union's cavities are filled).
    face_section : (f,) int8
    """
    from scipy.ndimage import label

    voxel = max(voxel, spacing)
    cell = max(cell * spacing, voxel)
    parts = []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for job in solids:
        j, idx, shape = job[:3]
        idx = job[4] if len(job) > 4 else idx      # a far part: its own points
        if len(idx) < 10:
            continue
        local = shape.local(points[idx])
        # a far part's chart is its points' own ellipse: its fill stays within it; its unseen side
        # no thicker than its thinnest seen side (a hand seen on its back), but a foot's: its sole,
        # on the floor, takes its fitted column (the floor's cut flattens it)
        part = len(job) > 3
        thin = (np.inf, -np.inf) if part and not shape.name.startswith("foot") else (-np.inf, np.inf)
        R, h0 = radial_field(local, cell, shape.radius_at, 0.0 if part else envelope * shape.width, thin)
        h1 = float(local[:, 2].max())
        reach = float(np.nanmax(R)) + cell
        corners = np.array([[x, y, z] for x in (-reach, reach) for y in (-reach, reach)
                            for z in (h0 - cell, h0 + (R.shape[1] + 1) * cell)])
        world = corners @ shape.frame + shape.start
        parts.append((j, shape, R, h0, h1, world.min(axis=0), world.max(axis=0)))
        lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int8)
    lo = np.maximum(lo, points.min(axis=0) - 0.05) - 2 * voxel
    hi = np.minimum(hi, points.max(axis=0) + 0.05) + 2 * voxel
    shape_ = tuple(np.ceil((hi - lo) / voxel).astype(int) + 1)
    F = np.full(shape_, -voxel)
    lab = np.zeros(shape_, dtype=np.int8)
    for j, shape, R, h0, h1, a, b in parts:
        i0 = np.clip(np.floor((a - lo) / voxel).astype(int), 1, None)
        i1 = np.minimum(np.ceil((b - lo) / voxel).astype(int) + 1, np.array(shape_) - 1)
        if (i1 <= i0).any():
            continue
        val = _solid_on_grid(R, h0, h1, cell, shape, lo, voxel, i0, i1)
        box = tuple(slice(a_, b_) for a_, b_ in zip(i0, i1))
        better = val > F[box]
        np.copyto(F[box], val, where=better)
        lab[box][better] = j
    if seen is not None and band > 0:
        _seen_band(F, lab, lo, voxel, spacing, max(band, BAND_MIN_STEPS * voxel / spacing), *seen,
                   workers=workers)
    if view is not None and (carve > 0 or background > 0):   # what a camera looked through is air
        flat = np.flatnonzero(F > -voxel)
        cams = Views(points, view[0], view[1], spacing)
        for s in range(0, len(flat), FIELD_CHUNK):   # in chunks: the temporaries stay in cache
            part = flat[s:s + FIELD_CHUNK]
            at = lo + voxel * np.column_stack(np.unravel_index(part, F.shape))
            projected = cams.project(at)     # once for the carve and the background
            cut = np.full(len(part), np.inf)
            if carve > 0:
                air = cams.air(at, projected)
                cut = np.where(np.isfinite(air), carve * spacing - air, np.inf)
            if background > 0:    # beside every head's silhouette
                cut = np.minimum(cut, background * spacing - cams.beside(at, CLOSE * spacing, voxel / 3, projected))
            F.reshape(-1)[part] = np.minimum(F.reshape(-1).take(part), cut)
    # nothing below the lowest point (the floor the subject stands on is not seen: no sole bulges)
    floor = lo[2] + voxel * np.arange(shape_[2]) - points[:, 2].min()
    low = int(np.searchsorted(floor, F.max(), side="right")) + 1    # the layers the floor can cut
    np.minimum(F[:, :, :low], floor[:low], out=F[:, :, :low])
    F[[0, -1]] = F[:, [0, -1]] = F[:, :, [0, -1]] = -voxel
    # no cavity within: grid points outside that no path of outside points joins to the border
    # (a piece of the open mesh inside a solid, seams of solids) are inside
    outer, _ = label(F < 0)
    F[(outer != outer[0, 0, 0]) & (outer > 0)] = voxel
    vertices, faces, face_label = grid_surface(F, lo, voxel, lab)
    if smooth > 0 and len(faces):
        # lambda, mu: Taubin's pass band k = 1 / lambda + 1 / mu = 0.1 (no shrinking below it)
        import trimesh

        mesh = trimesh.Trimesh(vertices, faces, process=False)
        trimesh.smoothing.filter_taubin(mesh, 0.5, 1.0 / (2.0 - 0.1), iterations=2 * int(smooth))
        vertices = np.asarray(mesh.vertices)
    return vertices, faces, face_label.astype(np.int8)


def _seen_band(F, lab, lo, voxel, spacing, band, vertices, faces, face_section, workers: int = 1):
    """Overwrite ``F`` (and ``lab``) in the seen surface's band with the signed distance to the
    open mesh (`seen_distance`), blended into the solids' value past its rims, in place.

    The band's grid points are found coarse to fine: the offsets along and beside the nearest
    vertex's normal on every second grid point near the mesh, then the signed distance only at the
    grid points whose coarse corner lies within reach of the band (the offsets change by at most the
    corner's distance, ``sqrt(3)`` steps, plus the turn of the normals between neighbouring vertices).
    """
    from scipy.ndimage import maximum_filter1d

    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return
    if not (F.flags.c_contiguous and lab.flags.c_contiguous):
        raise ValueError("_seen_band writes F and lab in place: they must be C-contiguous")
    index = seen_index(vertices, faces)
    used = index[0]
    shape = np.array(F.shape)
    reach = int(np.ceil(max(band, BAND_BLEND) * spacing / voxel)) + 1
    # grid points within ``reach`` steps (a box) of a vertex's grid point, on the coarse lattice
    # (even indices) first: the block of 2 x 2 x 2 points at each coarse point
    cshape = tuple((shape + 1) // 2)
    near = np.zeros(cshape, dtype=np.uint8)
    vi = np.clip(np.round((vertices[used] - lo) / voxel).astype(np.int64), 0, shape - 1)
    near[tuple((vi // 2).T)] = 1
    r = (reach + 2) // 2
    for ax in range(3):
        near = maximum_filter1d(near, 2 * r + 1, axis=ax, mode="constant")
    gc = np.argwhere(near) * 2
    reach_m = np.hypot(band, BAND_BLEND) * spacing
    margin = np.sqrt(3) * voxel
    # the offsets along (positive inside; NaN out of reach) and beside the nearest vertex's normal
    tree = index[2]
    at = lo + voxel * gc
    # a coarse point is kept only within this of a vertex (its offsets along and beside within the
    # limits below): the query need not look farther
    slack = SLACK * margin
    kept_max = np.hypot(band * spacing + slack, BAND_BLEND * spacing + slack) * (1 + 1e-9)
    dc, ic = tree.query(at, 1, distance_upper_bound=min(reach_m + 2 * margin, kept_max), workers=workers)
    along, beside, _ = seen_distance(vertices, faces, at, spacing, k=1, reach=reach_m + 2 * margin,
                                     index=index, nearest=(dc, ic))
    keep = np.flatnonzero((along > -band * spacing - slack) & (along < 0.5 * band * spacing + slack)
                          & (beside < BAND_BLEND * spacing + slack))
    # the 2 x 2 x 2 block of each kept coarse point, (0, 0, 0) first, and their flat grid indices
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    block = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    gk = gc[keep]
    g = (gk[:, None, :] + block[None]).reshape(-1, 3)
    ok = ((gk >= 1) & (gk < shape - 2)).all(axis=1)    # every block point inside the grid's border
    inside = np.repeat(ok, 8)
    if not ok.all():
        edge = np.repeat(~ok, 8)
        inside[edge] = ((g[edge] >= 1) & (g[edge] < shape - 1)).all(axis=1)
    g = g[inside]
    flat = g @ strides
    # the nearest vertex: a coarse point's is the coarse pass's (its query reached farther)
    parent = np.repeat(keep, 8)[inside]
    own = np.tile(np.arange(8) == 0, len(keep))[inside]
    d0, i0 = np.full(len(flat), np.inf), np.full(len(flat), len(index[0]), dtype=np.int64)
    within = own & (dc[parent] < reach_m)
    d0[within], i0[within] = dc[parent[within]], ic[parent[within]]
    ask = ~own
    at = lo + voxel * g
    d0[ask], i0[ask] = tree.query(at.take(np.flatnonzero(ask), axis=0), 1, distance_upper_bound=reach_m,
                                  workers=workers)
    dist, beside, v = seen_distance(vertices, faces, at, spacing, reach=reach_m,
                                    exact=EXACT * voxel, beside_max=BAND_BLEND * spacing, index=index,
                                    nearest=(d0, i0), workers=workers)
    w = np.clip((BAND_BLEND * spacing - beside) / ((BAND_BLEND - BAND_BESIDE) * spacing), 0, 1)
    over = (w > 0) & np.isfinite(dist) & (dist > -band * spacing) & (dist < 0.5 * band * spacing)
    flat, w = flat[over], w[over]
    Ff = F.reshape(-1)
    Ff[flat] = w * dist[over] + (1 - w) * Ff.take(flat)
    vsec = np.zeros(len(vertices), dtype=lab.dtype)
    vsec[faces.ravel()] = np.repeat(np.asarray(face_section, dtype=lab.dtype), 3)
    lab.reshape(-1)[flat] = vsec[v[over]]
