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
  points (itself included), at most ``clamp`` robust scales; a point farther than the outlier
  threshold from that fit is rejected as well (outliers in the charts). On a noise-free cloud the
  scale is the fits' own error, a small fraction of a millimetre, so the points barely move.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Tukey biweight tuning constant, in robust scales (95 % efficiency for Gaussian residuals).
TUKEY = 4.685
#: Fewest neighbours of a fit, whatever its radius (6 coefficients and some to spare).
MIN_FIT = 10
#: Query points fitted at a time (memory only: about 2 kB per neighbour).
CHUNK = 20000


@dataclass(frozen=True, eq=False)
class LocalFit:
    """Robust quadratic fits around query points.

    Attributes
    ----------
    normal : (m, 3) float
        Unit normal of each local fit (the direction of least spread; sign arbitrary).
    residual : (m,) float
        Signed distance of the query point above its fitted surface along ``normal``, metres.
    """

    normal: np.ndarray
    residual: np.ndarray


def robust_scale(residual: np.ndarray, floor: float = 1e-6) -> float:
    """``1.4826 * median |residual|`` (the Gaussian sigma for Gaussian residuals), at least ``floor``."""
    if len(residual) == 0:
        return floor
    return max(1.4826 * float(np.median(np.abs(residual))), floor)


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
    if m == 0:
        return LocalFit(normal, resid)
    if distance is None or not np.isfinite(radius):
        base = np.ones((m, k))
    else:
        base = ((distance <= radius) | (np.arange(k) < min_points)).astype(np.float64)
    if scale is None:  # from the unweighted fits' residuals at the neighbours, over a sample
        sample = np.random.default_rng(0).choice(m, min(m, 5000), replace=False)
        A, z, beta, *_ = _frame(points[neighbours[sample]], query[sample], base[sample])
        scale = robust_scale((z - _predict(beta, A))[base[sample] > 0])
    def chunk(a):
        w0 = base[a:a + CHUNK]
        A, z, beta, aq, zq, normal[a:a + CHUNK] = _frame(points[neighbours[a:a + CHUNK]],
                                                         query[a:a + CHUNK], w0)
        for _ in range(iterations):
            u = (z - _predict(beta, A)) / (TUKEY * scale)
            w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0) * w0
            beta = _solve(A, z, w)
        resid[a:a + CHUNK] = zq - np.einsum("mp,mp->m", aq, beta)

    _map(chunk, range(0, m, CHUNK), workers)
    return LocalFit(normal, resid)


