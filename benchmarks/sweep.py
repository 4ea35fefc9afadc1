"""Parameter sweeps: expand a sweep file into jobs, run them on local processes or a Dask cluster,
store every result as it arrives.

A sweep file (YAML) names the bodies, seeds, methods, scanner settings and reconstruction
parameters; in the ``scanner`` and ``recon`` sections a list is an axis of the grid and a scalar is
fixed::

    name: paper
    bodies: library                  # every body of the shipped library, or a list of
                                     # library names and body files (.npz, meshes)
    seeds: [0]                       # scanner seeds (noise, misalignment)
    methods: [proposed]
    scanner:                         # simulator.ScannerConfig fields, from a preset
      preset: paper
      k: [1, 2, 3]                   # an axis: three scanner settings
    recon:                           # recon.ReconParams flat names (see `bodyscan reconstruct`)
      t_d: [0.2, 0.3]
      "mesh_theta,mesh_h": [[5, 5], [10, 10]]   # tied axes: values taken together
      cases: [{t_n_factor: 0.3}, {t_n_factor: 0.6, near_band: 2}]   # explicit combinations,
                                                                    # crossed with the grid
    keep_meshes: 3                   # per method, the meshes of the 3 worst jobs (of distinct
                                     # scans) are kept for the report's pictures
    sample: {seed: 1000, n: 10}      # and bodies 0-9 of the random corpus of seed 1000 (the
                                     # validate set), drawn here by `bodyscan.poses.sample` when
                                     # not yet in the cache (needs the bodies extra; see
                                     # `sampled_bodies`)

A method of your own (`benchmarks.methods`: ``[NAME=]module:function``, ``NAME=cmd:TEMPLATE``
or an installed entry point) is listed under ``methods`` like a built-in one; its own parameters
are swept under ``method_params``, by its name, with the same grid syntax (the ``recon`` grid is
for proposed and simple; peers and methods without ``method_params`` run once per scan)::

    methods: [proposed, tiny=mypkg.tiny:reconstruct]
    method_params:
      tiny: {radius: [0.01, 0.02]}

A list-valued setting is written as a list of lists (``[[1, 2, 3]]`` is one value). Every
combination of body x seed x scanner setting x method x recon setting is one job. A job's id is a
hash of all of these, so the same job has the same id in every run: `run_sweep` skips jobs whose
results are already stored (see `benchmarks.store`) and runs only the rest.

Scans are simulated once per (body, scanner setting, seed), on a worker, and every job of that
scan gets the same scan: jobs are submitted when their scan is ready. The engine is local worker
processes (`concurrent.futures.ProcessPoolExecutor`, one per core by default) or, with
``scheduler="tcp://HOST:PORT"``, a Dask distributed cluster; either way the driving process
receives each result and stores it at once, and prints progress (done, failed, left, time left)
on stderr.

The work itself is done by a *runner*, a module with two functions (the default, `DEFAULT_RUNNER`,
simulates with `simulator` and scores with `benchmarks.bench.evaluate`)::

    scan(body: str, scanner: dict, seed: int) -> object     # anything picklable
    evaluate(scanned, method: str, recon: dict) -> dict     # metrics; optional "_mesh" entry
    check(sweep: Sweep) -> None                             # optional: raise on bad settings
    recon_free_methods() -> tuple                           # optional: methods that ignore the
                                                            # recon grid (run once per scan)

A sweep file may name another one (``runner: mypackage.myrunner``), importable on every worker.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import itertools
import json
import math
import os
import socket
import sys
import time
import traceback
import warnings
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from . import BenchError
from .store import ResultStore

#: The runner used when a sweep file names none.
DEFAULT_RUNNER = "bodyscan.benchmarks.sweep"
#: Results between two refreshes of the store's one-file table (reading parts costs milliseconds).
COMPACT_EVERY = 100
#: Top-level keys of a sweep file.
SWEEP_KEYS = ("name", "description", "bodies", "seeds", "methods", "scanner", "recon", "runner",
              "keep_meshes", "method_params", "sample")
#: Environment variable naming the folder where sampled corpus bodies are kept between runs.
CACHE_ENV = "BODYSCAN_CACHE_DIR"


@dataclass(frozen=True)
class Job:
    """One reconstruction of one scan, scored."""

    job_id: str
    scan_id: str
    body: str
    seed: int
    scanner: dict
    method: str
    recon: dict

    def row(self) -> dict:
        """The job's parameters as result columns (``scanner.*``, ``recon.*``)."""
        from .methods import method_name

        row = {"job_id": self.job_id, "scan_id": self.scan_id, "body": self.body,
               "seed": self.seed, "method": method_name(self.method)}
        if row["method"] != self.method:
            row["method_spec"] = self.method
        row.update({f"scanner.{k}": v for k, v in self.scanner.items()})
        row.update({f"recon.{k}": v for k, v in self.recon.items()})
        row["scanner_json"] = json.dumps(self.scanner, sort_keys=True)
        row["recon_json"] = json.dumps(self.recon, sort_keys=True)
        return row


