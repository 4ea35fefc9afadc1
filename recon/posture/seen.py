"""The fitted model against the scan, as the cameras saw it (step 7 of `recon.posture.fit`).

A camera records, per pixel, the first surface along its line of sight. The fitted model, drawn
from the same camera (`recon.views.Views`: the heads' projections and depth buffers, read from the
points and their view directions only), predicts what that camera saw: where a section's surface is
the model's front-most, the scan should hold a point at the same depth. A section placed right
agrees there (its points are where the camera would have seen them); one placed wrongly does not:
the camera saw through where the model puts it (the scan's surface lies behind it), or saw another
surface in front of it where the model has none, or saw its surface at another depth. Pixels the
camera saw nothing in (laser shadow, unseen sides) say nothing and are left out.

`agreement` gives, per section, the surface it shows the cameras and how much of it the scan
confirms; `confirmed_parts`, the trunk's and the limbs'; `confirmed_fraction`, the lesser of the
two (the fit's check, `fit_min_agreement`).
"""

from __future__ import annotations

import numpy as np

from ..views import Views

#: the eight neighbours of a pixel and itself
_NEIGHBOURS = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)])


def scan_views(points: np.ndarray, view_dir: np.ndarray, head=None, min_pixel: float = 0.0) -> Views:
    """The cameras' depth buffers of a cloud (`recon.views.Views`), with pixels of its median point
    spacing (nearest neighbours over a sample of at most 2,000 points), at least ``min_pixel``.

    Parameters
    ----------
    points : (n, 3) float
    view_dir : (n, 3) float
        Unit directions toward the camera that saw each point.
    head : (n,) int, optional
        The head of each point (needed for perspective heads; parallel heads are told apart by
        their view direction).
    """
    from scipy.spatial import cKDTree

    sample = points[:: max(1, len(points) // 2000)]
    d, _ = cKDTree(points).query(sample, k=2)
    return Views(points, view_dir, head, max(float(np.median(d[:, 1])), min_pixel))


def _surface(sec, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(m, 3) samples of a section's surface about one ``spacing`` apart, and (m, 3) their outward
    normals (the gradient of the section's scaled distance)."""
    n_theta = int(np.clip(np.ceil(2 * np.pi * sec.radii.max() / spacing), 8, 96))
    n_h = int(np.clip(np.ceil(sec.length / spacing) + 1, 4, 96))
    p = sec.surface_points(n_theta, n_h)
    x, y, h, e, _ = sec._scaled(p)
    a, b = sec.radii
    c = np.where(h < 0, sec.caps[0], sec.caps[1])
    ez = np.divide(e, np.square(c), out=np.zeros_like(e), where=(e != 0) & (c > 0))
    g = np.column_stack([x / a ** 2, y / b ** 2, ez]) @ sec.frame
    return p, g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def agreement(secs: dict, views: Views, tolerance: float) -> dict:
    """Per section, how much of its surface the cameras would see and how much of it they saw.

    Each head draws every section's surface (samples one pixel apart) into a depth buffer of its own
    pixels; a sample is shown when it is its pixel's front-most (within one pixel) and faces the
    camera. A shown sample is confirmed when the scan holds a point within ``tolerance`` of its
    depth in its pixel or the eight around, and counts only when the scan holds a point there at
    all (no point: laser shadow, or a side no camera saw).

    Parameters
    ----------
    secs : dict
        {name: SectionShape}, the fitted model.
    views : Views
        The scan's depth buffers (`scan_views`).
    tolerance : float
        Metres.

    Returns
    -------
    dict
        {name: (shown, confirmed)}: samples shown where the scan holds points, and those confirmed.
    """
    names = list(secs)
    surf = [_surface(secs[n], views.spacing) for n in names]
    P = np.concatenate([p for p, _ in surf])
    N = np.concatenate([g for _, g in surf])
    owner = np.repeat(np.arange(len(names)), [len(p) for p, _ in surf])
    shown = np.zeros(len(names), dtype=np.int64)
    confirmed = np.zeros(len(names), dtype=np.int64)
    for i, (_, _, shape, z, _) in enumerate(views.heads):
        k, dx, ok = views.pixels(i, P)
        # facing the camera: depth grows toward it, so a step along the normal raises the depth
        _, dn, _ = views.pixels(i, P + 1e-3 * N)
        front = ok & (dn > dx)
        model = np.full(shape, -np.inf)
        np.maximum.at(model, (k[front, 0], k[front, 1]), dx[front])
        vis = np.flatnonzero(front)
        vis = vis[dx[vis] >= model[k[vis, 0], k[vis, 1]] - views.spacing]
        kk = k[vis, None, :] + _NEIGHBOURS[None]
        inside = ((kk >= 0) & (kk < np.array(shape))).all(axis=2)
        kk = np.where(inside[..., None], kk, 0)
        zs = np.where(inside, z[kk[..., 0], kk[..., 1]], -np.inf)          # (v, 9) the scan's depths
        seen = np.isfinite(zs).any(axis=1)
        match = (np.abs(zs - dx[vis, None]) < tolerance).any(axis=1)
        shown += np.bincount(owner[vis[seen]], minlength=len(names))
        confirmed += np.bincount(owner[vis[seen & match]], minlength=len(names))
    return {n: (int(shown[j]), int(confirmed[j])) for j, n in enumerate(names)}


#: The trunk's sections; the check judges them apart from the limbs (`confirmed_parts`).
TRUNK = ("waist", "chest", "head")


def confirmed_parts(secs: dict, views: Views, tolerance: float) -> dict:
    """Of the surface the model ``secs`` shows the cameras where the scan holds points, the fraction
    the scan confirms (`agreement`, summed over the sections), for the trunk (`TRUNK`) and for the
    limbs apart: {"trunk": float, "limbs": float}, 1 for a part that shows none."""
    ag = agreement(secs, views, tolerance)
    out = {}
    for part, trunk in (("trunk", True), ("limbs", False)):
        a = np.array([v for n, v in ag.items() if (n in TRUNK) == trunk]).reshape(-1, 2).sum(axis=0)
        out[part] = float(a[1] / a[0]) if a[0] else 1.0
    return out


def confirmed_fraction(secs: dict, views: Views, tolerance: float) -> float:
    """The lesser of the trunk's and the limbs' confirmed fractions (`confirmed_parts`).

    The torso places the whole model (the limbs hang from it), so a trunk the cameras contradict
    means the posture was not found however well the limbs agree; summed over all sections, the
    limbs' agreement hid it (tune62, paper 10 mm: fits with the torso 11-24 cm off passed at 0.74
    to 0.78 of the whole model's surface confirmed)."""
    return min(confirmed_parts(secs, views, tolerance).values())

