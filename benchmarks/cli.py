"""The ``bodyscan`` command: gathers each package's subcommands, turns user errors into one line.

Each package contributes a module with ``register(subparsers)``; the handler it sets with
``set_defaults(func=...)`` takes the parsed arguments and returns an exit code. Handlers import
their heavy dependencies lazily, so ``bodyscan --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

#: Modules whose ``register(subparsers)`` adds subcommands, in the order of ``--help``.
COMMAND_MODULES = (
    "bodyscan.poses.cli",
    "bodyscan.simulator.cli",
    "bodyscan.recon.cli",
    "bodyscan.benchmarks.bench_cli",
    "bodyscan.benchmarks.sweep_cli",
)


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that mean "the user asked for something wrong": one line, exit code 2."""
    errors: list[type[BaseException]] = [FileNotFoundError, IsADirectoryError, PermissionError]
    for module, name in (("bodyscan.poses", "BodyError"), ("bodyscan.simulator", "ScanError"),
                         ("bodyscan.recon", "ReconError"), ("bodyscan.benchmarks", "BenchError")):
        try:
            errors.append(getattr(importlib.import_module(module), name))
        except (ImportError, AttributeError):
            pass
    return tuple(errors)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bodyscan",
        description="Benchmark suite for human-body surface reconstruction from range scans "
                    "(Funatomi et al. 2006). Units are metres, +z up, the subject faces -y.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="show the full traceback of errors (also: BODYSCAN_DEBUG=1)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = args.debug or os.environ.get("BODYSCAN_DEBUG") == "1"
    try:
        return int(args.func(args) or 0)
    except _user_errors() as exc:
        if debug:
            raise
        print(f"bodyscan {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bodyscan: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
