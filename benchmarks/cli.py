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
import warnings

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
    errors: list[type[BaseException]] = [FileNotFoundError, IsADirectoryError, PermissionError,
                                         NotADirectoryError]
    for module, name in (("bodyscan._io", "OutputError"), ("bodyscan._resources", "ResourceError"),
                         ("bodyscan.poses", "BodyError"), ("bodyscan.simulator", "ScanError"),
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


def _split_debug(argv: list[str]) -> tuple[list[str], bool]:
    """``argv`` without ``--debug`` (accepted anywhere before a ``--``), and whether it was there."""
    end = argv.index("--") if "--" in argv else len(argv)
    head = [a for a in argv[:end] if a != "--debug"]
    return head + argv[end:], len(head) < end


def _one_line_warning(command: str):
    """A `warnings.showwarning` printing ``bodyscan COMMAND: warning: message`` on one line."""
    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        print(f"bodyscan {command}: warning: {text}", file=file or sys.stderr)
    return show


#: Thread-count variables of the BLAS libraries numpy may be built with.
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Run numpy's BLAS on one thread in this process and the workers it starts, unless the user
    set one of `BLAS_THREADS`. The stages' matrix products are small ((n, 3) by (3, 3)): more
    threads gain no wall time and on a busy machine spin, inflating the CPU seconds the benchmark
    reports. Takes effect only before numpy is first imported (as by ``bodyscan`` and
    ``python -m bodyscan.benchmarks.perf_recon``)."""
    if not any(v in os.environ for v in BLAS_THREADS) and "numpy" not in sys.modules:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"


def main(argv: list[str] | None = None) -> int:
    one_blas_thread()
    argv, debug_flag = _split_debug(list(sys.argv[1:] if argv is None else argv))
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = debug_flag or args.debug or os.environ.get("BODYSCAN_DEBUG") == "1"
    shown = warnings.showwarning
    if not debug:
        warnings.showwarning = _one_line_warning(args.command)
    try:
        return _answered(f"bodyscan {args.command}", lambda: args.func(args), debug)
    finally:
        warnings.showwarning = shown


def _answered(prog: str, call, debug: bool) -> int:
    """``call()``'s exit code; a user error, or running out of memory, is one line on stderr
    naming ``prog`` and exit code 2 (``debug``: the traceback)."""
    try:
        return int(call() or 0)
    except _user_errors() as exc:
        if debug:
            raise
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        if debug:
            raise
        print(f"{prog}: error: out of memory; ask for less (a coarser resolution, fewer samples) or "
              "run where more memory is free", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:      # output piped into a reader that stopped (| head)
        sys.stderr.close()
        return 1


def run_script(prog: str, main, argv: list[str] | None = None) -> int:
    """Run the ``main(argv)`` of a ``python -m bodyscan.benchmarks.<prog>`` script as `main` runs
    a subcommand: a user error is one line on stderr and exit code 2, the traceback only with
    ``--debug`` (anywhere before ``--``) or ``BODYSCAN_DEBUG=1``."""
    argv, debug = _split_debug(list(sys.argv[1:] if argv is None else argv))
    return _answered(prog, lambda: main(argv), debug or os.environ.get("BODYSCAN_DEBUG") == "1")


def values(kind=float, positive: bool = False):
    """An argparse ``type``: a comma-separated list of ``kind`` (positive ones with ``positive``);
    a bad item is argparse's one-line error, naming it."""
    def parse(text: str) -> list:
        out = []
        for item in (x.strip() for x in text.split(",")):
            try:
                v = kind(item)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{item!r} is not a {kind.__name__}") from None
            if positive and not v > 0:
                raise argparse.ArgumentTypeError(f"{item!r} must be positive")
            out.append(v)
        return out
    return parse


def positive(kind=int):
    """An argparse ``type``: one positive ``kind``."""
    def parse(text: str):
        if "," in text:
            raise argparse.ArgumentTypeError(f"{text!r}: give one value")
        return values(kind, positive=True)(text)[0]
    return parse


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