@dataclass(frozen=True)
class Sweep:
    """A parsed sweep file.

    Attributes
    ----------
    name : str
    bodies : tuple of str
        Library names or body files (resolved paths in ``body_paths``).
    seeds : tuple of int
    methods : tuple of str
    scanner : tuple of dict
        Every scanner setting of the grid (each with a ``preset``).
    recon : tuple of dict
        Every reconstruction setting of the grid (flat `recon.ReconParams` names).
    runner : str
        Module doing the work (see the module docstring).
    keep_meshes : int
        Meshes kept per method for pictures: the worst jobs by spurious + bridging area.
    source : str
        The sweep file's text.
    recon_free : tuple of str
        Methods that take no reconstruction parameters: one job per scan.
    method_params : dict of str to tuple of dict
        Per method name, the grid of its own parameters (``method_params`` of the file), used
        instead of ``recon``.
    """

    name: str
    bodies: tuple
    seeds: tuple
    methods: tuple
    scanner: tuple
    recon: tuple
    runner: str = DEFAULT_RUNNER
    keep_meshes: int = 3
    body_paths: dict = field(default_factory=dict)
    source: str = ""
    recon_free: tuple = ()
    method_params: dict = field(default_factory=dict)

    def settings(self, method: str) -> tuple:
        """The parameter settings of ``method``'s jobs: its ``method_params`` grid, one empty
        setting for a method without parameters, else the ``recon`` grid."""
        from .methods import method_name

        name = method_name(method)
        if name in self.method_params:
            return self.method_params[name]
        return ({},) if method in self.recon_free else self.recon

    def jobs(self) -> list[Job]:
        """Every job, grouped by scan (all jobs of one scan are adjacent)."""
        out = []
        for body, scanner, seed in itertools.product(self.bodies, self.scanner, self.seeds):
            scan_key = {"body": body, "scanner": scanner, "seed": seed, "runner": self.runner}
            scan_id = _digest(scan_key)
            for method in self.methods:
                for recon in self.settings(method):
                    job_id = _digest({**scan_key, "method": method, "recon": recon})
                    out.append(Job(job_id, scan_id, body, seed, scanner, method, recon))
        return out


