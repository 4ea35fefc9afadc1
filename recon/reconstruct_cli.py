"""`bodyscan reconstruct`: surface of a point cloud by posture, clustering and per-section Delaunay."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np

from bodyscan._params import param_action

from . import ReconError

#: Close-ups of the preview: (title, joints whose mean is the centre, offset along z in metres).
CLOSE_UPS = (("left armpit", ("shoulder_l",), -0.08), ("right armpit", ("shoulder_r",), -0.08),
             ("crotch", ("hip_l", "hip_r"), -0.08))
CLOSE_UP_HALF = 0.14  # metres


def _listing() -> str:
    from .params import stage_help

    return stage_help()


def register(sub) -> None:
    """Add ``bodyscan reconstruct`` to the subparsers ``sub``."""
    p = sub.add_parser(
        "reconstruct", help="reconstruct a body surface from a point cloud (paper section 3)",
        description="Reconstruct the body surface of a point cloud: posture estimation (or --fit), "
                    "clustering into the 11 body sections, per-section 2D Delaunay surfaces merged "
                    "through the points kept in two sections. Writes a binary PLY whose faces carry "
                    "a 'section' property. Units: metres.")
    p.add_argument("cloud", metavar="CLOUD.ply", help="point cloud (PLY with x, y, z; a viewing "
                   "direction per point is used for orientation when present)")
    p.add_argument("--method", choices=("proposed", "proposed-closed", "paper", "simple"),
                   default="proposed",
                   help="'proposed': the paper's refined clustering with our rules; "
                        "'proposed-closed': proposed with the unseen surface closed, watertight "
                        "(beyond the paper); 'paper': the paper's steps alone (every rule of ours "
                        "off); 'simple': T_d threshold only, the paper's baseline (default: proposed)")
    p.add_argument("--out", required=True, metavar="MESH.ply", help="output mesh (binary PLY)")
    p.add_argument("--preview", metavar="PNG", help="also draw the mesh coloured by section: front, "
                   "side, back, and close-ups of the armpits and crotch")
    p.add_argument("--param", action=param_action(_listing), default=[], metavar="NAME=VALUE",
                   help="set a reconstruction parameter (repeatable); `--param help` lists them all, "
                        "by stage, with default, unit, range and meaning (recon/params.py explains "
                        "the choices)")
    p.add_argument("--fit", metavar="FIT.json", help="use this fitted model (the JSON written by "
                   "`bodyscan fit`) instead of estimating the posture")
    p.set_defaults(func=run)


def parse_params(items):
    """``["t_d=0.3", ...]`` -> {"t_d": "0.3", ...}; a malformed item raises `ReconError`."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ReconError(f"--param {item!r}: expected NAME=VALUE, e.g. --param t_d=0.3")
        out[name.strip()] = value
    return out


def load_fit(path):
    """A BodyFit from the JSON of `BodyFit.to_dict`."""
    from .model import BodyFit

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--fit {path}: no such file")
    try:
        return BodyFit.from_dict(json.loads(path.read_text()))
    except (ValueError, KeyError, TypeError) as exc:
        raise ReconError(f"--fit {path}: not a fitted-model JSON ({type(exc).__name__}: {exc})") from None


