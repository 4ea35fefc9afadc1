"""Robust local surface fits: outlier rejection and denoising of a range-scan cloud (beyond the paper).

The paper's clouds were noise-free and its mesh interpolates every point, so 1 mm of range noise
tilts its triangles and a stray point becomes a vertex in the air. Here the surface near each point
is a height field over its local tangent plane (the section's chart, locally): a quadratic
``z = a + b x + c y + d x^2 + e x y + f y^2`` fitted to the point's ``k`` nearest neighbours by
iteratively reweighted least squares (Tukey's biweight), with the scale taken from the data's own
residuals (``1.4826 * median |residual|`` over the cloud, the MAD). A quadratic, not a plane, so
that the curvature of a limb is not taken for noise (a plane over a 5 mm scan's neighbourhood
would flatten an arm by about a millimetre).

- `reject_outliers`: a point lying farther from the surface fitted to its neighbours (itself left
  out) than ``z`` robust scales, and than ``floor`` point spacings, is an outlier (a stray
  triangulation: the simulator and real scanners displace them along the camera ray).
- `denoise`: each point is moved along the fitted surface's normal onto the fit of its section's
  points (itself included), at most ``clamp`` robust scales (where the noise widened the fits, up
  to the outlier threshold); a point farther than the outlier threshold from that fit is rejected
  as well (outliers in the charts). On a noise-free cloud the scale is the fits' own error, a small
  fraction of a millimetre, so the points barely move (`recon.reconstruct` does not denoise a cloud
  that quiet: ``denoise_min_noise``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Tukey biweight tuning constant, in robust scales (95 % efficiency for Gaussian residuals).
TUKEY = 4.685
#: Fewest neighbours of a fit, whatever its radius (6 coefficients and some to spare).
MIN_FIT = 10
#: Query points fitted at a time, for 40 neighbours (speed only: a chunk's monomials, about
#: 120 bytes per neighbour, stay near the cache).
CHUNK = 2500
#: Queries whose unweighted fits give the residual scale, at most (a seeded sample).
SAMPLE = 5000
#: Neighbours (queries times k) at most whose first fits are all kept while the scale is taken
#: from them, six chunks (speed only: about 140 bytes each, 85 MB; more, and the sample is fitted
#: on its own, as well).
KEEP = 6 * CHUNK * 40
#: Shared fits (`denoise` with ``share``) averaged per point.
BLEND = 3
#: Points evaluated at a time by `LocalFit.at` (speed only: a chunk's gathered fits, about 650
#: bytes per point, are reused from one chunk to the next).
AT_CHUNK = 8192


@dataclass(frozen=True, eq=False)
class LocalFit:
    """Robust quadratic fits around query points.

    Attributes
    ----------
    normal : (m, 3) float
        Unit normal of each local fit (the direction of least spread; sign arbitrary).
    residual : (m,) float
        Signed distance of the query point above its fitted surface along ``normal``, metres.
    center, frame, size, beta : (m, 3), (m, 3, 3), (m,), (m, 6) float
        The fits themselves, for `at`: each patch's centre, frame (columns: along, across,
        ``normal``), size (the unit of x and y) and the quadratic's coefficients.
    """

    normal: np.ndarray
    residual: np.ndarray
    center: np.ndarray | None = None
    frame: np.ndarray | None = None
    size: np.ndarray | None = None
    beta: np.ndarray | None = None

    def at(self, points: np.ndarray, which: np.ndarray) -> "LocalFit":
        """The fits ``which`` (n, b) int evaluated at ``points`` (n, 3), averaged over each
        point's ``b`` fits (their normals oriented alike): normal and residual of each point."""
        normal, residual = np.empty((len(points), 3)), np.empty(len(points))
        for a in range(0, len(points), AT_CHUNK):
            s = slice(a, a + AT_CHUNK)
            normal[s], residual[s] = self._at(points[s], which[s])
        return LocalFit(normal, residual)

    def _at(self, points: np.ndarray, which: np.ndarray):
        """`at` on one chunk of points: (normal, residual)."""
        loc = np.einsum("nbdj,nbd->nbj", self.frame[which], points[:, None] - self.center[which])
        xy = loc[..., :2] / self.size[which][..., None]
        x, y = xy[..., 0], xy[..., 1]
        b = self.beta[which]
        height = b[..., 0] + x * (b[..., 1] + x * b[..., 3] + y * b[..., 4]) + y * (b[..., 2] + y * b[..., 5])
        r = loc[..., 2] - height
        nrm = self.normal[which]
        flip = np.where(np.einsum("nbd,nd->nb", nrm, nrm[:, 0]) < 0, -1.0, 1.0)
        normal = (nrm * flip[..., None]).sum(axis=1)
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        return normal, (r * flip).mean(axis=1)


