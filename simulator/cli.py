"""`bodyscan scan`: scan a body with the slit-laser simulator and write the cloud as PLY."""

from __future__ import annotations

import json
import sys
import time

from bodyscan._params import param_action

from .config import HEAD_LAYOUTS, PRESETS

_P, _S = PRESETS["paper"], PRESETS["scanner"]


def _listing() -> str:
    from bodyscan._params import param_help

    from .config import Head, ScannerConfig

    return param_help({"scanner (ScannerConfig)": ScannerConfig, "each head (Head; --param heads=[{...}])": Head})


def _from_preset(field: str, fmt=lambda v: f"{v:g}") -> str:
    return f"default: from the preset (paper {fmt(getattr(_P, field))}, scanner {fmt(getattr(_S, field))})"


def register(sub) -> None:
    """Add the ``scan`` command to the ``bodyscan`` subparsers ``sub``."""
    p = sub.add_parser(
        "scan", help="scan a body with the simulated slit-laser range finder, write a PLY cloud",
        description="Simulate a slit-laser range finder (Funatomi et al. 2006, section 4.1): a point "
                    "is measured only if its head's camera sees it and its laser lights it, both "
                    "tested by ray casts against the whole posed mesh. Writes a binary PLY with x y z, "
                    "head, view direction (vx vy vz) and ground truth (gt_face, gt_section, "
                    "gt_nx gt_ny gt_nz); metadata in 'comment bodyscan' header lines. Units: metres, "
                    "degrees; +z up, the subject faces -y.")
    p.add_argument("body", metavar="BODY",
                   help="a library body name (see `bodyscan poses list`), a body .npz, or a mesh file "
                        "(.ply .obj .stl .glb .gltf .off) in metres, +z up, facing -y")
    p.add_argument("--out", "-o", required=True, metavar="CLOUD.ply", help="output point cloud (binary PLY)")
    p.add_argument("--preset", choices=sorted(PRESETS), default="paper",
                   help="starting configuration: paper = parallel projection, k = 1, 10 mm, no noise; "
                        "scanner = perspective, 2 mm, 1 mm noise (default: paper)")
    p.add_argument("--projection", choices=("parallel", "perspective"), default=None,
                   help="camera and laser model; " + _from_preset("projection", str))
    g = p.add_mutually_exclusive_group()
    g.add_argument("--k", type=float, default=None,
                   help="laser angle from the optical axis in units of pi/12 = 15 degrees (paper: 1, 2, 3; "
                        "any number); " + _from_preset("k"))
    g.add_argument("--laser-angle", type=float, default=None, metavar="DEG",
                   help="laser angle from the optical axis, degrees (instead of --k)")
    g.add_argument("--baseline", type=float, default=None, metavar="M",
                   help="perspective: camera-to-laser distance, metres; sets the laser angle to "
                        "atan(baseline / camera distance)")
    p.add_argument("--laser-side", choices=("above", "below", "left", "right"), default=None,
                   help="where every head's laser sits relative to its camera (above = the angle lies in "
                        "the vertical plane, a laser line travelling along the body); default: each "
                        "head's own (above for front_rear)")
    p.add_argument("--resolution", type=float, default=None, metavar="M",
                   help="sample spacing on the body, metres; " + _from_preset("resolution"))
    p.add_argument("--heads", choices=HEAD_LAYOUTS, default=None,
                   help="head layout: front_rear = one camera in front and one behind (paper); "
                        "two_towers = front and rear towers with two heads each; four_towers = four "
                        "two-head towers at 45, 135, 225, 315 degrees; front = front head only "
                        "(default: front_rear)")
    p.add_argument("--field-width", type=float, default=None, metavar="M",
                   help="image width of every head at the scanner axis, metres (default: per head, 2.6)")
    p.add_argument("--field-height", type=float, default=None, metavar="M",
                   help="image height of every head at the scanner axis, metres (default: per head, "
                        "2.6 for front_rear, 1.4 for towers)")
    p.add_argument("--camera-distance", type=float, default=None, metavar="M",
                   help="perspective: pinhole distance from the scanner axis, metres; "
                        + _from_preset("camera_distance"))
    p.add_argument("--noise", type=float, default=None, metavar="M",
                   help="standard deviation of range noise along the camera ray, metres; "
                        + _from_preset("noise_sigma"))
    p.add_argument("--outliers", type=float, default=None, metavar="FRACTION",
                   help="fraction of points moved along their ray by up to --outlier-spread; "
                        + _from_preset("outlier_fraction"))
    p.add_argument("--outlier-spread", type=float, default=None, metavar="M",
                   help="largest outlier offset, metres; " + _from_preset("outlier_spread"))
    p.add_argument("--misalign-deg", type=float, default=None, metavar="DEG",
                   help="rotate each head's points by this angle about a random axis, degrees; "
                        + _from_preset("misalign_deg"))
    p.add_argument("--misalign-mm", type=float, default=None, metavar="MM",
                   help="shift each head's points by this distance in a random direction, millimetres; "
                        + _from_preset("misalign_mm"))
    p.add_argument("--max-incidence", type=float, default=None, metavar="DEG",
                   help="drop points seen or lit more obliquely than this from the normal, degrees "
                        "(90 keeps all); " + _from_preset("max_incidence_deg"))
    p.add_argument("--no-center", action="store_true",
                   help="put the scanner axis at x = y = 0 instead of the body's centre")
    p.add_argument("--seed", type=int, default=0, help="seed of noise, outliers and misalignment (default: 0)")
    p.add_argument("--param", action=param_action(_listing), default=[], metavar="NAME=VALUE",
                   help="set any ScannerConfig field by name (JSON value), e.g. --param "
                        "laser_angle_deg=20; repeatable; applied last; `--param help` lists them")
    p.add_argument("--preview", default=None, metavar="PNG",
                   help="also save a picture of the cloud (front, side, back) over the body's silhouette")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary on stderr")
    p.set_defaults(func=_scan)


