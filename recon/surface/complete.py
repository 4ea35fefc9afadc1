"""Completion beyond the paper: every seen point in the surface, and the unseen surface closed.

`far_charts`: the points that no fitted section explains (beyond T_d of every section: hands,
feet, the points of a section listed unfitted; and the forearm and lower-leg points past the
fitted wrist and ankle, `past_joints`, which the paper's model lengthens its columns over) are
grouped into connected parts, and each part of at least ``far_min_points`` points gets a chart of
its own, which also holds the meshed points within ``far_join`` spacings of the part, so that the
part's surface joins its section's. With ``far_view`` the chart is the range image each camera
took of the part, triangulated across its view (`recon.surface.mesh.view_surface`: a hand or a
foot is a height field over its camera's image, whatever its shape); otherwise (the chart kept
for `closed_surface`) an elliptic column along the part's principal axis (open at the end that
joins the body, closed by a cap at the other), triangulated like a section
(`recon.surface.mesh.section_surface`). Then the merge and the air rules as for any section; the
faces carry the section whose axis comes nearest (a hand counts as its forearm, a foot as its
lower leg). Smaller parts are outliers and stay out of the surface.

`closed_surface` (the method ``proposed-closed``): each section's and far part's points, in its
chart's cylindrical coordinates, give a radial height field r(theta, h) whose holes (what the
scanner did not see) are filled by a discrete Laplace equation within the model's envelope
(`radial_field`); each field bounds a solid, the solids are united (a maximum of their signed
values on a grid) and the union's surface is extracted by marching tetrahedra: one closed,
consistently wound 2-manifold. Sections join where their solids overlap at the seams; no solid
holds another section's points, so no surface spans the air between two sections.
"""

from __future__ import annotations

import numpy as np

from ..model import SECTIONS, SectionShape


