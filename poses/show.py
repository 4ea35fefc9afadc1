"""A three-view picture (front, side, top) of a body, coloured by section, joints marked."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .body import SECTIONS, Body

#: One colour per section (`SECTIONS` order); left and right differ in shade.
SECTION_COLORS = np.array([
    (0.93, 0.80, 0.55),  # head
    (0.85, 0.33, 0.31),  # chest
    (0.95, 0.62, 0.20),  # waist
    (0.20, 0.55, 0.85),  # upper_arm_l
    (0.55, 0.75, 0.95),  # upper_arm_r
    (0.15, 0.65, 0.45),  # forearm_l
    (0.55, 0.85, 0.60),  # forearm_r
    (0.55, 0.35, 0.75),  # thigh_l
    (0.80, 0.65, 0.90),  # thigh_r
    (0.45, 0.45, 0.45),  # lower_leg_l
    (0.75, 0.75, 0.75),  # lower_leg_r
])

#: The three views: (title, horizontal axis, vertical axis, viewing direction towards the viewer).
VIEWS = (
    ("front (from -y)", 0, 2, np.array([0.0, -1.0, 0.0])),
    ("side (from +x, subject's left)", 1, 2, np.array([1.0, 0.0, 0.0])),
    ("top (from +z)", 0, 1, np.array([0.0, 0.0, 1.0])),
)


def show(body: Body, out: str | os.PathLike, *, dpi: int = 110, joints: bool = True) -> Path:
    """Draw ``body`` from the front, the side and the top into a PNG.

    Faces are painted back to front with Lambert shading, in their section's colour
    (`SECTION_COLORS`; grey when the body has no ground truth); joints are black dots.

    Parameters
    ----------
    body : Body
    out : path
        PNG file to write (its folder is created).
    dpi : int
        Resolution of the picture.
    joints : bool
        Mark the joints.

    Returns
    -------
    path : Path
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    v = np.asarray(body.vertices, dtype=float)
    f = np.asarray(body.faces)
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    if body.vertex_section is not None:
        base = SECTION_COLORS[body.face_section()]
    else:
        base = np.full((len(f), 3), 0.7)

    fig, axes = plt.subplots(1, 3, figsize=(15, 6.5), gridspec_kw={"width_ratios": [1, 1, 1]})
    lo, hi = v.min(0), v.max(0)
    for ax, (title, i, j, toward) in zip(axes, VIEWS):
        facing = normal @ toward
        keep = facing > 0
        depth = tri[keep].mean(1) @ toward
        order = np.argsort(depth)
        light = 0.35 + 0.65 * facing[keep][order, None]
        polys = tri[keep][order][:, :, [i, j]]
        ax.add_collection(PolyCollection(polys, facecolors=np.clip(base[keep][order] * light, 0, 1),
                                         edgecolors="none", antialiased=False))
        if joints and body.joints is not None:
            jj = np.asarray(body.joints)
            ax.scatter(jj[:, i], jj[:, j], s=14, c="k", zorder=3)
        pad = 0.05
        ax.set_xlim(lo[i] - pad, hi[i] + pad)
        ax.set_ylim(lo[j] - pad, hi[j] + pad)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
        ax.grid(alpha=0.3)
    if body.vertex_section is not None:
        fig.legend(handles=[Patch(color=c, label=s) for s, c in zip(SECTIONS, SECTION_COLORS)],
                   loc="lower center", ncol=11, fontsize=8, frameon=False)
    fig.suptitle(f"{body.name}: height {body.height:.3f} m, {len(v)} vertices, {len(f)} faces")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    from bodyscan._io import atomic_write

    try:
        atomic_write(out, lambda tmp: fig.savefig(tmp, dpi=dpi))
    finally:
        plt.close(fig)
    return out
