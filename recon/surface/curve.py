"""Curved subdivision: long triangles follow the surface their vertices' normals describe.

A chart's Delaunay triangles join samples; where the samples are far apart (the flanks of limbs
and trunk, which the front and rear cameras see at grazing angles), a flat triangle is a chord of
the curved body and lies inside it, by ``L**2 / (8 r)`` for an edge of length L on a radius r (7 mm
for 66 mm on a thigh). Splitting the long edges at midpoints lifted toward the vertices' tangent
planes (the quadratic of Phong tessellation, Boubekeur and Alexa 2008, with shape factor 1/2,
which is exact to second order on a circle) puts the surface back where the body is. A midpoint
depends only on its edge, so neighbouring triangles share it: the mesh keeps its connectivity,
with no cracks or T-junctions.
"""

from __future__ import annotations

import numpy as np

from .mesh import max_edge_length

#: Phong tessellation's shape factor: 1/2 lifts a chord's midpoint onto a circle through its ends
#: with the circle's tangents there (to second order in the arc's angle).
SHAPE_FACTOR = 0.5


def curved_midpoints(a: np.ndarray, b: np.ndarray, na: np.ndarray, nb: np.ndarray):
    """Midpoints of the edges ``a``-``b`` (k, 3) lifted toward the tangent planes of their ends.

    Parameters
    ----------
    a, b : (k, 3) float
        The edges' ends.
    na, nb : (k, 3) float
        Unit normals at the ends, oriented alike (outward).

    Returns
    -------
    mid : (k, 3) float
        On an arc of angle 2a and radius r with its normals, within about ``3/8 r a**4`` of the
        arc (0.5 mm for a 39 mm edge on a 5 cm radius, whose chord is 3.9 mm inside it).
    normal : (k, 3) float
        Unit normal at each midpoint: the ends' normals averaged.
    """
    m = (a + b) / 2
    lift = (np.einsum("ij,ij->i", a - m, na)[:, None] * na
            + np.einsum("ij,ij->i", b - m, nb)[:, None] * nb)
    n = na + nb
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return m + SHAPE_FACTOR * 0.5 * lift, n


