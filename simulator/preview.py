"""A picture of a scan: the cloud from the front, the side and the back, over the body's silhouette."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .raycast import RayCaster

#: Views: (title, horizontal axis, sign of horizontal axis, depth axis toward the viewer sign).
VIEWS = (
    ("front (from -y)", 0, 1.0, 1, -1.0),
    ("left side (from +x)", 1, 1.0, 0, 1.0),
    ("back (from +y)", 0, -1.0, 1, 1.0),
)

#: Pixels along the longer side of each view.
PIXELS = 900


def _view_image(caster, vertices, points, head, rgb, spacing, view):
    """One view as an RGB image: grey silhouette, then each pixel coloured by its nearest point.

    Returns the (rows, cols, 3) float image and its imshow extent (metres).
    """
    _, h_axis, h_sign, d_axis, d_sign = view
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    pad = 0.02 * float(np.ptp(vertices[:, 2]))
    h0, h1 = sorted((h_sign * lo[h_axis], h_sign * hi[h_axis]))
    h0, h1, z0, z1 = h0 - pad, h1 + pad, lo[2] - pad, hi[2] + pad
    step = max(h1 - h0, z1 - z0) / PIXELS
    cols, rows = int(np.ceil((h1 - h0) / step)), int(np.ceil((z1 - z0) / step))
    # silhouette: parallel rays along the viewing direction
    hh, zz = np.meshgrid(h0 + (np.arange(cols) + 0.5) * step, z0 + (np.arange(rows) + 0.5) * step)
    origins = np.empty((hh.size, 3))
    origins[:, h_axis] = h_sign * hh.ravel()
    origins[:, 2] = zz.ravel()
    origins[:, d_axis] = (hi if d_sign > 0 else lo)[d_axis] + d_sign * (pad + 0.1)
    direction = np.zeros((1, 3))
    direction[0, d_axis] = -d_sign
    face, _ = caster.first_hit(origins, direction)
    image = np.where((face >= 0)[:, None], 0.82, 1.0) * np.ones(3)
    # points: square dots about half the sample spacing wide; the nearest point wins each pixel
    c = np.floor((h_sign * points[:, h_axis] - h0) / step).astype(np.int64)
    r = np.floor((points[:, 2] - z0) / step).astype(np.int64)
    near = d_sign * points[:, d_axis]
    half = int(round(0.25 * spacing / step))
    offsets = [(dr, dc) for dr in range(-half, half + 1) for dc in range(-half, half + 1)]
    rr = np.concatenate([r + dr for dr, _ in offsets])
    cc = np.concatenate([c + dc for _, dc in offsets])
    idx = np.tile(np.arange(len(points)), len(offsets))
    ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    pixel, idx = rr[ok] * cols + cc[ok], idx[ok]
    order = np.lexsort((-near[idx], pixel))             # by pixel, nearest first
    pixel, idx = pixel[order], idx[order]
    first = np.ones(len(pixel), bool)
    first[1:] = pixel[1:] != pixel[:-1]
    image[pixel[first]] = rgb[head[idx[first]] % len(rgb)]
    return image.reshape(rows, cols, 3), (h0, h0 + cols * step, z0, z0 + rows * step)


def save_preview(scan, body, path: str | os.PathLike, *, title: str | None = None) -> Path:
    """Draw ``scan`` over the silhouette of ``body`` and save it as an image.

    Each pixel of a view shows the point nearest to the viewer, so a hole in the near side shows
    the far head's colour, or the grey silhouette when nothing was measured there at all.

    Parameters
    ----------
    scan : Scan
    body : poses.Body
        The scanned body (its triangles give the grey silhouette).
    path : str or path
        Image file (.png, .pdf, .svg: anything matplotlib writes).
    title : str, optional

    Returns
    -------
    path : Path
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    names = scan.meta.get("heads") or [str(i) for i in range(int(scan.head.max()) + 1 if len(scan) else 0)]
    colors = plt.get_cmap("tab10")
    rgb = np.array([colors(i)[:3] for i in range(10)])
    cfg = scan.meta.get("config", {})
    caster = RayCaster(body.vertices, body.faces)
    fig, axes = plt.subplots(1, len(VIEWS), figsize=(4.2 * len(VIEWS), 7.5), constrained_layout=True)
    for ax, view in zip(axes, VIEWS):
        image, extent = _view_image(caster, body.vertices, scan.points, scan.head, rgb,
                                    cfg.get("resolution", 0.01), view)
        ax.imshow(image, extent=extent, origin="lower", interpolation="nearest")
        label, h_axis, h_sign = view[:3]
        ax.set_title(label, fontsize=10)
        ax.set_xlabel(("-" if h_sign < 0 else "") + "xyz"[h_axis] + " (m)")
        ax.set_ylabel("z (m)")
    handles = [plt.Line2D([], [], ls="", marker="o", color=colors(i % 10), label=f"{n}: {c} points")
               for i, (n, c) in enumerate(zip(names, scan.meta.get("points_per_head", [])))]
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=min(4, len(handles)), fontsize=8)
    fig.suptitle(title or f"{scan.meta.get('body', '')}: {len(scan)} points, {cfg.get('projection', '')}, "
                 f"laser {cfg.get('laser_angle_deg', 0):g} deg, {1000 * cfg.get('resolution', 0):g} mm",
                 fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    from bodyscan._io import atomic_write

    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, bbox_inches="tight"))
    finally:
        plt.close(fig)
    return path
