"""`bodyscan fit`: posture estimation of a point cloud (paper section 2), written as FIT.json."""

from __future__ import annotations

import sys
import warnings

from bodyscan._params import param_action


def _listing() -> str:
    from .params import stage_help

    return stage_help(("fit", "clean"))


def register(sub) -> None:
    """Add ``bodyscan fit`` to the subparsers ``sub``."""
    p = sub.add_parser(
        "fit", help="fit the body model to a point cloud (posture estimation, paper section 2)",
        description="Fit the body model (11 sections of elliptic columns and caps) to a point cloud: "
                    "volume matching, then fine adjustment on the points. Writes FIT.json with "
                    "'joints' {name: [x, y, z]} (the estimated joints), 'seams' {name: [x, y, z]} (where the "
                    "sections meet, which the clustering cuts at) and 'sections' {name: {...}}; units "
                    "are metres.")
    p.add_argument("cloud", metavar="CLOUD", help="point cloud: .ply, .xyz/.txt (x y z columns) or .pcd, metres")
    p.add_argument("--out", required=True, metavar="FIT.json", help="output fit (JSON)")
    p.add_argument("--preview", metavar="PNG", help="also draw the cloud with the model over it, in "
                   "three views, after the volume match and after the fine adjustment")
    p.add_argument("--param", action=param_action(_listing), default=[], metavar="NAME=VALUE",
                   help="set a posture-estimation parameter (repeatable); `--param help` lists them "
                        "all with default, unit, range and meaning")
    p.set_defaults(func=run)


def run(args) -> int:
    from dataclasses import fields

    from .cloud import read_cloud
    from .params import ReconParams, _did_you_mean
    from .pipeline import estimate_fit

    from bodyscan._io import check_out, write_json

    from . import ReconError

    stage_of = {f.name: stage for stage, obj in ReconParams().stages().items() for f in fields(obj)}
    known = {name for name, stage in stage_of.items() if stage in ("fit", "clean")}
    for pair in args.param:   # the posture depends on the fit's and the cleaning's parameters only
        name, sep, _ = pair.partition("=")
        name = name.strip()
        if not sep or name not in known:
            hint = (f"; {name!r} is a {stage_of[name]} parameter, which the fit does not use"
                    if name in stage_of else _did_you_mean(name, known))
            raise ReconError(f"--param {pair!r}: expected name=value with name a parameter of the "
                             f"posture fit or the cleaning before it{hint} (`--param help` lists them)")
    params = ReconParams.from_overrides({n.strip(): v for n, _, v in (p.partition("=") for p in args.param)})
    out = check_out(args.out, error=ReconError)
    if args.preview:
        check_out(args.preview, option="--preview", error=ReconError)
    cloud = read_cloud(args.cloud)
    print(f"bodyscan fit: {len(cloud.points)} points from {args.cloud}", file=sys.stderr)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = estimate_fit(cloud.points, params, view_dir=cloud.view_dir, head=cloud.head)
    for w in caught:
        print(f"bodyscan fit: warning: {w.message}", file=sys.stderr)
    write_json(out, fit.to_dict(), indent=1, error=ReconError)
    t = fit.times
    print(f"bodyscan fit: wrote {out} ({len(fit.sections)} sections; voxelize {t['voxelize']:.2f} s, "
          f"match {t['match']:.2f} s, fine {t['fine']:.2f} s)", file=sys.stderr)
    if args.preview:
        from .posture.preview import draw_fit

        draw_fit(cloud.points, fit, args.preview)
        print(f"bodyscan fit: wrote {args.preview}", file=sys.stderr)
    return 0