def read_points(path):
    """(points (n, 3), view_dir (n, 3) or None, head (n,) or None) of a cloud file, without any
    ground truth."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        from .cloud import read_cloud
    except ImportError:
        read_cloud = None
    if read_cloud is not None:
        cloud = read_cloud(path)
        return np.asarray(cloud.points), cloud.view_dir, cloud.head
    import trimesh  # fallback until recon.cloud lands: xyz only

    try:
        data = trimesh.load(path, process=False)
    except Exception as exc:
        raise ReconError(f"{path}: cannot read it as a point cloud ({type(exc).__name__}: {exc})") from None
    return np.asarray(data.vertices, dtype=np.float64), None, None


def run(args) -> int:
    from .params import ReconParams
    from .pipeline import reconstruct

    from bodyscan._io import check_out
    params = ReconParams.from_overrides(parse_params(args.param))
    out = check_out(args.out, suffixes=(".ply",), error=ReconError)
    if args.preview:
        check_out(args.preview, option="--preview", error=ReconError)
    fit = load_fit(args.fit) if args.fit else None
    points, view_dir, head = read_points(args.cloud)
    print(f"reconstruct: {len(points)} points, method {args.method}", file=sys.stderr)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = reconstruct(points, args.method, params, view_dir=view_dir, fit=fit, head=head)
    for w in caught:
        print(f"reconstruct: warning: {w.message}", file=sys.stderr)
    if rec.noise is not None and args.method.startswith("proposed") and params.clean.denoise:
        what = (f"denoised (points moved {1000 * np.median(rec.moved):.2f} mm, median)"
                if "denoise" in rec.times else "under denoise_min_noise: meshed as measured")
        print(f"reconstruct: range noise {1000 * rec.noise:.2f} mm: {what}", file=sys.stderr)
    rec.write(out)
    times = ", ".join(f"{k} {v:.2f} s" for k, v in rec.times.items())
    print(f"reconstruct: {len(rec.faces)} triangles -> {out} ({times})", file=sys.stderr)
    if args.preview:
        preview(rec, args.preview)
        print(f"reconstruct: preview -> {args.preview}", file=sys.stderr)
    return 0


# -- preview ---------------------------------------------------------------------------------------
_VIEWS = {"front": ((0, 1, 0), (0, 0, 1)), "side": ((-1, 0, 0), (0, 0, 1)), "back": ((0, -1, 0), (0, 0, 1))}
_COLORS = np.array([
    (0.93, 0.80, 0.55), (0.35, 0.55, 0.85), (0.55, 0.40, 0.75), (0.30, 0.70, 0.45), (0.60, 0.80, 0.30),
    (0.20, 0.65, 0.70), (0.50, 0.80, 0.80), (0.95, 0.60, 0.20), (0.85, 0.75, 0.25), (0.70, 0.50, 0.35),
    (0.80, 0.65, 0.55)])


def _draw(ax, v, f, colors, view, box=None):
    d, up = (np.asarray(x, dtype=float) for x in _VIEWS[view])
    right = np.cross(d, up)
    p = v[f]
    if box is not None:
        c, half = box
        inside = (np.abs(p.mean(axis=1) - c) <= half).all(axis=1)
        p, colors = p[inside], colors[inside]
    xy = np.stack([p @ right, p @ up], axis=-1)
    depth = (p @ d).mean(axis=1)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.35 + 0.65 * np.abs(n @ d)
    order = np.argsort(-depth)
    from matplotlib.collections import PolyCollection

    ax.add_collection(PolyCollection(xy[order], facecolors=colors[order] * shade[order, None],
                                     edgecolors="k" if box is not None else "none", linewidths=0.1))
    if box is not None:
        c, half = box
        cx, cy = c @ right, c @ up
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
    elif len(xy):
        lo, hi = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.axis("off")


def preview(rec, path) -> Path:
    """Draw ``rec`` coloured by section: three views and close-ups of armpits and crotch (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v, f = rec.vertices, rec.faces
    colors = _COLORS[np.clip(rec.face_section, 0, len(_COLORS) - 1)]
    fig, axes = plt.subplots(2, 3, figsize=(12, 10))
    for ax, view in zip(axes[0], _VIEWS):
        _draw(ax, v, f, colors, view)
        ax.set_title(view)
    joints = rec.fit.joints
    for ax, (title, names, dz) in zip(axes[1], CLOSE_UPS):
        if all(n in joints for n in names):
            c = np.mean([joints[n] for n in names], axis=0) + np.array([0, 0, dz])
            _draw(ax, v, f, colors, "front", box=(c, CLOSE_UP_HALF))
        ax.set_title(f"{title} (front)")
        ax.axis("off")
    fig.tight_layout()
    from bodyscan._io import atomic_write

    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110), error=ReconError)
    finally:
        plt.close(fig)
    return Path(path)