def curved_subdivision(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, max_edge: float,
                       face_data: np.ndarray | None = None, rounds: int = 8):
    """Split every edge longer than ``max_edge`` at its curved midpoint until none is.

    Each round splits the long edges (`curved_midpoints`) and replaces each triangle by 2, 3 or 4
    according to how many of its edges were split (red-green refinement), so that every triangle
    sharing an edge shares its midpoint.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (k, 3) int
    normals : (n, 3) float
        Unit normals at the vertices, oriented alike (read only at the vertices of long edges).
    max_edge : float
        Metres: no edge longer than this is left (within ``rounds`` halvings).
    face_data : (k,) array, optional
        Carried to each triangle's pieces (a face's section).
    rounds : int
        At most this many halvings.

    Returns
    -------
    vertices : (n + n_new, 3) float
        The input vertices in order, then the new ones.
    faces : (k', 3) int
        With the winding of the triangles they came from.
    face_data : (k',) array or None
    """
    V = [np.asarray(vertices, dtype=np.float64)]
    N = [np.asarray(normals, dtype=np.float64)]
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    D = None if face_data is None else np.asarray(face_data)
    if max_edge <= 0:
        raise ValueError(f"max_edge must be positive, got {max_edge}")
    done, done_data = [], []   # faces with no long edge: no round changes them
    for _ in range(rounds):
        verts, nrm = np.concatenate(V), np.concatenate(N)
        active = max_edge_length(verts, F) > max_edge
        done.append(F[~active])
        done_data.append(None if D is None else D[~active])
        F, D = F[active], None if D is None else D[active]
        if not len(F):
            break
        corner = np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1)   # edge j: corners j, j+1
        pair = np.sort(corner, axis=2).reshape(-1, 2)
        key, inv = np.unique(pair[:, 0] * len(verts) + pair[:, 1], return_inverse=True)
        key = np.column_stack([key // len(verts), key % len(verts)])
        long = np.linalg.norm(verts[key[:, 0]] - verts[key[:, 1]], axis=1) > max_edge
        if not long.any():
            break
        k0, k1 = key[long, 0], key[long, 1]
        mid, n = curved_midpoints(verts[k0], verts[k1], nrm[k0], nrm[k1])
        at = np.full(len(key), -1)
        at[long] = len(verts) + np.arange(len(mid))
        V.append(mid)
        N.append(n)
        me = at[inv.ravel()].reshape(-1, 3)          # midpoint on edge j of each face, -1 for none
        split = me >= 0
        count = split.sum(axis=1)
        pieces, data = [F[count == 0]], [] if D is None else [D[count == 0]]
        for c in (1, 2, 3):
            sel = np.flatnonzero(count == c)
            if not len(sel):
                continue
            # turn each face so that its split edges come first: edge 0 (c = 1), edges 0 and 1 (c = 2)
            first = np.argmax(split[sel], axis=1) if c == 1 else \
                (np.argmin(split[sel], axis=1) + 1) % 3 if c == 2 else np.zeros(len(sel), dtype=np.int64)
            turn = (first[:, None] + np.arange(3)) % 3
            v0, v1, v2 = np.take_along_axis(F[sel], turn, axis=1).T
            m01, m12, m20 = np.take_along_axis(me[sel], turn, axis=1).T
            if c == 1:
                new = [(v0, m01, v2), (m01, v1, v2)]
            elif c == 2:
                new = [(m01, v1, m12), (v0, m01, m12), (v0, m12, v2)]
            else:
                new = [(v0, m01, m20), (m01, v1, m12), (m20, m12, v2), (m01, m12, m20)]
            pieces += [np.stack(t, axis=1) for t in new]
            if D is not None:
                data += [D[sel]] * len(new)
        F = np.concatenate(pieces)
        D = None if D is None else np.concatenate(data)
    F = np.concatenate(done + [F])
    D = None if D is None else np.concatenate(done_data + [D])
    return np.concatenate(V), F, D


def curve_surface(points: np.ndarray, faces: np.ndarray, max_edge: float, view_dir=None, tree=None,
                  face_data: np.ndarray | None = None):
    """`curved_subdivision` of the outward-wound ``faces`` (k, 3) over ``points`` (n, 3), with
    `outward_normals` at the vertices of its long edges. Returns the same as it."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    active = max_edge_length(points, faces) > max_edge   # the others stay as they are
    normals = outward_normals(points, faces, view_dir, tree=tree, at=np.unique(faces[active]))
    v, f, d = curved_subdivision(points, faces[active], normals, max_edge,
                                 None if face_data is None else face_data[active])
    return v, np.concatenate([faces[~active], f]), None if d is None else np.concatenate([face_data[~active], d])


def outward_normals(points: np.ndarray, faces: np.ndarray, view_dir=None, k: int = 12, tree=None,
                    at: np.ndarray | None = None):
    """(n, 3) unit normals of ``points`` (n, 3) at the vertices ``at`` (default: those of
    ``faces`` (k, 3)), zero elsewhere: the direction of least spread of each vertex's ``k``
    nearest points (`recon.surface.mesh.point_normals`), turned to the side the outward-wound
    faces around it face. The faces' own normals would lean toward the long triangles that
    `curved_subdivision` is meant to bend."""
    from .mesh import point_normals

    points = np.asarray(points, dtype=np.float64)
    out = np.zeros_like(points)
    at = np.unique(faces) if at is None else np.asarray(at, dtype=np.int64)
    if not len(at):
        return out
    n = point_normals(points, at, np.zeros(3) if view_dir is None else view_dir, k, tree)
    on = np.zeros(len(points), dtype=bool)
    on[at] = True
    faces = faces[on[faces].any(axis=1)]                      # the faces around them
    p = points[faces]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])       # area-weighted, outward
    around = np.stack([np.bincount(faces.ravel(), np.repeat(fn[:, c], 3), len(points)) for c in range(3)], 1)
    out[at] = n * np.where(np.einsum("ij,ij->i", n, around[at]) < 0, -1.0, 1.0)[:, None]
    return out
