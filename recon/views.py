"""How the scanner's cameras saw a cloud: what lies in front of the surface a camera saw is air.

A camera records, per pixel, the first surface along its line of sight; everything between the
camera and that point is empty. `Views` holds one depth buffer per head from the points and
their view directions (parallel or perspective heads); the returned function says how far any
position lies in front of the seen surface of its pixel (`Views.air`), and how far beside the
silhouettes of every head (`Views.beside`), and whether it lies behind what every head saw
(`Views.behind`). Used by the closed surface (what a camera looked through or past is outside the
body, `recon.surface.closed`), by the posture fit's volume (what no camera looked through is
inside, `recon.posture.volume`) and its check of the fitted model against the scan
(`recon.posture.seen`).
"""

from __future__ import annotations

import numpy as np

from .geometry import perp

#: Percentile of a head's gaps between neighbouring points (in its image) that `Views.beside`'s
#: closing fills at least: a scan sampled more coarsely across than along its rows keeps no holes
#: in its silhouettes.
GAP_Q = 95.0


def _camera(points: np.ndarray, view_dir: np.ndarray, spacing: float):
    """How one head saw: ``(project, parallel)``, ``project(x) -> (uv (m, 2), depth (m,))`` its
    image coordinates in metres at the body and depth increasing toward the camera, ``parallel``
    whether its rays are parallel (else they meet in a centre); None when they do neither
    (within ``spacing``)."""
    a = view_dir.mean(axis=0)
    a /= np.linalg.norm(a)
    e1 = perp(a)
    e2 = np.cross(a, e1)
    if np.abs(view_dir - a).max() < 1e-6:        # parallel projection
        return (lambda x: (np.column_stack([x @ e1, x @ e2]), x @ a)), True
    # perspective: the centre nearest to every ray (p + t v)
    P = np.eye(3)[None] - view_dir[:, :, None] * view_dir[:, None, :]
    c = np.linalg.lstsq(P.sum(axis=0), np.einsum("nij,nj->i", P, points), rcond=None)[0]
    off = c - points
    if np.sqrt(max(float(np.mean(np.einsum("ni,nij,nj->n", off, P, off))), 0.0)) > spacing:
        return None
    dist = float(np.linalg.norm(off, axis=1).mean())

    def project(x):
        u = c - x
        ua = u @ a
        return dist * np.column_stack([u @ e1, u @ e2]) / ua[:, None], -np.linalg.norm(u, axis=1)
    return project, False


