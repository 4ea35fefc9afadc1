"""`bodyscan poses ...`: list, show and generate bodies."""

from __future__ import annotations

import sys


def register(sub) -> None:
    """Add the ``poses`` command to the ``bodyscan`` subparsers ``sub``."""
    p = sub.add_parser("poses", help="list, picture and generate posed bodies",
                       description="The pose library: posed bodies with ground-truth sections and joints.")
    psub = p.add_subparsers(dest="poses_command", required=True, metavar="SUBCOMMAND")
    lst = psub.add_parser("list", help="list the shipped bodies (name, height in m, vertex count)")
    lst.set_defaults(func=_list)

    show = psub.add_parser(
        "show", help="three-view picture of a body, coloured by section, joints marked",
        description="Draw BODY from the front, the side and the top into a PNG, each section in its "
                    "own colour, joints as black dots.")
    show.add_argument("body", metavar="BODY",
                      help="a shipped body name (see `poses list`), a body .npz, or a mesh file")
    show.add_argument("--out", required=True, metavar="PNG", help="PNG file to write")
    show.add_argument("--dpi", type=int, default=110, help="resolution of the picture (default: 110)")
    show.set_defaults(func=_show)

    gen = psub.add_parser(
        "generate", help="generate a posed body with the anny body model (needs the 'bodies' extra)",
        description="Generate a posed body with ground truth from a posture (joint angles) and a body "
                    "shape (anny phenotype), both given as a library name or a YAML file. Needs the "
                    "'bodies' extra (torch, anny); the first run builds anny's model, which takes a few "
                    "minutes and writes ~800 MB to $ANNY_CACHE_DIR (default ~/.cache/anny).")
    gen.add_argument("--pose", metavar="SPEC",
                     help="posture: a name from poses/postures/ (e.g. standing) or a posture YAML path")
    gen.add_argument("--shape", default="average_male", metavar="SPEC",
                     help="body shape: a name from poses/shapes/ or a shape YAML path (default: average_male)")
    gen.add_argument("--out", metavar="FILE",
                     help="body .npz to write (with --library: the folder, default the shipped library)")
    gen.add_argument("--max-edge", type=float, default=None, metavar="M",
                     help="split edges longer than this, metres (default: 0.025)")
    gen.add_argument("--library", action="store_true",
                     help="regenerate every body of poses/shipped.yaml instead of one")
    gen.set_defaults(func=_generate)

    smp = psub.add_parser(
        "sample", help="draw a random body corpus with the anny body model (needs the 'bodies' extra)",
        description="Draw bodies INDEX = START .. START+N-1 of seed SEED into DIR, each a function of "
                    "(SEED, INDEX) only: a random anny shape over its whole phenotype range, a posture "
                    "drawn per joint from a family of scanner poses within human range of motion, "
                    "bodies that interpenetrate drawn again, scanner conditions stored with each body. "
                    "Seeds 0-999 are the tune corpus, 1000-1999 the validate corpus. Bodies already "
                    "in DIR are kept. A body takes a few seconds.")
    smp.add_argument("--n", type=int, required=True, help="number of bodies")
    smp.add_argument("--seed", type=int, required=True,
                     help="corpus seed (tune: 0-999, validate: 1000-1999)")
    smp.add_argument("--start", type=int, default=0, help="first index (default: 0)")
    smp.add_argument("--out", required=True, metavar="DIR", help="folder of body .npz files to write")
    smp.set_defaults(func=_sample)

    chk = psub.add_parser(
        "check", help="measure gaps between close body parts and look for interpenetration",
        description="For each BODY: the smallest gaps (cm) arm-torso (without the armpit fold), "
                    "hand-hip, thigh-thigh and between any two sections that do not meet at a joint, "
                    "the number of vertices pushed into a part that is not a neighbour "
                    "(interpenetrating), and the number of vertices inside the body at all (contact: "
                    "closed lips, toes, and the folds of bent joints, where linear blend skinning "
                    "overlaps neighbouring sections). Exit code 1 when a body has interpenetrating "
                    "vertices.")
    chk.add_argument("bodies", nargs="*", metavar="BODY",
                     help="shipped body names or body .npz files (default: the whole library)")
    chk.set_defaults(func=_check)


def _list(args) -> int:
    from .body import load_body
    from .library import list_bodies

    names = list_bodies()
    print(f"{'name':<28} {'height_m':>8} {'vertices':>9}")
    for name in names:
        body = load_body(name)
        print(f"{name:<28} {body.height:>8.3f} {len(body.vertices):>9d}")
    print(f"{len(names)} bodies")
    return 0


def _show(args) -> int:
    from .body import load_body
    from .show import show

    if args.dpi <= 0:
        print(f"poses show: --dpi must be positive, got {args.dpi}", file=sys.stderr)
        return 2
    path = show(load_body(args.body), args.out, dpi=args.dpi)
    print(path)
    return 0


def _generate(args) -> int:
    from dataclasses import replace
    from pathlib import Path

    from .body import save_body
    from .generate import GenerateParams, build_library, generate, load_posture, load_shape

    params = GenerateParams()
    if args.max_edge is not None:
        if not args.max_edge > 0:
            print(f"poses generate: --max-edge must be positive metres, got {args.max_edge}", file=sys.stderr)
            return 2
        params = replace(params, max_edge_m=args.max_edge)
    if args.library:
        for path in build_library(args.out, params=params):
            print(path)
        return 0
    if not args.pose or not args.out:
        print("poses generate: --pose and --out are needed (or --library)", file=sys.stderr)
        return 2
    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        print(f"poses generate: --out {out} must end in .npz", file=sys.stderr)
        return 2
    posture, shape = load_posture(args.pose), load_shape(args.shape)  # user errors before the slow part
    body = generate(posture, shape, params, name=out.stem)
    print(save_body(body, out))
    return 0


def _sample(args) -> int:
    from .body import BodyError
    from .generate import _import_anny
    from .sample import sample

    from bodyscan._io import check_out

    if args.seed < 0 or args.start < 0:
        raise BodyError(f"--seed and --start must be non-negative, got {args.seed}, {args.start}")
    check_out(args.out, folder=True)   # before the body model is built
    _import_anny()  # says how to install the 'bodies' extra before anything is drawn
    sample(args.n, args.seed, args.out, start=args.start)
    return 0


def _check(args) -> int:
    from .body import load_body
    from .checks import gaps, inside_vertices, interpenetration
    from .library import list_bodies

    names = args.bodies or list_bodies()
    print(f"{'name':<24} {'height_m':>8} {'arm_torso':>9} {'hand_hip':>8} {'thigh_thigh':>11} "
          f"{'nonadjacent':>11} {'interpenetrating':>16} {'contact':>7}")
    worst = 0
    for name in names:
        body = load_body(name)
        body.require_ground_truth("checking gaps")
        g = {k: 100 * v for k, v in gaps(body).items()}
        bad = int(interpenetration(body).sum())
        worst = max(worst, bad)
        print(f"{body.name:<24} {body.height:>8.3f} {g['arm_torso']:>9.1f} {g['hand_hip']:>8.1f} "
              f"{g['thigh_thigh']:>11.1f} {g['nonadjacent']:>11.1f} {bad:>16d} "
              f"{int(inside_vertices(body).sum()):>7d}", flush=True)
    print("gaps in cm; interpenetrating = vertices inside a part that is not their neighbour; "
          "contact = vertices inside the body at all")
    return 1 if worst else 0