def load_sweep(path) -> Sweep:
    """Read and check a sweep file.

    Raises
    ------
    BenchError
        A missing file, bad YAML, an unknown key, a bad axis, or (through the runner's ``check``)
        an unknown body, method or parameter; the message names the file.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise BenchError(f"{path}: no such sweep file")
    text = path.read_text()
    try:
        spec = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise BenchError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(spec, dict):
        raise BenchError(f"{path}: a sweep file is a mapping with keys {', '.join(SWEEP_KEYS)}")
    unknown = sorted(set(spec) - set(SWEEP_KEYS))
    if unknown:
        raise BenchError(f"{path}: unknown key(s) {', '.join(unknown)} "
                         f"(known: {', '.join(SWEEP_KEYS)})")
    where = str(path)
    bodies = spec.get("bodies", "library")
    if bodies == "library":
        from bodyscan.poses.library import list_bodies
        bodies = list_bodies()
        if not bodies:
            raise BenchError(f"{path}: bodies: library, but the pose library is empty")
    bodies = tuple(str(b) for b in _as_list(bodies, where, "bodies")) if bodies else ()
    body_paths = {b: _resolve_body(b, path.parent) for b in bodies}
    if spec.get("sample") is not None:
        sampled = sampled_bodies(spec["sample"], where=where)
        bodies += tuple(p.stem for p in sampled)
        body_paths.update({p.stem: str(p) for p in sampled})
    if not bodies:
        raise BenchError(f"{path}: no bodies (give bodies:, sample:, or both)")
    seeds = tuple(_as_list(spec.get("seeds", [0]), where, "seeds"))
    if not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
        raise BenchError(f"{path}: seeds must be non-negative integers, got {list(seeds)}")
    methods = tuple(str(m) for m in _as_list(spec.get("methods", ["proposed"]), where, "methods"))
    scanner = spec.get("scanner") or {}
    if not isinstance(scanner, dict):
        raise BenchError(f"{path}: scanner must be a mapping of ScannerConfig fields")
    scanner = {"preset": "paper", **scanner}
    own = spec.get("method_params") or {}
    if not isinstance(own, dict) or not all(isinstance(v, dict) for v in own.values()):
        raise BenchError(f"{path}: method_params maps method names to parameter grids")
    from .methods import method_name
    names = [method_name(m) for m in methods]
    stray = sorted(set(map(str, own)) - set(names))
    if stray:
        raise BenchError(f"{path}: method_params names {', '.join(stray)}, not among the "
                         f"methods ({', '.join(names)})")
    own = {str(k): tuple(expand_grid(v, where=f"{path}: method_params: {k}"))
           for k, v in own.items()}
    keep = spec.get("keep_meshes", 3)
    if not (isinstance(keep, int) and keep >= 0):
        raise BenchError(f"{path}: keep_meshes must be an integer >= 0, got {keep!r}")
    sweep = Sweep(
        name=str(spec.get("name") or path.stem), bodies=bodies, seeds=seeds, methods=methods,
        scanner=tuple(expand_grid(scanner, where=f"{path}: scanner")),
        recon=tuple(expand_grid(spec.get("recon") or {}, where=f"{path}: recon")),
        runner=str(spec.get("runner") or DEFAULT_RUNNER), keep_meshes=keep,
        body_paths=body_paths, source=text, method_params=own)
    for name, values in (("bodies", bodies), ("seeds", seeds), ("methods", methods)):
        if len(set(values)) != len(values):
            raise BenchError(f"{path}: {name} lists a value twice")
    runner = _runner(sweep.runner, where)
    if hasattr(runner, "recon_free_methods"):
        import inspect
        free = runner.recon_free_methods
        takes = bool(inspect.signature(free).parameters)
        sweep = dataclasses.replace(sweep, recon_free=tuple(free(methods) if takes else free()))
    check = getattr(runner, "check", None)
    if check is not None:
        try:
            check(sweep)
        except (ValueError, KeyError, TypeError) as exc:
            raise BenchError(f"{path}: {exc}") from None
    return sweep


def sampled_bodies(spec, *, where: str = "sweep") -> list[Path]:
    """The body files of a sweep file's ``sample:`` entry (a mapping or a list of them, each
    ``{seed: S, n: N, start: 0}``): bodies ``start .. start + n - 1`` of the random corpus of
    ``seed`` (`bodyscan.poses.sample`), drawn once and kept in ``$BODYSCAN_CACHE_DIR`` (default
    ``~/.cache/bodyscan``) under ``corpus/g<generator version>/s<seed>``. A body is a function of
    (seed, index) and the generator's version, so a kept one is the one a new draw would give."""
    from bodyscan.poses import BodyError
    from bodyscan.poses.generate import GENERATOR_VERSION
    from bodyscan.poses.sample import sample

    entries = spec if isinstance(spec, list) else [spec]
    root = Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "bodyscan")
    paths = []
    for entry in entries:
        if not isinstance(entry, dict) or set(entry) - {"seed", "n", "start"} or not {"seed", "n"} <= set(entry):
            raise BenchError(f"{where}: sample: give {{seed: S, n: N}} (optionally start: I), got {entry!r}")
        seed, n, start = entry["seed"], entry["n"], entry.get("start", 0)
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (seed, n, start)) \
                or seed < 0 or n < 1 or start < 0 or n > 10000:
            raise BenchError(f"{where}: sample: seed and start must be integers >= 0 and n in 1..10000, "
                             f"got {entry!r}")
        folder = root / "corpus" / f"g{GENERATOR_VERSION}" / f"s{seed}"
        missing = sum(not any(folder.glob(f"s{seed}_{i:04d}_*.npz")) for i in range(start, start + n))
        if missing:
            print(f"{where}: drawing {missing} of {n} corpus bodies (seed {seed}) into {folder} "
                  f"(about 10 s each, once)", file=sys.stderr, flush=True)
        try:
            paths += sample(n, seed, folder, start=start)
        except BodyError as exc:
            raise BenchError(f"{where}: sample: {exc}") from None
    return paths