def _map(function, items, workers: int) -> list:
    """``[function(i) for i in items]``, in ``workers`` threads when more than one."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [function(i) for i in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(function, items))


def _frame(nb: np.ndarray, q: np.ndarray, w: np.ndarray):
    """Local frames of neighbourhoods ``nb`` (m, k, 3) with weights ``w`` (m, k) by weighted PCA;
    the quadratic's design [1, x, y, x^2, xy, y^2] at the neighbours (m, k, 6) and at the queries
    ``q`` (m, 6) in them, the heights, the weighted fit and the normals."""
    sw = w.sum(axis=1)[:, None]
    c = (nb * w[..., None]).sum(axis=1) / sw
    d = nb - c[:, None]
    _, vec = np.linalg.eigh(np.swapaxes(d * w[..., None], 1, 2) @ d)
    vec = np.ascontiguousarray(vec[:, :, ::-1])  # columns: major, minor, normal
    loc = d @ vec
    ql = (vec.transpose(0, 2, 1) @ (q - c)[..., None])[..., 0]
    # x, y in units of the neighbourhood's size, so that the damping of `_solve` is scale-free
    s = np.sqrt(((loc[..., :2] ** 2).sum(axis=2) * w).sum(axis=1) / sw[:, 0])
    s = np.where(s > 0, s, 1.0)
    A = _design(loc[..., 0] / s[:, None], loc[..., 1] / s[:, None])
    z = loc[..., 2]
    return A, z, _solve(A, z, w), _design(ql[:, 0] / s, ql[:, 1] / s), ql[:, 2], vec[:, :, 2]


def _design(x, y):
    out = np.empty(x.shape + (6,))
    out[..., 0] = 1.0
    out[..., 1] = x
    out[..., 2] = y
    np.multiply(x, x, out=out[..., 3])
    np.multiply(x, y, out=out[..., 4])
    np.multiply(y, y, out=out[..., 5])
    return out


def _predict(beta, A):
    """(m, k) heights of the quadratics ``beta`` (m, 6) at the neighbours (design (m, k, 6))."""
    return (A @ beta[..., None])[..., 0]


def _solve(A, z, w):
    """(m, 6) weighted least-squares quadratic coefficients from the design (m, k, 6), heights
    (m, k) and weights (m, k) (None: all 1), lightly damped: a neighbourhood along a line, a
    finger's edge, gets the flattest fit instead of a singular system."""
    aw = np.swapaxes(A if w is None else A * w[..., None], 1, 2)
    ata = aw @ A
    atz = (aw @ z[..., None])[..., 0]
    tr = np.trace(ata, axis1=1, axis2=2)[:, None, None]
    ata = ata + 1e-9 * tr * np.eye(6) + 1e-30 * np.eye(6)
    return np.linalg.solve(ata, atz[..., None])[..., 0]


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
        Threshold in robust scales of the leave-one-out residuals.
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
    d, nb = tree.query(points, k=k + 1, workers=workers)
    fit = local_fits(points, points, nb[:, 1:], workers=workers)
    scale = robust_scale(fit.residual)
    return (np.abs(fit.residual) > max(z * scale, floor * spacing)) & (d[:, 1] > isolation * spacing), scale


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
    """

    points: np.ndarray
    moved: np.ndarray
    rejected: np.ndarray
    scale: float


def denoise(points: np.ndarray, member: np.ndarray, spacing: float, neighbours: int = 40,
            clamp: float = 3.0, z: float = 5.0, floor: float = 1.0, isolation: float = 1.5,
            radius: float = 0.02, workers: int = 1) -> Denoised:
    """Move each point onto the robust surface fitted to its section's points near it.

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
    radius : float
        Points of each fit within this distance, metres, but at least `MIN_FIT` (see `local_fits`).
    clamp : float
        No point moves farther than this many robust scales.
    z, floor, isolation : float
        Outlier test, as in `reject_outliers` (the nearest point of the same section counts).
    workers : int
        Threads fitting sections at the same time (speed only).

    Returns
    -------
    Denoised
    """
    from scipy.spatial import cKDTree

    n = len(points)
    shift = np.zeros((n, 3))
    count = np.zeros(n)
    resid = np.zeros(n)
    alone = np.ones(n, dtype=bool)

    def section(j):
        idx = np.flatnonzero(member[:, j])
        k = int(min(neighbours, len(idx)))
        if k < 10:
            return None
        sub = points[idx]
        d, nb = cKDTree(sub).query(sub, k=k)
        return idx, d[:, 1] > isolation * spacing, local_fits(sub, sub, nb, distance=d, radius=radius)

    fits = []
    for done in _map(section, range(member.shape[1]), workers):
        if done is not None:
            idx, far, fit = done
            alone[idx] &= far
            fits.append((idx, fit))
    if not fits:
        return Denoised(points.copy(), np.zeros(n), np.zeros(n, dtype=bool), 0.0)
    scale = robust_scale(np.concatenate([f.residual for _, f in fits]))
    for idx, f in fits:
        r = np.clip(f.residual, -clamp * scale, clamp * scale)
        np.add.at(shift, idx, -r[:, None] * f.normal)
        np.add.at(count, idx, 1.0)
        np.maximum.at(resid, idx, np.abs(f.residual))
    shift /= np.maximum(count, 1.0)[:, None]
    rejected = (resid > max(z * scale, floor * spacing)) & alone
    shift[rejected] = 0.0
    moved = np.linalg.norm(shift, axis=1)
    return Denoised(points + shift, moved, rejected, scale)