class Views:
    """The cameras' depth buffers of a cloud: per head, the depth (toward the camera) of the seen
    surface in each pixel of one ``spacing``, from the points and their view directions.

    Parameters
    ----------
    points : (n, 3) float
    view_dir : (n, 3) float
        Unit directions toward the camera that saw each point.
    head : (n,) int or None
        The head of each point (None: the points grouped by their view direction when fewer than
        16, else all from one camera).
    spacing : float
        Median point spacing, metres: the pixel.
    """

    def __init__(self, points: np.ndarray, view_dir: np.ndarray, head, spacing: float):
        from scipy.ndimage import maximum_filter

        if head is None:   # parallel heads by their direction, else one perspective camera
            _, head = np.unique(np.round(view_dir, 6), axis=0, return_inverse=True)
            head = head.ravel() if head.max() < 16 else np.zeros(len(points), dtype=np.int64)
        self.spacing = float(spacing)
        self.parallel = True   # every head's lines of sight parallel
        self.heads = []   # per head: project, origin (2,), shape, depth (raw), nearest of 3 x 3
        self._uv = []     # per head: its points' image coordinates (k, 2)
        for h in np.unique(head):
            sel = np.flatnonzero(head == h)
            camera = _camera(points[sel], view_dir[sel], spacing)
            if camera is None or len(sel) < 10:
                continue
            project, parallel = camera
            self.parallel &= parallel
            uv, depth = project(points[sel])
            o = uv.min(axis=0) - spacing
            ij = np.floor((uv - o) / spacing).astype(np.int64)
            shape = tuple(ij.max(axis=0) + 2)
            z = np.full(shape, -np.inf)
            np.maximum.at(z, (ij[:, 0], ij[:, 1]), depth)
            near = maximum_filter(z, size=3, mode="nearest")   # never in front of a neighbour
            self.heads.append((project, o, shape, z, near))
            self._uv.append(uv)
        self._nearest = [None] * len(self.heads)

    def project(self, at: np.ndarray) -> list:
        """Per head, its view of positions ``at`` (m, 3): image coordinates (m, 2) float, metres,
        and depth toward the camera (m,) float; `air` and `beside` take it as ``projected`` (the
        positions projected once for both)."""
        at = np.asarray(at, dtype=np.float64).reshape(-1, 3)
        return [head[0](at) for head in self.heads]

    def pixels(self, i: int, at: np.ndarray, projected=None):
        """Head ``i``'s view of positions ``at`` (m, 3): pixel (m, 2) int, depth toward the camera
        (m,), and (m,) bool inside its picture (``projected``: head ``i``'s `project` of ``at``)."""
        project, o, shape = self.heads[i][:3]
        xy, dx = project(np.asarray(at, dtype=np.float64).reshape(-1, 3)) if projected is None else projected
        k = np.floor((xy - o) / self.spacing).astype(np.int64)
        return k, dx, ((k >= 0) & (k < np.array(shape))).all(axis=1)

    def air(self, at: np.ndarray, projected=None) -> np.ndarray:
        """(m,) how far (metres) each position ``at`` (m, 3) lies in front of the surface its camera
        saw (its depth toward the camera beyond the nearest seen point of its pixel and the eight
        around it: a pixel finer than the scan's rows holds no point of its own); positive is air
        the camera looked through, -inf where no camera saw a point along that line or the eight
        around it (unknown; beside the silhouettes: `beside`). ``projected``: `project` of ``at``."""
        at = np.asarray(at, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(at), -np.inf)
        for i in range(len(self.heads)):
            a = self._ahead(i, at, None if projected is None else projected[i])
            out = np.maximum(out, np.where(np.isnan(a), -np.inf, a))
        return out

    def _ahead(self, i: int, at: np.ndarray, projected=None) -> np.ndarray:
        """(m,) how far (metres) each position ``at`` (m, 3) lies in front of the surface head ``i``
        saw (the nearest seen point of its pixel and the eight around it); NaN where that head saw
        nothing there or outside its picture. ``projected``: head ``i``'s `project` of ``at``."""
        near = self.heads[i][4]
        k, dx, ok = self.pixels(i, at, projected)
        a = np.full(len(at), np.nan)
        zk = near.take(k[ok, 0] * near.shape[1] + k[ok, 1])
        a[ok] = np.where(np.isfinite(zk), dx[ok] - zk, np.nan)
        return a

    def behind(self, at: np.ndarray) -> np.ndarray:
        """(m,) bool: whether each position ``at`` (m, 3) lies behind the surface every head whose
        picture holds it saw along its line of sight (the nearest seen point of its pixel and the
        eight around it), and at least two heads' pictures hold it: the volume between the views,
        which no camera looked through. False where such a head saw nothing there. A head whose
        picture (the extent of what it saw) does not reach the position has no say (a tower's
        upper head, the legs), and one head alone bounds a line on its own side only. With heads
        of parallel lines of sight (`parallel`) facing each other, it is the body's extent along
        each line. Perspective heads' lines diverge, and the space their shadows share beyond the
        body (below the soles, under a raised thigh) is behind both: there it is a loose bound."""
        at = np.asarray(at, dtype=np.float64).reshape(-1, 3)
        out, said = np.ones(len(at), dtype=bool), np.zeros(len(at), dtype=np.int64)
        for i, head in enumerate(self.heads):
            projected = head[0](at)     # once for both tests
            ok = self.pixels(i, at, projected)[2]
            out &= ~ok | (self._ahead(i, at, projected) <= 0)      # NaN (saw nothing) compares False
            said += ok
        return out & (said >= 2)

    #: Margin of `beside`'s images around the points, pixels.
    PAD = 4

    def beside(self, at: np.ndarray, close: float = 0.0, step=None, projected=None) -> np.ndarray:
        """(m,) how far (metres, in the picture) each position ``at`` (m, 3) lies beside the
        silhouettes of every head: per head, the distance from its image to the head's silhouette,
        the least over the heads (0 within a silhouette). A head's silhouette is the image of the
        points it saw, closed (a morphological closing by a disc of radius ``close``, metres: the
        gaps between neighbouring points filled, its outline kept; at least the head's ``GAP_Q``-th
        percentile gap between neighbouring points), in sub-pixels of ``step``
        metres (default a quarter pixel); positions more than ``PAD`` pixels beside the points
        are at least that far. ``projected``: `project` of ``at``."""
        from scipy.ndimage import distance_transform_edt

        at = np.asarray(at, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(at), np.inf)
        step = self.spacing / 4 if step is None else float(step)
        for i, head in enumerate(self.heads):
            if self._nearest[i] is None or self._nearest[i][0] != (close, step):
                uv = self._uv[i]
                o = uv.min(axis=0) - (self.PAD * self.spacing + close)
                ij = np.floor((uv - o) / step).astype(np.int64)
                shape = tuple(ij.max(axis=0) + int(np.ceil((self.PAD * self.spacing + close) / step)) + 1)
                occ = np.zeros(shape, dtype=bool)
                occ[ij[:, 0], ij[:, 1]] = True
                if close > 0:   # closing: dilate by close, then erode by close
                    r = close
                    if GAP_Q > 0 and len(uv) > 2:    # at least the head's own gaps between points
                        from scipy.spatial import cKDTree
                        r = max(r, float(np.percentile(cKDTree(uv).query(uv, 2)[0][:, 1], GAP_Q)))
                    occ = disc_closing(occ, r, step)
                self._nearest[i] = ((close, step), o, distance_transform_edt(~occ) * step)
            _, o, dist = self._nearest[i]
            xy = head[0](at)[0] if projected is None else projected[i][0]
            k = np.floor((xy - o) / step).astype(np.int64)
            inside = ((k >= 0) & (k < np.array(dist.shape))).all(axis=1)
            d = np.full(len(at), self.PAD * self.spacing)
            d[inside] = dist.take(k[inside, 0] * dist.shape[1] + k[inside, 1])
            out = np.minimum(out, d)
        return out