def robust_scale(residual: np.ndarray, floor: float = 1e-6) -> float:
    """``1.4826 * median |residual|`` (the Gaussian sigma for Gaussian residuals), at least ``floor``."""
    if len(residual) == 0:
        return floor
    return max(1.4826 * float(np.median(np.abs(residual))), floor)


def tukey_weights(residual: np.ndarray, scale: float) -> np.ndarray:
    """Tukey's biweight of each residual at ``scale``: ``(1 - u^2)^2`` with ``u`` the residual in
    `TUKEY` scales, 0 beyond (an outlier has no say)."""
    u = residual / (TUKEY * scale)
    inside = np.abs(u) < 1
    u *= u
    np.subtract(1.0, u, out=u)
    u *= u
    u[~inside] = 0.0
    return u


def local_fits(points: np.ndarray, query: np.ndarray, neighbours: np.ndarray, scale: float | None = None,
               iterations: int = 2, distance: np.ndarray | None = None, radius: float = np.inf,
               min_points: int = MIN_FIT, workers: int = 1) -> LocalFit:
    """Fit a robust quadratic height field to each query point's neighbours.

    Parameters
    ----------
    points : (n, 3) float, metres
    query : (m, 3) float
        Where each fit is evaluated (the point itself, in or out of its neighbours).
    neighbours : (m, k) int
        Indices into ``points`` of each query's neighbours, nearest first (k >= 6).
    scale : float, optional
        Residual scale for the biweight, metres; default: the MAD of the first, unweighted fits'
        residuals over a sample of the queries.
    iterations : int
        Reweighting rounds after the first, unweighted fit.
    distance : (m, k) float, optional
        Distances of the neighbours; with ``radius``, the neighbours farther than ``radius`` are
        left out, except the ``min_points`` nearest (a quadratic over a wide patch would take a
        limb's curvature for noise).
    workers : int
        Threads fitting chunks of the queries at the same time (speed only; numpy releases the GIL).

    Returns
    -------
    LocalFit
    """
    m, k = neighbours.shape
    normal = np.zeros((m, 3))
    resid = np.zeros(m)
    center, frame, size, coef = np.zeros((m, 3)), np.zeros((m, 3, 3)), np.ones(m), np.zeros((m, 6))
    if m == 0:
        return LocalFit(normal, resid, center, frame, size, coef)
    if distance is None or not np.isfinite(radius):
        base = np.ones((m, k))
    else:
        base = ((distance <= radius) | (np.arange(k) < min_points)).astype(np.float64)
    step = max(1, CHUNK * 40 // k)  # queries per chunk: about as much memory whatever k

    def first(a):  # a chunk's frames and unweighted fits
        f = _Patch(points[neighbours[a:a + step]], query[a:a + step], base[a:a + step])
        return f, f.fit(f.w0)

    starts = range(0, m, step)
    made = [None] * len(starts)
    if scale is None:  # from the unweighted fits' residuals at the neighbours, over a sample
        sample = _sample(m)
        if m * k <= KEEP:  # every chunk's first fits, kept: the fits go on from them
            made = _map(first, starts, workers)
            res = []
            for a, (f, beta) in zip(starts, made):
                rows = sample[(sample >= a) & (sample < a + step)] - a
                res.append((f.z[rows] - f.predict(beta[rows], rows))[base[a + rows] > 0])
            res = np.concatenate(res)
        else:  # the sample's own
            sub = _Patch(points[neighbours[sample]], query[sample], base[sample])
            res = (sub.z - sub.predict(sub.fit(sub.w0)))[base[sample] > 0]
        scale = robust_scale(res)

    def chunk(i):
        a = starts[i]
        f, beta = made[i] if made[i] is not None else first(a)
        made[i] = None  # the chunk's memory goes once fitted
        for _ in range(iterations):
            beta = f.fit(tukey_weights(f.z - f.predict(beta), scale) * f.w0)
        normal[a:a + step] = f.normal
        resid[a:a + step] = f.zq - np.einsum("mp,mp->m", f.aq, beta)
        center[a:a + step], frame[a:a + step], size[a:a + step] = f.center, f.frame, f.size
        coef[a:a + step] = beta

    _map(chunk, range(len(starts)), workers)
    return LocalFit(normal, resid, center, frame, size, coef)


def _sample(m: int, size: int = SAMPLE) -> np.ndarray:
    """Sorted seeded sample of at most ``size`` of ``m`` indices (all when fewer)."""
    if m <= size:
        return np.arange(m)
    return np.sort(np.random.default_rng(0).choice(m, size, replace=False))


def _map(function, items, workers: int) -> list:
    """``[function(i) for i in items]``, in ``workers`` threads when more than one."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [function(i) for i in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(function, items))


#: Exponents (a, b) of the monomials x^a y^b of the quadratic's design [1, x, y, x^2, xy, y^2]
#: first, then the rest of degree <= 4: the products of two design terms.
_EXPONENTS = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2),
              (3, 0), (2, 1), (1, 2), (0, 3), (4, 0), (3, 1), (2, 2), (1, 3), (0, 4)]
#: Column of `_EXPONENTS` of the product of design terms i and j (the normal matrix's entry).
_PRODUCT = np.array([[_EXPONENTS.index((a + c, b + d)) for (c, d) in _EXPONENTS[:6]]
                     for (a, b) in _EXPONENTS[:6]])


class _Patch:
    """Neighbourhoods ``nb`` (m, k, 3) of queries ``q`` (m, 3) with base weights ``w0`` (m, k), in
    their local frames (weighted PCA: x, y along the patch, z along the normal), with the
    monomials of degree <= 4 of x, y at the neighbours, so that each weighted least-squares fit
    of the quadratic is one weighted sum per monomial and a 6 x 6 solve."""

    def __init__(self, nb: np.ndarray, q: np.ndarray, w0: np.ndarray):
        sw = w0.sum(axis=1)[:, None]
        c = np.einsum("mk,mkd->md", w0, nb) / sw
        d = nb - c[:, None]
        _, vec = np.linalg.eigh(np.swapaxes(d * w0[..., None], 1, 2) @ d)
        vec = vec[:, :, ::-1]  # columns: major, minor, normal
        loc = d @ vec
        ql = np.einsum("mdj,md->mj", vec, q - c)
        # x, y in units of the neighbourhood's size, so that the damping of `fit` is scale-free
        x, y = loc[..., 0], loc[..., 1]
        s = np.sqrt(np.einsum("mk,mk->m", x * x + y * y, w0) / sw[:, 0])
        s = np.where(s > 0, s, 1.0)
        self.mono = _monomials(x / s[:, None], y / s[:, None])  # (m, 15, k)
        self.z = np.ascontiguousarray(loc[..., 2])
        self.w0 = w0
        self.aq = np.ascontiguousarray(_monomials(ql[:, 0, None] / s[:, None], ql[:, 1, None] / s[:, None])[:, :6, 0])
        self.zq = ql[:, 2]
        self.normal = np.ascontiguousarray(vec[:, :, 2])
        self.center, self.frame, self.size = c, vec, s

    def fit(self, w: np.ndarray) -> np.ndarray:
        """(m, 6) weighted least-squares quadratic coefficients for weights ``w`` (m, k), lightly
        damped: a neighbourhood along a line, a finger's edge, gets the flattest fit instead of
        a singular system."""
        moments = (self.mono @ w[..., None])[..., 0]
        ata = moments[:, _PRODUCT]
        atz = (self.mono[:, :6] @ (w * self.z)[..., None])[..., 0]
        diagonal = np.einsum("mii->mi", ata)  # a view: damped in place
        diagonal += 1e-9 * diagonal.sum(axis=1)[:, None]
        diagonal += 1e-30
        return np.linalg.solve(ata, atz[..., None])[..., 0]

    def predict(self, beta: np.ndarray, rows=None) -> np.ndarray:
        """(m, k) heights of the quadratics ``beta`` (m, 6) at the neighbours (of the patches
        ``rows`` alone, when given, with ``beta`` their fits)."""
        mono = self.mono[:, :6] if rows is None else self.mono[rows, :6]
        return (beta[:, None, :] @ mono)[:, 0]


def _monomials(x, y):
    """(m, 15, k): x^a y^b of ``x``, ``y`` (m, k) for the exponents of `_EXPONENTS` (a view of a
    (15, m, k) array: each monomial one contiguous product)."""
    out = np.empty((len(_EXPONENTS),) + np.shape(x))
    out[0] = 1.0
    out[1] = x
    out[2] = y
    for i, (a, b) in enumerate(_EXPONENTS[3:], start=3):   # each one more factor x or y than an earlier one
        j, f = (_EXPONENTS.index((a - 1, b)), x) if a else (_EXPONENTS.index((a, b - 1)), y)
        np.multiply(out[j], f, out=out[i])
    return out.transpose(1, 0, 2)


def reject_outliers(points: np.ndarray, spacing: float, neighbours: int = 16, z: float = 5.0,
                    floor: float = 1.0, isolation: float = 1.5, tree=None,
                    workers: int = 1) -> tuple[np.ndarray, float]:
    """Points off the surface their neighbours make, and alone (stray triangulations).

    Parameters
    ----------
    points : (n, 3) float, metres
    spacing : float
        Median point spacing, metres.
    neighbours : int
        Neighbours of each fit (the point itself left out).
    z : float
        Threshold in robust scales of the leave-one-out residuals (the scale: over a seeded
        sample of 2 x `SAMPLE` points; only the isolated points are tested).
    floor : float
        Threshold at least this many spacings (a noise-free cloud's fits are nearly exact: without
        a floor its fingers and silhouettes would go).
    isolation : float
        An outlier also has no other point within this many spacings (a fingertip, an ear or a
        silhouette, where a fit of the neighbours is poor, has one within about a spacing; a point
        thrown off the surface is alone).
    tree : scipy.spatial.cKDTree, optional
        Of ``points``.
    workers : int
        Threads (speed only).

    Returns
    -------
    outlier : (n,) bool
    scale : float
        The robust scale of the residuals, metres (about the range noise's sigma).
    """
    from scipy.spatial import cKDTree

    n = len(points)
    k = int(min(neighbours, n - 1))
    if k < 6:
        return np.zeros(n, dtype=bool), 0.0
    tree = cKDTree(points) if tree is None else tree
    # only isolated points can be outliers: fit those, and a sample of all for the scale
    alone = _isolated(tree, points, isolation * spacing, workers)
    sample = np.zeros(n, dtype=bool)
    sample[_sample(n, 2 * SAMPLE)] = True
    rows = np.flatnonzero(alone | sample)
    nb = tree.query(points[rows], k=k + 1, workers=workers)[1][:, 1:]
    fit = local_fits(points, points[rows], nb, workers=workers)
    scale = robust_scale(fit.residual[sample[rows]])
    outlier = np.zeros(n, dtype=bool)
    outlier[rows] = (np.abs(fit.residual) > max(z * scale, floor * spacing)) & alone[rows]
    return outlier, scale


def _isolated(tree, points: np.ndarray, gap: float, workers: int = 1) -> np.ndarray:
    """(n,) bool: whether each of ``points`` (n, 3), all of them in the cKDTree ``tree``, has no
    other point of the tree within ``gap`` (the search bounded just beyond it: speed only)."""
    bound = gap * (1 + 1e-6) if gap > 0 else np.inf
    return tree.query(points, k=2, distance_upper_bound=bound, workers=workers)[0][:, 1] > gap


def _thin(points: np.ndarray, cube: float) -> np.ndarray:
    """Sorted indices of one point (the first) per occupied cube of edge ``cube`` (points (n, 3))."""
    cell = np.floor((points - points.min(axis=0)) / cube).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    return np.sort(np.unique(key, return_index=True)[1])


@dataclass(frozen=True, eq=False)
class Denoised:
    """Points moved onto their sections' robust surfaces.

    Attributes
    ----------
    points : (n, 3) float
        The moved points, metres (points in no section, or rejected, are not moved).
    moved : (n,) float
        How far each point moved, metres.
    rejected : (n,) bool
        Points farther from their section's fit than the outlier threshold (not meshed).
    scale : float
        Robust scale of the residuals, metres.
    widened : bool
        The noise widened some section's fits (see `denoise`'s ``error``).
    """

    points: np.ndarray
    moved: np.ndarray
    rejected: np.ndarray
    scale: float
    widened: bool = False


def fit_size(noise: float, spacing: float, error: float, neighbours: int, radius: float) -> int:
    """Points of a denoising fit: enough that the fitted quadratic's own error, about
    ``noise * sqrt(6 / k)`` (six coefficients from ``k`` noisy points), is at most ``error``
    point spacings (``k = 6 (noise / (error * spacing))^2``), at least ``neighbours``, and at most
    the points of one surface within ``radius`` (``pi (radius / spacing)^2``; a wider fit would
    take a limb's curvature for noise). ``error=0``: ``neighbours``."""
    k = int(neighbours)
    if error > 0 and spacing > 0 and noise > 0:
        cap = int(np.ceil(np.pi * (radius / spacing) ** 2)) if np.isfinite(radius) else 10 ** 9
        k = max(k, min(int(np.ceil(6.0 * (noise / (error * spacing)) ** 2)), cap))
    return k


def denoise(points: np.ndarray, member: np.ndarray, spacing: float, neighbours: int = 40,
            clamp: float = 3.0, z: float = 5.0, floor: float = 1.0, isolation: float = 1.5,
            radius: float = 0.02, workers: int = 1, share: float = 3.0, error: float = 0.0,
            reach: float = 0.012, passes: int = 1) -> Denoised:
    """Move each point onto the robust surface fitted to its section's points near it; where the
    noise widened the fits, up to ``passes`` times onto the surfaces fitted again to the moved
    points (a moving least squares projection, iterated: each pass takes out part of the noise
    the last fits kept; a noise-free or coarse scan is projected once). Outliers are those of the
    first pass, which also gives the scale.

    Parameters
    ----------
    points : (n, 3) float, metres
    member : (n, s) bool
        Section memberships; each section is fitted on its own points, so that an arm against
        the chest is not blended with it. A point in two sections (a seam) moves by the mean
        of its two fits.
    spacing : float
        Median point spacing, metres.
    neighbours : int
        Points of each fit at most (the point itself included).
    radius : float or (s,) float
        Points of each fit within this distance, metres, but at least `MIN_FIT` (see `local_fits`);
        for all sections or per section.
    clamp : float
        No point moves farther than this many robust scales, in the sections whose fits keep
        ``neighbours`` points: their residuals are the fits' own error as much as noise (on a
        noise-free cloud, all of it). Where the noise widened the fits, the residuals are the
        noise, and a point within the outlier threshold ``z`` moves onto its fit: the scale is
        a median over all view angles, below the noise where the surface faces the camera, so
        ``clamp`` would leave a few per cent of those points standing off it.
    z, floor, isolation : float
        Outlier test, as in `reject_outliers` (the nearest point of the same section counts).
    workers : int
        Threads fitting sections at the same time (speed only).
    share : float
        Fit only at one point per cube of this many spacings, times ``sqrt(k / neighbours)`` for
        fits widened to ``k`` points (at most ``radius / 2``; 0: at
        every point); every point is then moved by the mean of its `BLEND` nearest fits (a fit
        spans ``neighbours`` points, a cube a few: the fits overlap, and their mean is smoother
        than one fit per point). Isolated points (see ``isolation``) get a fit of their own.
    error : float
        The fits' own error, in point spacings: each section's fits take `fit_size` points, from
        the noise measured on its first fits of ``neighbours`` points (leave-one-out residuals
        over a sample); a noisy fine scan gets wider fits, a noise-free one keeps ``neighbours``
        (0: always ``neighbours``).
    reach : float
        Widened fits take their points within this distance, metres (and at most as many as a
        surface holds there): widening trades the noise for the quadratic's error on a curved
        limb or a hand, which grows fast with the fit's size.
    passes : int
        Projections at most (at least 1), where the noise widened the fits. The later ones fit
        the same neighbourhoods (the moved points hardly change them, and finding them is more
        than half of a pass); the first pass's outliers stay where they are, and have no say in
        the later fits beyond a fit's `MIN_FIT` nearest points.

    Returns
    -------
    Denoised
    """
    if int(passes) < 1:
        raise ValueError(f"passes must be at least 1, got {passes}")
    radii = np.broadcast_to(np.asarray(radius, dtype=float), member.shape[1:])
    plans = [p for p in _map(lambda j: _plan(points, np.flatnonzero(member[:, j]), spacing, neighbours,
                                             isolation, float(radii[j]), share, error, reach),
                             range(member.shape[1]), workers) if p is not None]
    out = _project(points, plans, spacing, clamp, z, floor, workers)
    for _ in range(int(passes) - 1 if out.widened else 0):
        again = _project(out.points, plans, spacing, clamp, z, floor, workers, out.rejected)
        moved = np.where(out.rejected[:, None], out.points, again.points)
        out = Denoised(moved, np.linalg.norm(moved - points, axis=1), out.rejected, out.scale, True)
    return out


@dataclass(frozen=True, eq=False)
class _Plan:
    """Where one section's fits are made: its points ``idx`` (p,), those alone ``far`` (p,)
    bool, the fits' centres (c,) and neighbours ``nb``, ``distance`` (c, k) (indices into
    ``idx``), their ``radius``, each point's fits to blend ``near`` (p, b), and whether the noise
    widened them."""

    idx: np.ndarray
    far: np.ndarray
    centres: np.ndarray
    nb: np.ndarray
    distance: np.ndarray
    radius: float
    near: np.ndarray
    widened: bool


def _plan(points, idx, spacing, neighbours, isolation, radius, share, error, reach) -> _Plan | None:
    """The neighbourhoods of `denoise`'s fits over the section ``idx`` of ``points`` (None when
    it has too few points)."""
    from scipy.spatial import cKDTree

    k = int(min(neighbours, len(idx)))
    if k < 10:
        return None
    sub = points[idx]
    tree = cKDTree(sub)
    rad = radius
    if error > 0 and len(idx) > k:  # the section's noise, from leave-one-out fits of k points
        pilot = _sample(len(sub), SAMPLE // 5)
        d, nb = tree.query(sub[pilot], k=k + 1)
        fit = local_fits(sub, sub[pilot], nb[:, 1:], distance=d[:, 1:], radius=radius)
        k = min(fit_size(robust_scale(fit.residual), spacing, error, k, min(radius, reach)), len(idx))
        rad = radius if k <= neighbours else min(radius, reach)
    if share <= 0:  # a fit at every point
        d, nb = tree.query(sub, k=k)
        return _Plan(idx, d[:, 1] > isolation * spacing, np.arange(len(idx)), nb, d, rad,
                     np.arange(len(idx))[:, None], k > neighbours)
    far = _isolated(tree, sub, isolation * spacing)
    # a fit centred on each isolated point (it is tested as an outlier on its own fit)
    # widened fits are shared over wider cubes: as many fits overlap each point whatever k
    thin = _thin(sub, min(share * spacing * np.sqrt(max(k / neighbours, 1.0)), radius / 2))
    centres = np.concatenate([thin[~far[thin]], np.flatnonzero(far)])
    d, nb = tree.query(sub[centres], k=k)
    near = cKDTree(sub[centres]).query(sub, k=min(BLEND, len(centres)))[1].reshape(len(sub), -1)
    near[far] = np.arange(len(centres) - far.sum(), len(centres))[:, None]
    return _Plan(idx, far, centres, nb, d, rad, near, k > neighbours)


def _project(points, plans, spacing, clamp, z, floor, workers, left_out=None) -> Denoised:
    """One pass of `denoise`: the sections' fits made as ``plans`` say, over ``points`` (the
    points ``left_out`` (n,) bool, if given, count as beyond the fits' radius)."""
    n = len(points)
    shift = np.zeros((n, 3))
    count = np.zeros(n)
    resid = np.zeros(n)
    alone = np.ones(n, dtype=bool)

    def section(p):
        sub = points[p.idx]
        d = p.distance if left_out is None else np.where(left_out[p.idx][p.nb], np.inf, p.distance)
        return local_fits(sub, sub[p.centres], p.nb, distance=d, radius=p.radius).at(sub, p.near)

    fits, widened = [], False
    for p, fit in zip(plans, _map(section, plans, workers)):
        alone[p.idx] &= p.far
        widened |= p.widened
        fits.append((p.idx, fit, max(clamp, z) if p.widened else clamp))
    if not fits:
        return Denoised(points.copy(), np.zeros(n), np.zeros(n, dtype=bool), 0.0)
    scale = robust_scale(np.concatenate([f.residual for _, f, _ in fits]))
    for idx, f, c in fits:
        r = np.clip(f.residual, -c * scale, c * scale)
        np.add.at(shift, idx, -r[:, None] * f.normal)
        np.add.at(count, idx, 1.0)
        np.maximum.at(resid, idx, np.abs(f.residual))
    shift /= np.maximum(count, 1.0)[:, None]
    rejected = (resid > max(z * scale, floor * spacing)) & alone
    shift[rejected] = 0.0
    moved = np.linalg.norm(shift, axis=1)
    return Denoised(points + shift, moved, rejected, scale, widened)
