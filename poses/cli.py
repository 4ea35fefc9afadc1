"""`bodyscan poses ...`: list, show and generate bodies."""

from __future__ import annotations


def register(sub) -> None:
    """Add the ``poses`` command to the ``bodyscan`` subparsers ``sub``."""
    p = sub.add_parser("poses", help="list, picture and generate posed bodies",
                       description="The pose library: posed bodies with ground-truth sections and joints.")
    psub = p.add_subparsers(dest="poses_command", required=True, metavar="SUBCOMMAND")
    lst = psub.add_parser("list", help="list the shipped bodies (name, height in m, vertex count)")
    lst.set_defaults(func=_list)


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