def disc_offsets(r: float, step: float):
    """The pixel offsets within a disc: (k,) int ``di`` and (k,) int ``dj`` with
    ``sqrt(di**2 + dj**2) * step <= r``, the test of a Euclidean distance transform in pixels of
    ``step`` (``r``, ``step`` in metres)."""
    n = int(np.floor(r / step)) + 1
    di, dj = np.mgrid[-n:n + 1, -n:n + 1]
    inside = np.sqrt((di * di + dj * dj).astype(np.float64)) * step <= r
    return di[inside], dj[inside]


def disc_dilation(image: np.ndarray, r: float, step: float) -> np.ndarray:
    """(a, b) bool: the pixels of ``image`` (a, b) bool within ``r`` of a True pixel (pixels of
    ``step``; ``r``, ``step`` in metres), as ``distance_transform_edt(~image) * step <= r``: the
    image shifted by every offset of the disc (`disc_offsets`), or-ed."""
    out = np.zeros_like(image, dtype=bool)
    a, b = image.shape
    for di, dj in zip(*disc_offsets(r, step)):
        if abs(di) < a and abs(dj) < b:
            out[max(di, 0):a + min(di, 0), max(dj, 0):b + min(dj, 0)] |= \
                image[max(-di, 0):a + min(-di, 0), max(-dj, 0):b + min(-dj, 0)]
    return out


def disc_closing(image: np.ndarray, r: float, step: float) -> np.ndarray:
    """(a, b) bool: the morphological closing of ``image`` (a, b) bool by a disc of radius ``r``
    (pixels of ``step``; metres), as ``distance_transform_edt(distance_transform_edt(~image) * step
    <= r) * step > r`` (the erosion, like the distance transform, sees no background beyond the
    image's border)."""
    dilated = disc_dilation(image, r, step)
    if dilated.all():   # no background to erode from
        from scipy.ndimage import distance_transform_edt

        return distance_transform_edt(dilated) * step > r
    return ~disc_dilation(~dilated, r, step)


def seen_air(points: np.ndarray, view_dir: np.ndarray, head, at: np.ndarray, spacing: float) -> np.ndarray:
    """(m,) how far (metres) each position ``at`` (m, 3) lies in front of the surface its camera
    saw: `Views.air` of the cloud (parameters as there)."""
    return Views(points, view_dir, head, spacing).air(at)
