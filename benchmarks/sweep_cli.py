"""The ``bodyscan sweep`` and ``bodyscan report`` commands."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

SWEEPS_DIR = Path(__file__).resolve().parent / "sweeps"


def register(sub) -> None:
    """Add ``sweep`` and ``report`` to the ``bodyscan`` subcommands."""
    p = sub.add_parser(
        "sweep", help="run a parameter sweep (grid over scanner and reconstruction settings)",
        description="Run every job of a sweep file (bodies x seeds x scanner settings x methods "
                    "x reconstruction parameters), storing each result the moment it is done "
                    "(one Parquet part per job in DIR/parts/). A failing job is stored with its "
                    "error and traceback and the sweep goes on. Run the same command again after "
                    "an interruption: finished jobs are skipped (so after changing the code, use a new "
                    "--out folder). Exit code 0 when every job "
                    "succeeded, 1 when some failed (in this run or an earlier one).",
        epilog=f"Shipped sweep files: {', '.join(sorted(p.stem for p in SWEEPS_DIR.glob('*.yaml')))}"
               f" (give the name, or any file; see {SWEEPS_DIR}/paper.yaml for the format).")
    p.add_argument("sweep_file", metavar="SWEEP.yaml",
                   help="sweep file, or the name of a shipped one (paper, ci)")
    p.add_argument("--out", required=True, metavar="DIR", type=Path,
                   help="sweep folder for the results (created; reused to resume)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run on this Dask distributed scheduler (extra `dist`) instead of local "
                        "processes")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: every core); ignored with --scheduler")
    p.add_argument("--retry-failed", action="store_true",
                   help="also rerun jobs whose stored result is an error (default: skip them)")
    p.add_argument("--dry-run", action="store_true",
                   help="check the sweep file, print its size (jobs, scans, settings) and how many "
                        "jobs DIR already holds, and run nothing")
    p.set_defaults(func=_sweep)

    r = sub.add_parser(
        "report", help="write report.md and a self-contained index.html from a sweep folder; "
                       "optionally gate on a baseline",
        description="Tables by method and posture, heat maps of spurious and bridging area over "
                    "T_d and the T_n factor, curves over the mesh size, per-posture bars, time per "
                    "stage, and pictures of the worst reconstructions (report.md, and index.html "
                    "with every image inlined). With --baseline, the accuracy gate compares, per "
                    "method and posture, the mean spurious and bridging area fractions, F-score "
                    "(seen, 5 mm), section accuracy and median joint error with the baseline; "
                    "tolerances are stored in the baseline file.")
    r.add_argument("sweep_dir", metavar="DIR", type=Path, help="sweep folder (bodyscan sweep --out)")
    r.add_argument("--out", metavar="DIR", type=Path,
                   help="report folder (default: reports/<sweep name>/)")
    r.add_argument("--baseline", metavar="FILE", type=Path,
                   help="baseline JSON of the tracked metrics (e.g. reports/baseline.json)")
    r.add_argument("--fail-on-regression", action="store_true",
                   help="exit 1 when a tracked metric is worse than --baseline beyond its "
                        "tolerance, listing every regression")
    r.add_argument("--update-baseline", action="store_true",
                   help="write the current tracked metrics to --baseline (deliberately)")
    r.add_argument("--no-pictures", action="store_true",
                   help="skip the rendered pictures of reconstructions")
    r.set_defaults(func=_report)


def _sweep(args) -> int:
    from . import BenchError
    from .sweep import load_sweep, run_sweep

    path = Path(args.sweep_file)
    if not path.exists() and (SWEEPS_DIR / f"{args.sweep_file}.yaml").is_file():
        path = SWEEPS_DIR / f"{args.sweep_file}.yaml"
    if args.workers is not None and args.workers < 1:
        raise BenchError(f"--workers must be >= 1, got {args.workers}")
    if args.scheduler and not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ws://")):
        raise BenchError(f"--scheduler {args.scheduler!r}: give an address like tcp://HOST:PORT")
    if not args.dry_run:
        from bodyscan._io import check_out

        check_out(args.out, folder=True, error=BenchError)
    elif Path(args.out).exists() and not Path(args.out).is_dir():   # a dry run makes nothing
        raise BenchError(f"--out {args.out}: is a file, not a folder")
    sweep = load_sweep(path)
    if args.dry_run:
        from .store import ResultStore

        jobs = sweep.jobs()
        stored = len({j.job_id for j in jobs} & ResultStore(args.out).finished())
        from .methods import method_name

        per = ", ".join(f"{method_name(m)} {len(sweep.settings(m))}" for m in sweep.methods)
        print(f"sweep {sweep.name}: {len(jobs)} jobs = {len(sweep.bodies)} bodies x "
              f"{len(sweep.seeds)} seeds x {len(sweep.scanner)} scanner settings x "
              f"settings per method ({per}); "
              f"{len({j.scan_id for j in jobs})} scans; {stored} already stored in {args.out}")
        return 0
    # SIGTERM ends the run like Ctrl-C: stored results stay, workers are told to stop
    signal.signal(signal.SIGTERM, _terminate)
    summary = run_sweep(sweep, args.out, scheduler=args.scheduler, workers=args.workers,
                        retry_failed=args.retry_failed)
    print(f"sweep {sweep.name}: {summary.ok} succeeded, {summary.failed} failed, {summary.skipped} "
          f"already stored, {summary.scans} scans, {summary.seconds:.1f} s -> {args.out}",
          file=sys.stderr)
    if summary.failed_total:
        print(f"sweep: {summary.failed_total} job(s) of this sweep failed; their errors are in the "
              f"results (bodyscan report {args.out}); rerun with --retry-failed", file=sys.stderr)
        return 1
    return 0


def _terminate(signum, frame):
    raise KeyboardInterrupt


def _report(args) -> int:
    from .report import report_command
    return report_command(args)
