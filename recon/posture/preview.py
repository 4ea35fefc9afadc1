"""Picture of a posture fit: the cloud with the model over it, before and after the fine adjustment."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Views: (title, horizontal axis vector, vertical axis vector).
VIEWS = (("front", np.array([1.0, 0, 0]), np.array([0, 0, 1.0])),
         ("side", np.array([0, -1.0, 0]), np.array([0, 0, 1.0])),
         ("top", np.array([1.0, 0, 0]), np.array([0, 1.0, 0])))


def draw_fit(points: np.ndarray, fit, path, *, max_points: int = 20000, seed: int = 0) -> Path:
    """Draw ``points`` (n, 3) metres with the coarse and the fine model of ``fit`` (a `BodyFit`).

    Two rows (after the volume match, after the fine adjustment) by three views (front, side, top);
    the previous stage's model is drawn in outline, as in the paper's Fig. 10. Returns the path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = np.asarray(points, dtype=float)
    if len(points) > max_points:
        points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
    stages = [("volume match", fit.coarse, None), ("fine adjustment", fit, fit.coarse)]
    stages = [s for s in stages if s[1] is not None]
    fig, axes = plt.subplots(len(stages), 3, figsize=(12, 6 * len(stages)), squeeze=False)
    cmap = plt.get_cmap("tab20")
    for row, (title, f, before) in enumerate(stages):
        for col, (vname, u, v) in enumerate(VIEWS):
            ax = axes[row, col]
            ax.scatter(points @ u, points @ v, s=0.3, c="0.6", linewidths=0)
            if before is not None:
                for s in before.sections.values():
                    q = s.surface_points(16, 6)
                    ax.plot(q @ u, q @ v, ",", color="0.2", alpha=0.3)
            for i, (name, s) in enumerate(sorted(f.sections.items())):
                q = s.surface_points(16, 8)
                ax.scatter(q @ u, q @ v, s=1.0, color=cmap(i % 20), linewidths=0)
                a, b = s.start, s.end
                ax.plot([a @ u, b @ u], [a @ v, b @ v], "-", color=cmap(i % 20), lw=1.5)
            for name, p in f.joints.items():
                ax.plot(p @ u, p @ v, "k.", ms=4)
            ax.set_aspect("equal")
            ax.set_title(f"{title}: {vname}")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from bodyscan._io import atomic_write

    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=80))
    finally:
        plt.close(fig)
    return path