def expand_grid(section: dict, *, where: str = "sweep") -> list[dict]:
    """Every combination of a sweep-file section's axes.

    Parameters
    ----------
    section : dict
        ``name: value`` (fixed), ``name: [v1, v2]`` (an axis), ``"a,b": [[a1, b1], [a2, b2]]``
        (tied axes), and ``cases: [{...}, ...]`` (explicit combinations, crossed with the rest).

    Returns
    -------
    list of dict
        One flat ``{name: value}`` per combination, in grid order (the last axis varies fastest).
    """
    if not isinstance(section, dict):
        raise BenchError(f"{where}: expected a mapping of parameter names to values or lists")
    axes: list[list[dict]] = []
    for key, value in section.items():
        key = str(key)
        if key == "cases":
            cases = _as_list(value, where, "cases")
            if not cases or not all(isinstance(c, dict) for c in cases):
                raise BenchError(f"{where}: cases must be a non-empty list of mappings")
            axes.append([dict(c) for c in cases])
            continue
        names = [n.strip() for n in key.split(",")]
        if not all(names):
            raise BenchError(f"{where}: bad parameter name {key!r}")
        values = value if isinstance(value, list) else [value]
        if not values:
            raise BenchError(f"{where}: {key} is an empty list")
        if len(names) == 1:
            axes.append([{names[0]: v} for v in values])
            continue
        tied = []
        for v in values:
            if not (isinstance(v, list) and len(v) == len(names)):
                raise BenchError(f"{where}: {key} takes lists of {len(names)} values, got {v!r}")
            tied.append(dict(zip(names, v)))
        axes.append(tied)
    out = []
    for combo in itertools.product(*axes):
        merged: dict = {}
        for part in combo:
            clash = set(merged) & set(part)
            if clash:
                raise BenchError(f"{where}: {', '.join(sorted(clash))} set twice in one "
                                 "combination")
            merged.update(part)
        out.append(merged)
    return out


# -- running ------------------------------------------------------------------------------------

@dataclass
class SweepSummary:
    """What a run did: counts of jobs and the time it took."""

    total: int
    skipped: int
    ok: int
    failed: int
    seconds: float
    scans: int
    failed_total: int = 0    # jobs of the sweep stored as errors, in this run or an earlier one

    @property
    def remaining(self) -> int:
        return self.total - self.skipped - self.ok - self.failed


def run_sweep(sweep: Sweep, out, *, scheduler: str | None = None, workers: int | None = None,
              retry_failed: bool = False, progress=True) -> SweepSummary:
    """Run every job of ``sweep`` that ``out`` does not hold yet, storing each result as it comes.

    Parameters
    ----------
    sweep : Sweep
    out : str or Path
        The sweep folder (see `benchmarks.store`).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler (extra ``dist``); default: local processes.
    workers : int, optional
        Local processes (default: every core). Ignored with a scheduler.
    retry_failed : bool
        Also run again the jobs whose stored result is an error.
    progress : bool or file
        Where progress lines go (jobs done, failed, remaining, estimated time left): True for
        stderr, a file, or False/None for none.

    Returns
    -------
    SweepSummary
    """
    store = ResultStore(out).open_for_writing()
    jobs = sweep.jobs()
    done = store.finished(include_failed=not retry_failed)
    todo = [j for j in jobs if j.job_id not in done]
    store.write_text("sweep.yaml", sweep.source)
    meta = store.read_json("meta.json")
    provenance = _provenance()
    runs = meta.get("runs", [])
    runs.append({"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "jobs": len(jobs),
                 "todo": len(todo), "engine": scheduler or f"local:{workers or os.cpu_count()}",
                 "git_commit": provenance["git_commit"]})
    store.write_json("meta.json", {"sweep": sweep.name, "runner": sweep.runner, "runs": runs,
                                   **provenance})
    stored_failures = len(done - store.finished(include_failed=False)) if done else 0
    stream = sys.stderr if progress is True else (progress or None)
    earlier = {r.get("git_commit") for r in runs[:-1]} - {provenance["git_commit"]}
    if stream is not None and done and earlier:
        commits = ", ".join(sorted(str(c)[:12] for c in earlier))
        print(f"sweep: note: {out} holds results of other code ({commits}); finished jobs are "
              "not rerun: use a new --out folder to measure this code", file=stream)
    meter = _Progress(len(jobs), len(jobs) - len(todo), stream, stored_failures)
    keeper = _MeshKeeper(store, sweep.keep_meshes)
    groups: dict[str, list[Job]] = {}
    for job in todo:
        groups.setdefault(job.scan_id, []).append(job)
    start = time.perf_counter()
    if todo:
        engine = _DaskEngine(scheduler) if scheduler else _LocalEngine(workers, len(groups))
        try:
            _drive(engine, sweep, groups, store, meter, keeper)
        except BrokenProcessPool:
            engine.close(abort=True)
            raise BenchError(
                f"a worker process died (a crash in native code, or out of memory); the jobs it "
                f"may have been running are stored as failed, every finished job is stored in "
                f"{out}: run the same command again to go on") from None
        except BaseException:
            engine.close(abort=True)
            raise
        engine.close()
    meter.finish()
    ids = {j.job_id for j in jobs}
    failed_total = len(ids & (store.finished() - store.finished(include_failed=False)))
    return SweepSummary(total=len(jobs), skipped=len(jobs) - len(todo), ok=meter.ok,
                        failed=meter.failed, seconds=time.perf_counter() - start,
                        scans=len(groups), failed_total=failed_total)