def far_parts(points: np.ndarray, far: np.ndarray, link: float, min_points: int):
    """Connected parts of the ``far`` points.

    Parameters
    ----------
    points : (n, 3) float, metres
    far : (n,) bool
        The points no fitted section explains.
    link : float
        Two far points nearer than this (metres) are in the same part.
    min_points : int
        Smaller parts are left out (outliers).

    Returns
    -------
    list of (k,) int
        Point indices of each part, largest first.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    idx = np.flatnonzero(far)
    if len(idx) < max(min_points, 1):
        return []
    pairs = cKDTree(points[idx]).query_pairs(link, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
    _, lab = connected_components(g, directed=False)
    count = np.bincount(lab)
    order = np.argsort(-count, kind="stable")
    return [idx[lab == c] for c in order if count[c] >= min_points]


#: The limb sections whose fitted column goes on over a hand or a foot, and the joint that ends them.
DISTAL = {"forearm_l": "wrist_l", "forearm_r": "wrist_r", "lower_leg_l": "ankle_l", "lower_leg_r": "ankle_r"}


def past_joints(points: np.ndarray, member: np.ndarray, fit, margin: float = 0.0,
                hands: bool = True) -> np.ndarray:
    """(n,) bool: the points of a forearm or lower leg past its fitted wrist or ankle.

    The paper's model has no hands and feet, so the fit lengthens a forearm over its hand (and a
    lower leg's end cap takes the heel): their points lie within T_d of the section's column, and
    a hand's fingers and a foot's arch fold over it. Past the joint they are a far part's points
    (`far_charts`: meshed as their cameras saw them) and no longer the section's.

    Parameters
    ----------
    points : (n, 3) float, metres
    member : (n, 11) bool
        Section memberships.
    fit : BodyFit
        Its sections and joints (``wrist_l``, ``ankle_l``, ...).
    margin : float
        Metres past the joint, along the section's axis.
    hands : bool
        Also the hands (False: the feet only; a hand's fingers and their gaps need a finer scan
        than a foot).
    """
    out = np.zeros(len(points), dtype=bool)
    for name, joint in DISTAL.items():
        if not hands and name.startswith("forearm"):
            continue
        if name not in fit.sections or joint not in (fit.joints or {}):
            continue
        j = SECTIONS.index(name)
        along = (points - np.asarray(fit.joints[joint], dtype=float)) @ fit.sections[name].axis
        out |= member[:, j] & (along > margin)
    return out


def part_shape(part: np.ndarray, joined: np.ndarray, name: str) -> SectionShape:
    """The chart of one far part: an elliptic column along the part's principal axis.

    Parameters
    ----------
    part : (k, 3) float
        The part's points, metres.
    joined : (j, 3) float
        The meshed points it joins (may be empty); the column is open at the end nearer to them
        (they lie on its extension) and closed by a cap at the other.
    name : str
        Section name given to the shape.
    """
    c = part.mean(axis=0)
    q = part - c
    _, vec = np.linalg.eigh(q.T @ q)
    axis, fx = vec[:, 2], vec[:, 1]
    t = q @ axis
    lo, hi = float(t.min()), float(t.max())
    if len(joined) and float(((joined - c) @ axis).mean()) > 0.5 * (lo + hi):
        axis, t, lo, hi = -axis, -t, -hi, -lo      # the joined end is the start
    spread = np.sqrt(np.maximum(np.mean((q @ np.column_stack([fx, np.cross(axis, fx)])) ** 2, axis=0), 0))
    radii = np.maximum(1.7 * spread, 0.005)   # a uniform plate's half-width is 1.73 std
    length = max(hi - lo, 0.01)
    cap = min(float(radii.mean()), 0.5 * length)
    return SectionShape(name=name, start=c + lo * axis, end=c + (lo + length) * axis, radii=radii,
                        frame_x=fx, closed=(not len(joined), True), caps=(cap, cap))


def nearest_axis(part: np.ndarray, sections: dict) -> int:
    """Index (into `SECTIONS`) of the fitted section whose axis segment comes nearest to the
    points ``part`` (k, 3): the section a far part continues (a hand its forearm, past the wrist,
    even when it hangs nearer to a thigh's surface than to the forearm's)."""
    best, out = np.inf, 0
    for j, name in enumerate(SECTIONS):
        if name not in sections:
            continue
        sh = sections[name]
        t = np.clip((part - sh.start) @ sh.axis, 0.0, sh.length)
        d = float(np.linalg.norm(part - sh.start - t[:, None] * sh.axis, axis=1).min())
        if d < best:
            best, out = d, j
    return out


def far_charts(points: np.ndarray, far: np.ndarray, sections: dict, meshed: np.ndarray,
               spacing: float, link: float = 4.0, join: float = 3.0, min_points: int = 5,
               max_edge: float = 4.0, tree=None, hands: bool = True):
    """Charts for the points no fitted section explains (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float, metres
    far : (n,) bool
        Points beyond T_d of every fitted section (hands, feet, a section listed unfitted).
    sections : dict of str to SectionShape
        The fitted sections (`BodyFit.sections`): a part goes to the one whose axis comes
        nearest (`nearest_axis`).
    meshed : (n, 11) bool
        Memberships of the points meshed on the sections' own charts.
    spacing : float
        Median point spacing, metres.
    link, join : float
        Spacings: far points nearer than ``link`` form one part; meshed points within ``join``
        of a part, in its section, join its chart.
    min_points : int
        Parts with fewer points are outliers and stay out.
    max_edge : float
        Spacings: longer triangles are left out of these charts (a hand's or a foot's points are
        few across its features: long triangles there span fingers and toes).
    tree : scipy.spatial.cKDTree, optional
        Of ``points``, if already built.
    hands : bool
        False: the parts continuing a forearm (hands) are triangulated around their column
        (``far_view`` off in their parameters): on a coarse scan a hand's range image bridges the
        gaps between its fingers.

    Returns
    -------
    list of (int, (k,) int, SectionShape, dict, (k',) int)
        Parts with no meshed point within ``join`` spacings are left out (nothing of the body
        they continue).
        Section index, point indices, chart and surface parameter changes of each part (for
        `recon.surface.mesh.reconstruct_surfaces`'s ``extra``), and the part's own points (without
        the joined ones: its solid in `closed_surface`). The parts' points are in no section
        of ``meshed``: not in their section's own chart, and never "inner" in the merge.
    """
    from scipy.spatial import cKDTree

    jobs = []
    tree = cKDTree(points) if tree is None else tree
    for idx in far_parts(points, far, link * spacing, min_points):
        j = nearest_axis(points[idx], sections)
        near = tree.query_ball_point(points[idx], join * spacing)
        near = np.unique(np.concatenate([np.asarray(a, dtype=np.int64) for a in near]))
        if not meshed[near].any():   # joined to no meshed point: not the body's (a fit off the cloud)
            continue
        near = near[meshed[near, j]]
        shape = part_shape(points[idx], points[near], SECTIONS[j])
        change = {"max_edge_factor": max_edge}
        if not hands and SECTIONS[j].startswith("forearm"):
            change["far_view"] = False     # a hand on a coarse scan: around its column
        jobs.append((j, np.union1d(idx, near), shape, change, idx))
    return jobs


def unmeshed_count(n: int, faces: np.ndarray) -> int:
    """Points of ``n`` in no face of ``faces`` (k, 3)."""
    used = np.zeros(n, dtype=bool)
    used[np.asarray(faces, dtype=np.int64).ravel()] = True
    return int(n - used.sum())


# --------------------------------------------------------------------------------------------------
# the closed surface


#: The six tetrahedra of a cube (corner k at offset (k & 1, k >> 1 & 1, k >> 2 & 1)), all around
#: the diagonal 0-7 (Kuhn): neighbouring cubes split their shared faces alike, so the tetrahedra
#: tile the grid and marching them gives a closed manifold surface.
_TETS = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])


def marching_tetrahedra(values: np.ndarray, origin: np.ndarray, step: float, labels=None):
    """The surface ``values = 0`` of a grid, closed and consistently wound outward.

    Parameters
    ----------
    values : (nx, ny, nz) float
        Positive inside; the grid's border must be outside (negative).
    origin : (3,) float
        Position of ``values[0, 0, 0]``, metres.
    step : float
        Grid spacing, metres.
    labels : (nx, ny, nz) int, optional
        A label per grid point; each face takes the label of an inside corner of its tetrahedron.

    Returns
    -------
    vertices : (v, 3) float
    faces : (f, 3) int
        Outward winding (normals toward decreasing ``values``).
    face_label : (f,) int
        Per face (zeros without ``labels``).
    """
    v = np.where(values == 0, 1e-12, values).astype(np.float64)
    nx, ny, nz = v.shape
    inside = v > 0
    corner = np.array([[k & 1, k >> 1 & 1, k >> 2 & 1] for k in range(8)])
    flat = v.ravel()
    ins = inside.ravel()
    off = np.ravel_multi_index(corner.T, v.shape)
    cnt = sum(inside[i:nx - 1 + i, j:ny - 1 + j, k:nz - 1 + k].astype(np.int8) for i, j, k in corner)
    cube = np.flatnonzero((cnt > 0) & (cnt < 8))             # cubes the surface crosses
    base = np.ravel_multi_index(np.unravel_index(cube, (nx - 1, ny - 1, nz - 1)), v.shape)
    tet = (base[:, None, None] + off[_TETS][None]).reshape(-1, 4)
    s = ins[tet]
    n_in = s.sum(axis=1)
    tet, s, n_in = tet[(n_in > 0) & (n_in < 4)], s[(n_in > 0) & (n_in < 4)], n_in[(n_in > 0) & (n_in < 4)]
    # order each tetrahedron's corners: inside ones first
    order = np.argsort(~s, axis=1, kind="stable")
    t = np.take_along_axis(tet, order, axis=1)
    tris = []      # (m, 3, 2) corner pairs of each triangle's three edge points, and the tet row
    rows = []
    one = np.flatnonzero(n_in == 1)        # a | b c d
    tris.append(np.stack([t[one][:, [0, 1]], t[one][:, [0, 2]], t[one][:, [0, 3]]], axis=1))
    rows.append(one)
    three = np.flatnonzero(n_in == 3)      # a b c | d
    tris.append(np.stack([t[three][:, [0, 3]], t[three][:, [1, 3]], t[three][:, [2, 3]]], axis=1))
    rows.append(three)
    two = np.flatnonzero(n_in == 2)        # a b | c d: the quad ac ad bd bc
    q = t[two]
    tris.append(np.stack([q[:, [0, 2]], q[:, [0, 3]], q[:, [1, 3]]], axis=1))
    tris.append(np.stack([q[:, [0, 2]], q[:, [1, 3]], q[:, [1, 2]]], axis=1))
    rows += [two, two]
    pairs = np.concatenate(tris)                           # (m, 3, 2): inside corner, outside corner
    row = np.concatenate(rows)
    key = pairs[..., 0].astype(np.int64) * flat.size + pairs[..., 1]
    uniq, inv = np.unique(key.ravel(), return_inverse=True)
    a, b = uniq // flat.size, uniq % flat.size
    w = flat[a] / (flat[a] - flat[b])                      # a inside (> 0), b outside (< 0)
    w = np.clip(w, 1e-3, 1 - 1e-3)
    pa = np.column_stack(np.unravel_index(a, v.shape)).astype(np.float64)
    pb = np.column_stack(np.unravel_index(b, v.shape)).astype(np.float64)
    vertices = origin + step * (pa + w[:, None] * (pb - pa))
    faces = inv.reshape(-1, 3)
    # outward: from the tetrahedron's inside corners toward its outside ones
    tt, ss = tet[row], s[row]
    cp = np.stack(np.unravel_index(tt, v.shape), axis=-1).astype(np.float64)
    k_in = ss.sum(axis=1, keepdims=True)
    out_dir = ((cp * ~ss[..., None]).sum(axis=1) / (4 - k_in) - (cp * ss[..., None]).sum(axis=1) / k_in)
    p = vertices[faces]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", nrm, out_dir) < 0
    faces[flip] = faces[flip][:, ::-1]
    if labels is None:
        face_label = np.zeros(len(faces), dtype=np.int64)
    else:
        face_label = labels.ravel()[pairs[:, 0, 0]]
    return vertices, faces, face_label


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
        row: parts of unknown shape (a far part: a hand, a foot) have their unseen side taken as
        thin as their thinnest seen side.

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


def field_value(R: np.ndarray, h0: float, cell: float, local: np.ndarray, h1=None) -> np.ndarray:
    """(k,) signed value, positive inside, of the solid ``rho <= R(theta, h)`` at the points
    ``local`` (k, 3) of its frame: ``R - rho`` bilinear in the grid, bounded by the signed distance
    (metres along the grid) to the edge of the surface's cells, so that the solid ends half a cell
    past its last cells (and not past ``h1``, the last point's h, when given)."""
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
    rho = np.hypot(local[:, 0], local[:, 1])
    tf = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi) / (2 * np.pi) * n_t - 0.5
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


def _solid_on_grid(R, h0, h1, cell, shape, lo, voxel, i0, i1):
    """`field_value` of one solid on the grid box ``i0:i1`` (origin ``lo``, step ``voxel``):
    computed on every second grid point, then on every grid point only near the solid's surface
    (within 4 steps; elsewhere only its sign matters, and the coarse value has it)."""
    from scipy.ndimage import binary_dilation

    D = tuple(int(d) for d in i1 - i0)
    gc = np.indices(tuple((d + 1) // 2 for d in D)).reshape(3, -1).T * 2 + i0
    vc = field_value(R, h0, cell, shape.local(lo + voxel * gc), h1).reshape(tuple((d + 1) // 2 for d in D))
    near = binary_dilation(np.abs(vc) < 4 * voxel)
    up = (lambda a: a.repeat(2, 0).repeat(2, 1).repeat(2, 2)[:D[0], :D[1], :D[2]])
    out = np.ascontiguousarray(up(vc))
    fine = np.flatnonzero(up(near))
    g = np.column_stack(np.unravel_index(fine, D)) + i0
    out.ravel()[fine] = field_value(R, h0, cell, shape.local(lo + voxel * g), h1)
    return out


def closed_surface(points: np.ndarray, solids, spacing: float, voxel: float = 0.008,
                   cell: float = 1.5, envelope: float = 0.3):
    """A closed, manifold surface: the union of the sections' solids, each the inside of its
    radial height field with the holes filled (`radial_field`), by marching tetrahedra.

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
        Grid step of the implicit surface, metres.
    cell : float
        Spacings: cell size of the radial height fields.
    envelope : float
        Fill at most this times the section's width beyond its model radius.

    Returns
    -------
    vertices : (v, 3) float
    faces : (f, 3) int
        Outward winding; every edge in exactly two faces.
    face_section : (f,) int8
    """
    cell = max(cell * spacing, voxel)
    parts = []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for job in solids:
        j, idx, shape = job[:3]
        idx = job[4] if len(job) > 4 else idx      # a far part: its own points
        if len(idx) < 10:
            continue
        local = shape.local(points[idx])
        # a far part's chart is its points' own ellipse: its fill stays within it
        part = len(job) > 3
        thin = (np.inf, -np.inf) if part else (-np.inf, np.inf)
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
        F[box] = np.where(better, val, F[box])
        lab[box] = np.where(better, j, lab[box])
    # nothing below the lowest point (the floor the subject stands on is not seen: no sole bulges)
    F = np.minimum(F, (lo[2] + voxel * np.arange(shape_[2]) - points[:, 2].min())[None, None, :])
    F[[0, -1]] = F[:, [0, -1]] = F[:, :, [0, -1]] = -voxel
    vertices, faces, face_label = marching_tetrahedra(F, lo, voxel, lab)
    return vertices, faces, face_label.astype(np.int8)
