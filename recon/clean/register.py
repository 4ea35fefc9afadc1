"""Registration between scanner heads: robust point-to-surface ICP on their overlap (beyond the paper).

The paper leaves the misalignment between its cameras to future work. Where two heads overlap, a
point of one is paired with the robust quadratic surface (`recon.clean.denoise.local_fits`) of
the other's points near it, where the two surfaces are alike in direction (PCA normals within
``normal_cos``). The point-to-surface distances of every overlapping pair of heads are minimised
together over all heads' rigid motions (a global multi-view ICP: Gauss-Newton with Tukey weights
on the MAD scale of the residuals, the pairing distance shrinking as the fit converges), so a
ring of heads that each overlap only their neighbours is closed as one piece.

Only where the heads really overlap (both measured the same surface, their points interleaved)
is the offset measured. Heads in towers overlap over tens of centimetres and are registered to
within about a tenth of a degree; the paper's front and rear heads meet only along the silhouettes,
seen edge on, where neither measures the surface beyond its own side: a head with less than
``min_overlap`` of its points in an overlap is left as it is by `register_heads`;
`register_silhouettes` registers such a pair by their common outline instead. Directions of the
motion whose standard error exceeds ``max_error`` are not moved either (truncated Gauss-Newton on
the eigenvectors of the normal matrix): the motion of the whole scanner, and between two towers
facing each other the turns across and the shift along their view; `Registration` reports how
many directions were estimated. The heads' mean motion is removed, so no head is taken as exact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import rotvec
from .denoise import local_fits, robust_scale, tukey_weights


@dataclass(frozen=True, eq=False)
class Registration:
    """The rigid corrections applied to each head.

    Attributes
    ----------
    rotation : (h, 3, 3) float
        Rotation applied to each head's points about ``center``.
    translation : (h, 3) float
        Then this translation, metres.
    center : (3,) float
        Centre of the rotations (the cloud's bounding-box centre), metres.
    pairs : (h,) int
        Overlap pairs of each head's points in the last step.
    observable : (h,) int
        Of the 6 motion directions, how many were estimated for each head against the heads it
        overlaps (the rest: their standard error exceeded ``max_error``).
    """

    rotation: np.ndarray
    translation: np.ndarray
    center: np.ndarray
    pairs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    observable: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def offset(self, a: int = 0, b: int = 1) -> tuple[float, float]:
        """(degrees, millimetres) of the estimated misregistration of head ``b`` against head ``a``:
        the rotation angle and the translation at ``center`` of ``b``'s correction relative to
        ``a``'s."""
        r = self.rotation[a].T @ self.rotation[b]
        t = self.rotation[a].T @ (self.translation[b] - self.translation[a])
        angle = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        return float(angle), float(1000 * np.linalg.norm(t))

    def apply(self, points: np.ndarray, head: np.ndarray, view_dir: np.ndarray | None = None):
        """``points`` (n, 3) and ``view_dir`` (n, 3) with each head's correction applied."""
        p = np.array(points, dtype=np.float64)
        vd = None if view_dir is None else np.array(np.broadcast_to(view_dir, p.shape), dtype=np.float64)
        for h in range(len(self.rotation)):
            sel = head == h
            p[sel] = (p[sel] - self.center) @ self.rotation[h].T + self.center + self.translation[h]
            if vd is not None:
                vd[sel] = vd[sel] @ self.rotation[h].T
        return p, vd


def _log_rotation(r: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix (angles well below pi)."""
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))
    if angle < 1e-12:
        return np.zeros(3)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return v * angle / (2 * np.sin(angle))


def _normals(query: np.ndarray, points: np.ndarray, tree, k: int) -> np.ndarray:
    """(m, 3) unit normals (unsigned) at ``query`` by PCA of their ``k`` nearest ``points``
    (``tree`` of them)."""
    _, nb = tree.query(query, k=k)
    q = points[nb] - points[nb].mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.swapaxes(q, 1, 2) @ q)[1][:, :, 0]


def truncated_step(J: np.ndarray, w: np.ndarray, res: np.ndarray, scale: float, max_error: float):
    """One weighted Gauss-Newton step for residuals ``res`` (m,) with Jacobian ``J`` (m, k) and
    weights ``w`` (m,), truncated to the eigen-directions of the normal matrix whose standard error
    at ``scale`` is below ``max_error`` (a rotation's in metres at 1 m): the data move only what
    they measure. Returns the step (k,) and the eigen-directions it used (k, kept) as columns."""
    lam, vec = np.linalg.eigh(J.T @ (w[:, None] * J))
    keep = scale / np.sqrt(np.maximum(lam, 1e-300)) < max_error
    return -vec[:, keep] @ ((vec[:, keep].T @ (J.T @ (w * res))) / lam[keep]), vec[:, keep]


def register_heads(points: np.ndarray, head: np.ndarray, spacing: float, reach: float = 0.005,
                   iterations: int = 30, max_error: float = 5e-4, min_pairs: int = 200,
                   min_overlap: float = 0.05, neighbours: int = 16, normal_cos: float = 0.7,
                   max_pairs: int = 1000) -> Registration:
    """Estimate every head's rigid correction at once from the overlaps between heads.

    Each ordered pair of overlapping heads (a, b) contributes a sample of a's points near b's
    surface; a residual is the distance of such a point from the robust quadratic surface of b's
    points around it, and depends on the motions of both a and b. All heads' motions are solved
    together by Gauss-Newton with Tukey weights (a global multi-view ICP): a ring of heads, each
    overlapping only its neighbours, converges as one piece instead of head by head. The motion
    of the whole scanner, which no residual sees, and any relative motion the overlaps do not
    measure are left out by the truncated step (`truncated_step`).

    Parameters
    ----------
    points : (n, 3) float, metres
    head : (n,) int
        Head index of each point (0 .. h-1).
    spacing : float
        Median point spacing, metres.
    reach : float
        The overlap: points with a point of another head within this distance (at least 2
        spacings), metres. Pairs may be twice as far apart at the start; the limit then shrinks
        towards 4 robust scales of the residuals plus 2 spacings.
    iterations : int
        Gauss-Newton steps, at most.
    max_error : float
        A motion direction is estimated only when its standard error is below this, metres (a
        rotation's at 1 m from the centre).
    min_pairs : int
        A pair of heads with fewer points in its overlap is not used;
    min_overlap : float
        neither is a head with less than this fraction of its points near another head.
    neighbours : int
        Points of each surface fit and normal.
    normal_cos : float
        Pairs whose (unsigned) normals make a cosine below this are not paired.
    max_pairs : int
        Points of each pair's overlap used, at most (a seeded sample).

    Returns
    -------
    Registration
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    head = np.asarray(head).astype(np.int64)
    nh = int(head.max()) + 1 if len(head) else 0
    center = (points.min(axis=0) + points.max(axis=0)) / 2
    rot = np.repeat(np.eye(3)[None], max(nh, 1), axis=0)[:nh]
    trans = np.zeros((nh, 3))
    pairs = np.zeros(nh, dtype=int)
    observable = np.zeros(nh, dtype=int)
    k = int(min(neighbours, len(points) - 1))
    reach = max(reach, 2 * spacing)
    own = [np.flatnonzero(head == h) for h in range(nh)]
    big = [len(i) >= min_pairs for i in own]
    trees = [cKDTree(points[i]) if b else None for i, b in zip(own, big)]
    links = []  # (a, b, a's overlap points, their normals): each head's trees stay in its own frame
    for a in range(nh):
        if not big[a]:
            continue
        cand = own[a]
        if len(cand) > 20 * max_pairs:  # the overlaps are found on a seeded sample (speed only)
            cand = np.sort(np.random.default_rng(a).choice(cand, 20 * max_pairs, replace=False))
        per = len(own[a]) / len(cand)  # head a's points per candidate
        near = {b: np.isfinite(trees[b].query(points[cand], distance_upper_bound=reach)[0])
                for b in range(nh) if b != a and big[b]}
        if per * np.logical_or.reduce(list(near.values())).sum() < max(min_pairs, min_overlap * len(own[a])):
            continue
        for b, m in near.items():
            idx = cand[m]
            if per * len(idx) < min_pairs:
                continue
            if len(idx) > max_pairs:  # a seeded sample of the overlap (speed only)
                idx = np.sort(np.random.default_rng([a, b]).choice(idx, max_pairs, replace=False))
            p0 = points[idx]
            links.append((a, b, p0, _normals(p0, points[own[a]], trees[a], k)))
    if not links:
        return Registration(rot, trans, center, pairs, observable)
    limit = 2 * reach
    used = np.zeros((6 * nh, 0))
    for _ in range(iterations):
        res, rows, cols = [], [], []
        count = np.zeros(nh, dtype=int)
        for a, b, p0, n0 in links:
            p = (p0 - center) @ rot[a].T + center + trans[a]
            q = (p - center - trans[b]) @ rot[b] + center  # in b's own frame
            d, nb = trees[b].query(q, k=k)
            ok = d[:, 0] < limit
            fit = local_fits(points[own[b]], q[ok], nb[ok], iterations=1)
            normal = fit.normal @ rot[b].T
            same = np.abs(np.einsum("ij,ij->i", normal, n0[ok] @ rot[a].T)) > normal_cos
            g = np.column_stack([np.cross(p[ok][same] - center, normal[same]), normal[same]])
            res.append(fit.residual[same])
            rows.append(g)
            cols.append((a, b))
            count[a] += len(g)
        r = np.concatenate(res)
        if len(r) < min_pairs:
            break
        J = np.zeros((len(r), 6 * nh))
        at = 0
        for g, (a, b) in zip(rows, cols):  # a's points move with a, b's surface with b
            J[at:at + len(g), 6 * a:6 * a + 6] = g
            J[at:at + len(g), 6 * b:6 * b + 6] = -g
            at += len(g)
        scale = robust_scale(r, floor=1e-5)
        step, used = truncated_step(J, tukey_weights(r, scale), r, scale, max_error)
        for h in range(nh):
            dr = rotvec(step[6 * h:6 * h + 3])
            rot[h] = dr @ rot[h]
            trans[h] = dr @ trans[h] + step[6 * h + 3:6 * h + 6]
        pairs = count
        limit = max(4 * scale + 2 * spacing, 0.7 * limit)
        if np.abs(step).max() < 1e-6:
            break
    # the directions estimated for each head: the rank of the kept eigen-directions on its motion
    for h in range(nh):
        observable[h] = int((np.linalg.svd(used[6 * h:6 * h + 6], compute_uv=False) > 0.25).sum())
    # remove the heads' mean motion: the corrections are relative, no head is exact
    back = rotvec(-np.mean([_log_rotation(x) for x in rot], axis=0))
    t_mean = trans.mean(axis=0)
    for h in range(nh):
        rot[h] = back @ rot[h]
        trans[h] = back @ (trans[h] - t_mean)
    return Registration(rot, trans, center, pairs, observable)


#: Outline points of each line of `register_silhouettes`' outline.
OUTLINE_LINE = 8


def register_silhouettes(points: np.ndarray, head: np.ndarray, view_dir: np.ndarray, spacing: float,
                         iterations: int = 30, min_points: int = 100, max_error: float = 5e-4) -> Registration:
    """Estimate the offset between two opposite heads from their silhouettes.

    Two heads looking along opposite directions ``a`` and ``-a`` see the same occluding contour
    (exactly with parallel projection; with perspective from afar, nearly): the outline of the
    body's projection along ``a`` is the same from both sides. A rigid offset between the heads
    moves one outline against the other: the translation across ``a`` (x and z for front and rear
    heads) and the rotation about ``a`` (about y) are measured, by a robust point-to-line ICP
    between the heads' outlines in the plane across ``a`` (each front outline point stands for
    the line through its `OUTLINE_LINE` nearest: on a scan's grid the outline is a staircase,
    and points paired with points would lock one head's grid onto the other's), truncated like
    `register_heads` to the motions whose standard error is below ``max_error``. The other three
    motions are not estimated: the translation along ``a`` moves one head's points along the
    view, which the data cannot tell from a thicker or thinner body, and so do the rotations
    about the axes across ``a``, but for a shift of the outline by its points' depth times the
    angle, smaller than the contours' own differences (perspective) or the outline's staircase.

    Parameters
    ----------
    points : (n, 3) float, metres
    head : (n,) int
        Head of each point; exactly two heads (0 and 1) are registered, otherwise nothing.
    view_dir : (n, 3) float
        Unit direction from each point toward its camera.
    spacing : float
        Median point spacing, metres (the outline's raster cell).
    iterations : int
        ICP steps at most.
    min_points : int
        Outline points of each head needed, at least.
    max_error : float
        A motion direction is estimated only when its standard error is below this, metres (a
        rotation's at 1 m), at the residuals' scale but at most a cell's (spacing / sqrt 12).

    Returns
    -------
    Registration
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree

    head = np.asarray(head).astype(np.int64)
    center = (points.min(axis=0) + points.max(axis=0)) / 2
    none = Registration(np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3)), center,
                        np.zeros(2, dtype=int), np.zeros(2, dtype=int))
    if len(head) == 0 or head.max() != 1 or np.ndim(view_dir) != 2:
        return none
    dirs = []
    for h in range(2):
        m = np.asarray(view_dir[head == h], dtype=np.float64).sum(axis=0)
        if (head == h).sum() < min_points:
            return none
        dirs.append(m / np.linalg.norm(m))
    a = dirs[0] - dirs[1]
    if np.linalg.norm(a) < 1.8:   # not facing each other (the views within 50 degrees of opposite)
        return none
    a /= np.linalg.norm(a)
    up = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(up, a)
    u /= np.linalg.norm(u)
    basis = np.stack([u, np.cross(a, u)])          # (2, 3): across the view
    q = (points - center) @ basis.T                # (n, 2)
    # each head's outline: the boundary cells of its filled raster, and the points in them
    lo = q.min(axis=0) - 2.5 * spacing
    cell = np.floor((q - lo) / spacing).astype(np.int64)
    shape = tuple(cell.max(axis=0) + 3)
    outline = []
    for h in range(2):
        img = np.zeros(shape, dtype=bool)
        img[tuple(cell[head == h].T)] = True
        img = ndimage.binary_fill_holes(ndimage.binary_closing(img, iterations=2))
        edge = img & ~ndimage.binary_erosion(img)
        outline.append(np.flatnonzero((head == h) & edge[tuple(cell.T)]))
    if min(len(o) for o in outline) < min_points:
        return none
    ref = q[outline[0]]
    tree = cKDTree(ref)
    # the outline as lines through its points' neighbourhoods (not the points: on a scan's grid
    # the outline is a staircase, and point pairs would lock one head's grid onto the other's)
    _, nb = tree.query(ref, k=min(OUTLINE_LINE, len(ref)))
    mid = ref[nb].mean(axis=1)
    d = ref[nb] - mid[:, None]
    normal = np.linalg.eigh(np.swapaxes(d, 1, 2) @ d)[1][:, :, 0] @ basis   # (m, 3): across the outline
    p0 = points[outline[1]] - center
    # (3, 6): the motions estimated, as (rotation vector, translation): the turn about a and the
    # shifts across it; the rest moves the points mostly along the views (see above)
    motions = np.zeros((3, 6))
    motions[0, :3], motions[1, 3:], motions[2, 3:] = a, basis[0], basis[1]
    r_1, t_1 = np.eye(3), np.zeros(3)
    limit = 3 * spacing
    used = np.zeros((3, 0))
    for _ in range(iterations):
        p = p0 @ r_1.T + t_1
        dist, j = tree.query(p @ basis.T)
        ok = dist < limit
        if ok.sum() < min_points:
            return none
        p, n = p[ok], normal[j[ok]]
        res = np.einsum("ij,ij->i", p @ basis.T - mid[j[ok]], n @ basis.T)
        scale = robust_scale(res, floor=1e-5)
        J = np.column_stack([np.cross(p, n), n]) @ motions.T    # the rotation about a, the shifts across
        # standard errors at the residuals' scale, at most the outline's own resolution (a cell's
        # uniform spread): the residuals of a wrong start would hide the directions that correct them
        step, used = truncated_step(J, tukey_weights(res, scale), res, min(scale, spacing / np.sqrt(12)),
                                    max_error)
        step = motions.T @ step
        dr = rotvec(step[:3])
        r_1, t_1 = dr @ r_1, dr @ t_1 + step[3:]
        limit = max(4 * scale + spacing, 0.7 * limit)
        if np.abs(step).max() < 1e-7:
            break
    # head 1's correction about the centre, split symmetrically between the heads
    half = rotvec(_log_rotation(r_1) / 2)
    rot = np.stack([half.T, half])
    trans = np.stack([-t_1 / 2, t_1 / 2])
    pairs = np.array([len(outline[0]), int(ok.sum())])
    return Registration(rot, trans, center, pairs, np.full(2, used.shape[1]))