def _drive(engine, sweep: Sweep, groups: dict, store: ResultStore, meter, keeper) -> None:
    """Submit one scan task per group; when a scan is ready, submit its jobs; store each result."""
    pending: dict = {}    # future -> ("scan", scan_id) or ("job", Job), in submission order

    def store_row(job: Job, result: dict) -> None:
        row = {**job.row(), **result}
        mesh = row.pop("_mesh", None)
        store.put(row)
        if mesh is not None:
            keeper.offer(job, row, mesh)
        meter.update(row["status"] == "ok")
        if (meter.ok + meter.failed) % COMPACT_EVERY == 0:
            store.read(columns=["job_id"])    # refresh results.parquet (see store)

    for scan_id, group in groups.items():
        first = group[0]
        body_path = sweep.body_paths.get(first.body, first.body)
        future = engine.submit(_scan_task, sweep.runner, body_path, first.scanner, first.seed,
                               key=f"scan-{scan_id}")
        pending[future] = ("scan", scan_id)
    try:
        while pending:
            done = engine.wait(list(pending))
            for future in [f for f in pending if f in done]:   # oldest first
                kind, what = pending[future]
                if kind == "scan":
                    scanned = engine.result_ref(future)
                    del pending[future]
                    for job in groups[what]:
                        f = engine.submit(_job_task, sweep.runner, scanned, job.method,
                                          job.recon, key=f"job-{job.job_id}")
                        pending[f] = ("job", job)
                    continue
                try:
                    result = future.result()
                except BrokenProcessPool:
                    raise
                except Exception as exc:  # the engine lost the task (e.g. Dask's KilledWorker)
                    result = {"status": "error", "error": f"{type(exc).__name__}: {exc}",
                              "traceback": "".join(traceback.format_exception(exc))}
                del pending[future]
                store_row(what, result)
    except BrokenProcessPool:
        # A local worker died. The tasks it may have been running are the oldest unfinished
        # ones (the pool is first in, first out): record them as failed, so that a rerun goes on
        # past the crash (--retry-failed redoes innocent bystanders).
        # Tasks that finished before the crash are no suspects: store what they returned.
        for future, (kind, what) in list(pending.items()):
            if future.done() and not future.cancelled() and future.exception() is None:
                del pending[future]
                if kind == "job":
                    store_row(what, future.result())
        n = getattr(engine, "workers", 1)
        suspects = list(pending.values())[:n]
        note = "" if n == 1 else f" (or a task running beside it: {n} workers)"
        error = f"a worker process died while running this task{note}"
        for kind, what in suspects:
            for job in (groups[what] if kind == "scan" else [what]):
                store_row(job, {"status": "error", "error": error, "traceback": None})
        raise


def _scan_task(runner: str, body: str, scanner: dict, seed: int):
    """Worker side: simulate one scan; a failure is returned (not raised) for its jobs to report."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            scanned = _runner(runner).scan(body, dict(scanner), int(seed))
        except Exception as exc:
            scanned = _Failed(f"scan failed: {type(exc).__name__}: {exc}",
                              "".join(traceback.format_exception(exc)))
    return _Scanned(scanned, _warning_text(caught))


def _job_task(runner: str, scanned, method: str, recon: dict) -> dict:
    """Worker side: one job; returns the metrics (status ok) or the error and its traceback.

    Warnings (of the scan and of the job) go into the row's ``warnings`` column, not to stderr."""
    started = time.perf_counter()
    info = {"worker": f"{socket.gethostname()}:{os.getpid()}"}
    if isinstance(scanned.value, _Failed):
        return {"status": "error", "error": scanned.value.error,
                "traceback": scanned.value.traceback, "warnings": scanned.warnings,
                "wall_s": 0.0, **info, "finished_at": time.time()}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            metrics = dict(_runner(runner).evaluate(scanned.value, method, dict(recon)))
            status = {"status": "ok", "error": None, "traceback": None}
        except Exception as exc:
            metrics = {}
            status = {"status": "error", "error": f"{type(exc).__name__}: {exc}",
                      "traceback": "".join(traceback.format_exception(exc))}
    text = "\n".join(t for t in (scanned.warnings, _warning_text(caught)) if t) or None
    return {**metrics, **status, "warnings": text, "wall_s": time.perf_counter() - started,
            **info, "finished_at": time.time()}