def build_config(args):
    """The `ScannerConfig` described by parsed ``scan`` arguments."""
    import dataclasses
    import math

    from . import ScanError
    from .config import head_layout, preset

    changes = {name: value for name, value in (
        ("projection", args.projection), ("resolution", args.resolution),
        ("camera_distance", args.camera_distance), ("noise_sigma", args.noise),
        ("outlier_fraction", args.outliers), ("outlier_spread", args.outlier_spread),
        ("misalign_deg", args.misalign_deg), ("misalign_mm", args.misalign_mm),
        ("max_incidence_deg", args.max_incidence), ("k", args.k),
        ("laser_angle_deg", args.laser_angle)) if value is not None}
    if args.heads is not None:
        changes["heads"] = head_layout(args.heads)
    if args.no_center:
        changes["center_on_body"] = False
    config = preset(args.preset, seed=args.seed, **changes)
    if args.baseline is not None:
        if args.baseline <= 0:
            raise ScanError("--baseline must be positive metres")
        config = config.replace(laser_angle_deg=math.degrees(math.atan2(args.baseline, config.camera_distance)))
    head_changes = {}
    if args.laser_side is not None:
        head_changes["laser_roll_deg"] = {"above": 0.0, "below": 180.0, "right": 90.0, "left": 270.0}[args.laser_side]
    if args.field_width is not None:
        head_changes["field_width"] = args.field_width
    if args.field_height is not None:
        head_changes["field_height"] = args.field_height
    if head_changes:
        config = config.replace(heads=tuple(dataclasses.replace(h, **head_changes) for h in config.heads))
    for item in args.param:
        name, sep, text = item.partition("=")
        if not sep:
            raise ScanError(f"--param {item!r}: expected NAME=VALUE")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        if name.strip() == "heads" and isinstance(value, str):
            value = head_layout(value)
        known = {f.name for f in dataclasses.fields(config)} | {"k"}
        if name.strip() not in known:
            raise ScanError(f"--param {item!r}: unknown parameter {name.strip()!r} "
                            f"(known: {', '.join(sorted(known))})")
        config = config.replace(**{name.strip(): value})
    return config


def _scan(args) -> int:
    import warnings

    from bodyscan.poses import load_body

    from .cloud_io import write_cloud
    from .scan import scan

    from bodyscan._io import check_out

    from . import ScanError
    config = build_config(args)
    check_out(args.out, suffixes=(".ply",), error=ScanError)   # written as binary PLY
    if args.preview:
        check_out(args.preview, option="--preview", error=ScanError)
    t0 = time.perf_counter()
    body = load_body(args.body)
    t1 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = scan(body, config)
    seconds = time.perf_counter() - t1
    for w in caught:
        print(f"bodyscan scan: warning: {w.message}", file=sys.stderr)
    out = write_cloud(result, args.out)
    if args.preview:
        from .preview import save_preview
        save_preview(result, body, args.preview)
    if not args.quiet:
        per_head = ", ".join(f"{n} {c:,}" for n, c in zip(result.meta["heads"], result.meta["points_per_head"]))
        print(f"bodyscan scan: {body.name}: {len(result):,} points ({per_head}) from "
              f"{result.meta['rays']:,} rays in {seconds:.2f} s, "
              f"{time.perf_counter() - t0:.2f} s in all -> {out}"
              + (f", preview {args.preview}" if args.preview else ""), file=sys.stderr)
    return 0