def _warning_text(caught) -> str | None:
    """Distinct warning messages, one per line (None when there were none)."""
    lines = dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught)
    return "\n".join(lines) or None


@dataclass(frozen=True)
class _Scanned:
    """A scan stage's result as the engine carries it: the runner's value and its warnings."""

    value: object
    warnings: str | None


@dataclass(frozen=True)
class _Failed:
    error: str
    traceback: str


class _LocalEngine:
    """Local worker processes (`concurrent.futures.ProcessPoolExecutor`, spawned)."""

    def __init__(self, workers: int | None, n_tasks: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        n = int(workers) if workers else (os.cpu_count() or 1)
        if n < 1:
            raise BenchError(f"--workers must be >= 1, got {workers}")
        self.workers = n
        self.pool = ProcessPoolExecutor(max_workers=n,
                                        mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_watch_parent, initargs=(os.getpid(),))

    def submit(self, fn, *args, key=None):
        return self.pool.submit(fn, *args)

    def result_ref(self, future):
        return future.result()

    def wait(self, futures):
        from concurrent.futures import FIRST_COMPLETED, wait
        return wait(futures, return_when=FIRST_COMPLETED).done

    def close(self, abort: bool = False):
        self.pool.shutdown(wait=not abort, cancel_futures=True)


def _watch_parent(parent: int) -> None:
    """Worker initializer: exit when the driving process is gone (killed), not linger."""
    import threading

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


class _DaskEngine:
    """A Dask distributed cluster: ``tcp://HOST:PORT`` of its scheduler (extra ``dist``)."""

    def __init__(self, address: str):
        try:
            from distributed import Client
        except ImportError:
            raise BenchError("--scheduler needs Dask distributed: pip install 'bodyscan[dist]'") \
                from None
        self._token = f"{os.getpid()}-{time.time_ns()}"
        try:
            self.client = Client(address, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise BenchError(f"--scheduler {address}: cannot connect ({exc})") from None

    def submit(self, fn, *args, key=None):
        return self.client.submit(fn, *args, key=f"{key}-{self._token}", pure=False)

    def result_ref(self, future):
        return future   # Dask hands the scan to the job on the worker, without a round trip

    def wait(self, futures):
        from distributed import wait
        return wait(futures, return_when="FIRST_COMPLETED").done

    def close(self, abort: bool = False):
        self.client.close()


class _MeshKeeper:
    """Keeps, per method, the meshes of the ``k`` worst jobs (spurious + bridging area), at most
    one per scan (its worst setting), so that the pictures show distinct cases."""

    def __init__(self, store: ResultStore, k: int):
        self.store, self.k = store, k
        self.kept: dict[str, list] = {}
        ids = store.mesh_ids()
        if ids:
            table = store.read()
            for _, row in table[table["job_id"].isin(ids)].iterrows():
                self.kept.setdefault(row["method"], []).append(
                    (_badness(row), row["job_id"], row.get("scan_id")))

    def offer(self, job: Job, row: dict, mesh: dict) -> None:
        bad = _badness(row)
        if self.k == 0 or not math.isfinite(bad):
            return
        kept = self.kept.setdefault(row.get("method", job.method), [])
        same = [entry for entry in kept if entry[2] == job.scan_id]
        if same:   # one mesh per scan, its worst setting: the pictures show distinct cases
            if bad <= same[0][0]:
                return
            self.store.drop_mesh(same[0][1])
            kept.remove(same[0])
        if len(kept) >= self.k and bad <= min(kept)[0]:
            return
        self.store.put_mesh(job.job_id, mesh)
        kept.append((bad, job.job_id, job.scan_id))
        kept.sort(reverse=True)
        while len(kept) > self.k:
            self.store.drop_mesh(kept.pop()[1])


def _badness(row) -> float:
    try:
        value = float(row.get("spurious_area_fraction", math.nan)) + \
            float(row.get("bridging_area_fraction", math.nan))
    except (TypeError, ValueError):
        return math.nan
    return value


class _Progress:
    """Progress lines on stderr: done, failed, remaining, and the estimated time left."""

    def __init__(self, total: int, skipped: int, stream, stored_failures: int = 0):
        self.total, self.skipped, self.stream = total, skipped, stream
        self.ok = self.failed = 0
        self.start = self.last = time.perf_counter()
        self.tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self.printed = False
        if stream is not None:
            note = (f" ({stored_failures} of them failed; --retry-failed reruns them)"
                    if stored_failures else "")
            print(f"sweep: {total} jobs, {skipped} already stored{note}, {total - skipped} to run",
                  file=stream, flush=True)

    def update(self, ok: bool) -> None:
        if not self.ok + self.failed:
            self.first = time.perf_counter()
        self.ok += ok
        self.failed += not ok
        now = time.perf_counter()
        self.printed = False
        if self.stream is not None and (now - self.last >= 1.0 or self.tty):
            self.last = now
            self._print(end="\r" if self.tty else "\n")
            self.printed = not self.tty

    @property
    def left(self) -> int:
        return self.total - self.skipped - self.ok - self.failed

    def _print(self, end="\n"):
        ran = self.ok + self.failed
        now = time.perf_counter()
        elapsed = now - self.start
        # the rate since the first result: the scans and fits before it are not a job's cost
        eta = (now - self.first) / (ran - 1) * self.left if ran >= 2 else math.nan
        print(f"sweep: {self.skipped + ran}/{self.total} done ({self.failed} failed), "
              f"{self.left} left, elapsed {_hms(elapsed)}, ETA {_hms(eta)}",
              file=self.stream, end=end, flush=True)

    def finish(self) -> None:
        if self.stream is not None and not self.printed:
            self._print()


def _hms(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--:--"
    s = int(round(seconds))
    return f"{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


# -- helpers ------------------------------------------------------------------------------------

def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _as_list(value, where, name) -> list:
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, (str, int, float)):
        return [value]
    raise BenchError(f"{where}: {name} must be a value or a list, got {value!r}")


def _resolve_body(body: str, base: Path) -> str:
    """A library name stays a name; a file path becomes absolute (relative to cwd, else to the
    sweep file's folder)."""
    if "/" not in body and "\\" not in body and not Path(body).suffix:
        return body
    for candidate in (Path(body), base / body):
        if candidate.exists():
            return str(candidate.resolve())
    return body   # the runner's check reports it


#: Runner names of stores written before the bodyscan namespace, still resumable.
_OLD_RUNNERS = {"benchmarks.sweep": DEFAULT_RUNNER}


def _runner(name: str, where: str = "sweep"):
    try:
        return importlib.import_module(_OLD_RUNNERS.get(name, name))
    except ImportError as exc:
        raise BenchError(f"{where}: runner {name!r} cannot be imported ({exc})") from None


def _provenance() -> dict:
    """Package versions and git commit, stored with the results."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    versions = {}
    for pkg in ("bodyscan", "numpy", "scipy", "trimesh", "embreex", "pyrender", "dask",
                "distributed"):
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    commit = None
    try:
        import subprocess
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                                capture_output=True, text=True, timeout=5).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        pass
    return {"versions": versions, "git_commit": commit, "python": platform.python_version(),
            "host": socket.gethostname()}


# -- the default runner: simulator + recon + benchmarks.bench ------------------------------------
#
# Work shared by the jobs of one scan is done once: the scan stage also estimates the posture with
# the default fit parameters (the swept T_d, T_n factor and mesh size act after the fit); a job
# whose fit parameters differ fits again, once per worker and setting. `benchmarks.bench` keeps
# each worker's prepared ground truths. Peers take no reconstruction parameters: a sweep runs them
# once per scan, whatever its ``recon`` grid.


@dataclass
class Scanned:
    """What the scan stage hands to the jobs of one scan."""

    body: object                          # poses.Body
    scan: object                          # simulator.Scan
    fits: dict = field(default_factory=dict)     # repr(FitParams) -> BodyFit, or its ReconError
    seconds: dict = field(default_factory=dict)  # "scan", and repr(FitParams) -> fit seconds
    memory: dict = field(default_factory=dict)   # "scan", and repr(FitParams) -> fit peak MiB


def check(sweep: Sweep) -> None:
    """Check bodies, scanner settings, methods and reconstruction parameters before running."""
    from bodyscan.poses.body import load_body
    from bodyscan.recon import ReconParams

    from .methods import resolve
    from .peers import available_peers

    methods = [resolve(m) for m in sweep.methods]     # MethodError is a ValueError
    missing = [m.name for m in methods if m.kind == "peer" and m.name not in available_peers()]
    if missing:
        raise ValueError(f"method(s) {', '.join(missing)} need the peers extra: "
                         "pip install 'bodyscan[peers]'")
    for m in methods:
        if not m.builtin:
            for setting in sweep.settings(m.spec):
                m.check_params(setting)
        elif m.name in sweep.method_params:
            where = "go under recon" if m.kind == "recon" else "are fixed (benchmarks.peers)"
            raise ValueError(f"method_params: {m.name} is built in; its parameters {where}")
    for body in sweep.bodies:
        load_body(sweep.body_paths.get(body, body)).require_ground_truth("scoring")
    for setting in sweep.scanner:
        _scanner_config(setting)
    for setting in sweep.recon:
        ReconParams.from_overrides(setting)


def recon_free_methods(methods=()) -> tuple:
    """Methods that take no reconstruction parameters: the peers, and methods of yours (their
    own parameters are swept under ``method_params``)."""
    from .methods import builtin_methods
    from .peers import PEERS

    builtin = builtin_methods()
    return tuple(PEERS) + tuple(m for m in methods if m not in builtin)


def scan(body: str, scanner: dict, seed: int) -> Scanned:
    """Default runner: load ``body``, simulate its scan, estimate its posture (default fit)."""
    from bodyscan import simulator
    from bodyscan.poses.body import load_body
    from bodyscan.recon import ReconError, ReconParams

    from .bench import PeakMemory

    loaded = load_body(body)
    started = time.perf_counter()
    with PeakMemory() as mem:
        simulated = simulator.scan(loaded, _scanner_config(scanner), seed=seed)
    scanned = Scanned(loaded, simulated, seconds={"scan": time.perf_counter() - started},
                      memory={"scan": mem.peak_mb})
    try:
        _fit_for(scanned, ReconParams())
    except ReconError:      # kept in scanned.fits; reported by every job that needs this fit
        pass
    return scanned


def evaluate(scanned: Scanned, method: str, recon: dict) -> dict:
    """Default runner: reconstruct one scan and score it with `benchmarks.bench.evaluate`.

    The row has bench's metrics and times (``time_fit_s`` is the shared fit's time, reported
    with each job and not in its ``time_total_s``), ``time_scan_s``, and ``_mesh`` for the
    report's pictures. A method of yours gets ``recon`` as its own parameters.
    """
    from bodyscan.recon import ReconParams

    from .bench import RECON_METHODS
    from .bench import evaluate as bench_evaluate

    fit, seconds, params = None, 0.0, (dict(recon) or None)
    if method in RECON_METHODS:
        params = ReconParams.from_overrides(recon)
        fitted = params.paper() if method == "paper" else params   # the paper fits its own way
        fit = _fit_for(scanned, fitted)
        seconds = scanned.seconds.get(_fit_key(fitted), 0.0)
    row = bench_evaluate(scanned.body, scanned.scan, method, params, fit=fit,
                         fit_seconds=seconds, keep_mesh=True)
    row["time_scan_s"] = scanned.seconds.get("scan", math.nan)
    row["peak_memory_scan_mb"] = scanned.memory.get("scan", math.nan)
    if fit is not None:
        row["peak_memory_fit_mb"] = scanned.memory.get(_fit_key(fitted), math.nan)
    return row


def _fit_for(scanned: Scanned, params):
    """The posture for ``params.fit`` (estimated once per scan and worker), or its error."""
    from bodyscan.recon import ReconError
    from bodyscan.recon.pipeline import check_points, estimate_fit

    from .bench import PeakMemory

    key = _fit_key(params)
    if key not in scanned.fits:
        started = time.perf_counter()
        with PeakMemory() as mem:
            try:
                scanned.fits[key] = estimate_fit(check_points(scanned.scan.points), params,
                                                 scanned.scan.view_dir, head=scanned.scan.head)
            except ReconError as exc:
                scanned.fits[key] = exc
        scanned.seconds[key] = time.perf_counter() - started
        scanned.memory[key] = mem.peak_mb
    fit = scanned.fits[key]
    if isinstance(fit, Exception):
        raise fit
    return fit


def _fit_key(params) -> str:
    """What the posture depends on: the fit's parameters and the cleaning before it."""
    return repr(params.fit) + repr(getattr(params, "clean", None))


def _scanner_config(setting: dict):
    from bodyscan import simulator

    setting = dict(setting)
    return simulator.preset(setting.pop("preset", "paper"), **setting)
