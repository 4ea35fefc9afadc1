"""Sweeps: grid expansion, scans reused, nothing lost (failures, kills, restarts), a real Dask cluster.

The machinery is tested with a toy runner (a module written to a temporary folder) whose metrics are
known functions of the parameters, so every stored number can be checked exactly.
"""

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from bodyscan.benchmarks import BenchError
from bodyscan.benchmarks.store import ResultStore
from bodyscan.benchmarks.sweep import expand_grid, load_sweep, run_sweep

TOY_RUNNER = textwrap.dedent('''
    """A toy runner: metrics are known functions of the parameters; a scan log counts scans."""
    import os, time, uuid, warnings
    from pathlib import Path

    def scan(body, scanner, seed):
        log = os.environ.get("TOY_SCAN_LOG")
        if log:
            Path(log).mkdir(parents=True, exist_ok=True)
            (Path(log) / f"{body}-{scanner['k']}-{seed}-{uuid.uuid4().hex}").touch()
        if body == "broken":
            raise RuntimeError("cannot scan broken")
        return {"k": scanner["k"], "seed": seed, "pid": os.getpid()}

    def evaluate(scanned, method, recon):
        time.sleep(float(recon.get("sleep", 0)))
        if recon.get("t_d") == 0.666:
            raise ValueError("planted failure")
        if recon.get("t_d") == 0.3:
            warnings.warn("toy warning")
        if recon.get("t_d") == 0.999:
            os._exit(3)          # a crash that takes the worker process down
        return {"spurious_area_fraction": recon["t_d"] * scanned["k"],
                "bridging_area_fraction": 0.01 * scanned["seed"] + (method == "m2"),
                "scan_pid": scanned["pid"], "eval_pid": os.getpid()}

    def recon_free_methods():
        return ("peer",)

    def check(sweep):
        for setting in sweep.recon:
            if "t_d" not in setting:
                raise ValueError("every recon setting needs t_d")
''')


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """A folder with the toy runner, importable here and in every child process."""
    folder = tmp_path / "toy"
    folder.mkdir()
    (folder / "toyrunner.py").write_text(TOY_RUNNER)
    monkeypatch.syspath_prepend(str(folder))
    path = os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.setenv("TOY_SCAN_LOG", str(tmp_path / "scanlog"))
    return folder


def write_sweep(path, **spec):
    base = {"name": "toy", "runner": "toyrunner", "bodies": ["a", "b"], "seeds": [0],
            "methods": ["m1"], "scanner": {"k": [1, 2]}, "recon": {"t_d": [0.1, 0.3]}}
    base.update(spec)
    path.write_text(yaml.safe_dump(base))
    return path


def scans_done(tmp_path):
    log = tmp_path / "scanlog"
    return sorted(p.name.rsplit("-", 1)[0] for p in log.iterdir()) if log.is_dir() else []


# -- grid ---------------------------------------------------------------------------------------

def test_grid_axes_tied_axes_and_cases():
    grid = expand_grid({"a": [1, 2], "b": 5, "c,d": [[1, 2], [3, 4]],
                        "cases": [{"e": 0}, {"e": 1, "f": 2}]})
    assert len(grid) == 2 * 2 * 2
    assert grid[0] == {"a": 1, "b": 5, "c": 1, "d": 2, "e": 0}
    assert grid[-1] == {"a": 2, "b": 5, "c": 3, "d": 4, "e": 1, "f": 2}
    assert expand_grid({"v": [[1, 2, 3]]}) == [{"v": [1, 2, 3]}]   # one list-valued setting
    assert expand_grid({}) == [{}]


@pytest.mark.parametrize("section, match", [
    ({"c,d": [[1, 2, 3]]}, "lists of 2"),
    ({"a": []}, "empty"),
    ({"a": 1, "cases": [{"a": 2}]}, "set twice"),
    ({"cases": [1, 2]}, "mappings"),
])
def test_grid_errors(section, match):
    with pytest.raises(BenchError, match=match):
        expand_grid(section)


def test_sweep_file_errors_name_the_file(tmp_path, toy):
    with pytest.raises(BenchError, match="unknown key"):
        load_sweep(write_sweep(tmp_path / "s.yaml", colour="red"))
    with pytest.raises(BenchError, match="every recon setting needs t_d"):
        load_sweep(write_sweep(tmp_path / "s.yaml", recon={"x": 1}))
    with pytest.raises(BenchError, match="cannot be imported"):
        load_sweep(write_sweep(tmp_path / "s.yaml", runner="no_such_runner_module"))
    with pytest.raises(BenchError, match="no such sweep file"):
        load_sweep(tmp_path / "missing.yaml")


def test_sampled_corpus_bodies_join_the_listed_ones(tmp_path, toy, monkeypatch):
    from bodyscan.poses.generate import GENERATOR_VERSION

    cache = tmp_path / "cache"
    kept = cache / "corpus" / f"g{GENERATOR_VERSION}" / "s7"
    kept.mkdir(parents=True)
    for name in ("s7_0000_squat", "s7_0001_seated", "s7_0002_t_pose"):
        (kept / f"{name}.npz").write_bytes(b"")     # kept bodies are not drawn again
    monkeypatch.setenv("BODYSCAN_CACHE_DIR", str(cache))
    sweep = load_sweep(write_sweep(tmp_path / "s.yaml", bodies=["a"], sample={"seed": 7, "n": 2, "start": 1}))
    assert sweep.bodies == ("a", "s7_0001_seated", "s7_0002_t_pose")
    assert sweep.body_paths["s7_0002_t_pose"] == str(kept / "s7_0002_t_pose.npz")
    only = load_sweep(write_sweep(tmp_path / "s.yaml", bodies=[], sample=[{"seed": 7, "n": 1}]))
    assert only.bodies == ("s7_0000_squat",)


@pytest.mark.parametrize("sample", [{"seed": 7}, {"seed": -1, "n": 2}, {"seed": 7, "n": 0}, {"seed": 7, "n": 1, "x": 1},
                                    "s7", {"seed": 7, "n": 2.5}])
def test_bad_sample_entries(tmp_path, toy, sample):
    with pytest.raises(BenchError, match="sample:"):
        load_sweep(write_sweep(tmp_path / "s.yaml", sample=sample))


def test_job_ids_are_stable_and_distinct(tmp_path, toy):
    sweep = load_sweep(write_sweep(tmp_path / "s.yaml", seeds=[0, 1], methods=["m1", "m2"]))
    jobs = sweep.jobs()
    assert len(jobs) == 2 * 2 * 2 * 2 * 2
    assert len({j.job_id for j in jobs}) == len(jobs)
    assert len({j.scan_id for j in jobs}) == 2 * 2 * 2
    again = load_sweep(write_sweep(tmp_path / "t.yaml", seeds=[0, 1], methods=["m1", "m2"]))
    assert [j.job_id for j in again.jobs()] == [j.job_id for j in jobs]


def test_methods_without_recon_parameters_run_once_per_scan(tmp_path, toy):
    sweep = load_sweep(write_sweep(tmp_path / "s.yaml", methods=["m1", "peer"]))
    jobs = sweep.jobs()
    per_scan = {}
    for job in jobs:
        per_scan.setdefault(job.scan_id, []).append((job.method, job.recon))
    assert len(per_scan) == 4
    for entries in per_scan.values():
        assert sorted(entries, key=str) == sorted(
            [("m1", {"t_d": 0.1}), ("m1", {"t_d": 0.3}), ("peer", {})], key=str)


# -- local engine ------------------------------------------------------------------------------

def test_local_sweep_stores_every_job_and_scans_once_per_group(tmp_path, toy, capsys):
    sweep = load_sweep(write_sweep(tmp_path / "s.yaml", bodies=["a", "b", "broken"],
                                   seeds=[0, 1], recon={"t_d": [0.1, 0.666, 0.3]}))
    summary = run_sweep(sweep, tmp_path / "out", workers=2)
    table = ResultStore(tmp_path / "out").read()
    assert len(table) == len(sweep.jobs()) == 3 * 2 * 2 * 3
    # each (body, scanner, seed) scanned exactly once, though 3 jobs use it
    assert len(scans_done(tmp_path)) == 3 * 2 * 2 == summary.scans
    ok = table[table.status == "ok"]
    assert len(ok) == 2 * 2 * 2 * 2 and summary.ok == len(ok)
    assert (ok["spurious_area_fraction"] == ok["recon.t_d"] * ok["scanner.k"]).all()
    assert (ok["bridging_area_fraction"] == 0.01 * ok["seed"]).all()
    # the three jobs of one scan saw the same scan object (made by one process)
    assert (ok.groupby("scan_id")["scan_pid"].nunique() == 1).all()
    # failures are rows with the error and the traceback, and the sweep went on
    planted = table[(table["recon.t_d"] == 0.666) & (table.body != "broken")]
    assert len(planted) == 2 * 2 * 2 and (planted.status == "error").all()
    assert planted.error.str.contains("planted failure").all()
    assert planted.traceback.str.contains("toyrunner.py").all()
    broken = table[table.body == "broken"]
    assert (broken.status == "error").all() and broken.error.str.contains("cannot scan").all()
    assert len(broken) == 2 * 2 * 3 and summary.failed == len(planted) + len(broken)
    err = capsys.readouterr().err
    assert "36 jobs, 0 already stored, 36 to run" in err and "ETA" in err and "failed" in err
    # warnings of the jobs are kept in their rows, not printed over the progress
    assert "toy warning" not in err
    warned = ok["recon.t_d"] == 0.3
    assert ok.loc[warned, "warnings"].str.contains("UserWarning: toy warning").all()
    assert ok.loc[~warned, "warnings"].isna().all()


def test_restart_skips_finished_jobs_and_retry_reruns_failures(tmp_path, toy):
    sweep = load_sweep(write_sweep(tmp_path / "s.yaml", recon={"t_d": [0.1, 0.666]}))
    run_sweep(sweep, tmp_path / "out", workers=1, progress=None)
    first = ResultStore(tmp_path / "out").read().set_index("job_id")
    again = run_sweep(sweep, tmp_path / "out", workers=1, progress=None)
    assert again.skipped == 8 and again.ok == again.failed == 0 and again.scans == 0
    retry = run_sweep(sweep, tmp_path / "out", workers=1, progress=None, retry_failed=True)
    assert retry.skipped == 4 and retry.failed == 4
    second = ResultStore(tmp_path / "out").read().set_index("job_id")
    ok = first.status == "ok"
    assert (second.loc[ok, "finished_at"] == first.loc[ok, "finished_at"]).all()
    assert (second.loc[~ok, "finished_at"] > first.loc[~ok, "finished_at"]).all()
    # a larger sweep in the same folder runs only its new jobs
    bigger = load_sweep(write_sweep(tmp_path / "s2.yaml", recon={"t_d": [0.1, 0.666, 0.5]}))
    more = run_sweep(bigger, tmp_path / "out", workers=2, progress=None)
    assert more.skipped == 8 and more.ok == 4


def _bodyscan(*args):
    return [sys.executable, "-m", "bodyscan.benchmarks.cli", *args]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_killed_sweep_loses_nothing_and_resumes(tmp_path, toy, sig):
    path = write_sweep(tmp_path / "s.yaml", bodies=["a", "b", "c"],
                       recon={"t_d": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "sleep": 0.25})
    total = 3 * 2 * 6
    out = tmp_path / "out"
    proc = subprocess.Popen(_bodyscan("sweep", str(path), "--out", str(out), "--workers", "2"),
                            stderr=subprocess.PIPE, text=True)
    store = ResultStore(out)
    deadline = time.time() + 120
    while len(store.finished()) < 6 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.kill(proc.pid, sig)
    code = proc.wait(timeout=60)
    err = proc.stderr.read()
    assert code == (-signal.SIGKILL if sig == signal.SIGKILL else 130), err
    before = store.read().set_index("job_id")
    assert 6 <= len(before) < total
    assert (before.status == "ok").all()
    # the worker processes do not outlive the killed sweep
    pids = {int(w.rsplit(":", 1)[1]) for w in before.worker}
    deadline = time.time() + 10
    while any(_alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(_alive(p) for p in pids)
    # restart: only the rest runs
    done = subprocess.run(_bodyscan("sweep", str(path), "--out", str(out), "--workers", "2"),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"{len(before)} already stored, {total - len(before)} to run" in done.stderr
    after = store.read().set_index("job_id")
    assert len(after) == total and (after.status == "ok").all()
    assert set(after.index) == {j.job_id for j in load_sweep(path).jobs()}
    assert (after.loc[before.index, "finished_at"] == before.finished_at).all()
    assert (after.spurious_area_fraction == after["recon.t_d"] * after["scanner.k"]).all()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped) counts as gone
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def test_a_dying_worker_stops_the_sweep_and_the_rerun_goes_past_it(tmp_path, toy):
    path = write_sweep(tmp_path / "s.yaml", bodies=["a"], scanner={"k": 1},
                       recon={"t_d": [0.1, 0.999, 0.2, 0.3]})
    run = _bodyscan("sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1")
    proc = subprocess.run(run, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "a worker process died" in proc.stderr
    assert "Traceback" not in proc.stderr
    table = ResultStore(tmp_path / "o").read().set_index("recon.t_d")
    assert table.loc[0.1, "status"] == "ok"
    assert table.loc[0.999, "status"] == "error" and "died" in table.loc[0.999, "error"]
    assert 0.2 not in table.index          # not run yet: not recorded
    again = subprocess.run(run, capture_output=True, text=True, timeout=120)
    assert again.returncode == 1, again.stderr     # the crashed job stays failed
    table = ResultStore(tmp_path / "o").read()
    assert len(table) == 4 and (table.status == "ok").sum() == 3


def test_dry_run_counts_and_runs_nothing(tmp_path, toy, capsys):
    from bodyscan.benchmarks.cli import main

    path = write_sweep(tmp_path / "s.yaml", seeds=[0, 1])
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "16 jobs" in out and "8 scans" in out and "0 already stored" in out
    assert not (tmp_path / "o").exists() and not (tmp_path / "scanlog").exists()


def test_cli_user_errors_are_one_line(tmp_path, toy):
    bad = subprocess.run(_bodyscan("sweep", str(tmp_path / "none.yaml"), "--out", str(tmp_path)),
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "no such sweep file" in bad.stderr
    assert "Traceback" not in bad.stderr
    path = write_sweep(tmp_path / "s.yaml")
    bad = subprocess.run(_bodyscan("sweep", str(path), "--out", str(tmp_path / "o"),
                                   "--scheduler", "localhost:1"), capture_output=True, text=True)
    assert bad.returncode == 2 and "tcp://HOST:PORT" in bad.stderr


# -- Dask ---------------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(toy, tmp_path):
    """A real Dask scheduler and two single-threaded workers on loopback, as subprocesses."""
    pytest.importorskip("distributed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    worker = [sys.executable, "-m", "distributed.cli.dask_worker"]
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    procs = [subprocess.Popen([*dask, "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=open(logs / "scheduler.log", "w"))]
    try:
        for i in range(2):
            procs.append(subprocess.Popen(
                [*worker, address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                 "--host", "127.0.0.1", "--name", f"w{i}"],
                stdout=subprocess.DEVNULL, stderr=open(logs / f"worker{i}.log", "w")))
        from distributed import Client
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
            pids = set(client.run(os.getpid).values())
        yield address, pids
    finally:
        for p in procs:   # workers first would try to reconnect: stop them all at once
            p.kill()
        for p in procs:
            p.wait(timeout=20)


def test_sweep_on_a_dask_cluster(tmp_path, dask_cluster):
    address, worker_pids = dask_cluster
    path = write_sweep(tmp_path / "s.yaml", bodies=["a", "b", "c", "broken"],
                       recon={"t_d": [0.1, 0.666, 0.3], "sleep": 0.1})
    out = tmp_path / "out"
    proc = subprocess.run(_bodyscan("sweep", str(path), "--out", str(out), "--scheduler", address),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr       # the planted failures
    table = ResultStore(out).read()
    assert len(table) == 4 * 2 * 3
    ok = table[table.status == "ok"]
    assert len(ok) == 3 * 2 * 2
    assert (ok.spurious_area_fraction == ok["recon.t_d"] * ok["scanner.k"]).all()
    # the work ran on the cluster's workers, scans once per group, on the workers
    assert set(ok.eval_pid) <= worker_pids and set(ok.scan_pid) <= worker_pids
    assert len(set(ok.eval_pid)) == 2
    assert len(scans_done(tmp_path)) == 4 * 2
    failed = table[table.status == "error"]
    assert failed.traceback.str.len().min() > 0
    # resuming against the cluster runs nothing again
    again = subprocess.run(_bodyscan("sweep", str(path), "--out", str(out), "--scheduler",
                                     address), capture_output=True, text=True, timeout=300)
    assert "24 already stored" in again.stderr and len(scans_done(tmp_path)) == 4 * 2


# -- the default runner: simulator, recon, metrics ----------------------------------------------

def test_default_runner_on_the_standing_body(tmp_path):
    from bodyscan.poses.library import list_bodies

    if "standing" not in list_bodies():
        pytest.fail("the shipped library has no 'standing' body")
    path = tmp_path / "real.yaml"
    path.write_text(yaml.safe_dump({
        "name": "real", "bodies": ["standing"], "methods": ["proposed"],
        "scanner": {"preset": "paper", "resolution": 0.02},
        "recon": {"t_d": [0.2, 0.3]}, "keep_meshes": 1}))
    sweep = load_sweep(path)
    summary = run_sweep(sweep, tmp_path / "out", workers=1, progress=None)
    store = ResultStore(tmp_path / "out")
    table = store.read()
    assert summary.ok == 2, table.get("traceback")
    for metric in ("spurious_area_fraction", "bridging_area_fraction", "fscore_seen@5mm",
                   "section_accuracy", "joint_error_median_m", "time_fit_s", "time_scan_s"):
        assert table[metric].notna().all(), metric
    assert table["spurious_area_fraction"].between(0, 1).all()
    # the posture was estimated once, in the scan stage, and charged to both jobs
    assert table["time_fit_s"].nunique() == 1
    # the worse of the two jobs keeps its mesh, with close-ups near the shoulders and hips
    (kept,) = store.mesh_ids()
    worst = table.loc[(table.spurious_area_fraction + table.bridging_area_fraction).idxmax()]
    assert kept == worst.job_id
    mesh = store.get_mesh(kept)
    assert mesh["faces"].max() < len(mesh["vertices"]) and len(mesh["spurious"]) == len(mesh["faces"])
    from bodyscan.poses.body import load_body
    joints = load_body("standing").joint_dict()
    center, radius = mesh["closeups"]["armpit_l"]
    assert np.linalg.norm(center - joints["shoulder_l"]) < radius
    center, radius = mesh["closeups"]["crotch"]
    assert np.linalg.norm(center - (joints["hip_l"] + joints["hip_r"]) / 2) < radius


def test_shipped_sweep_files():
    from bodyscan.benchmarks.sweep_cli import SWEEPS_DIR

    paper = load_sweep(SWEEPS_DIR / "paper.yaml")
    jobs = paper.jobs()
    assert len(jobs) == 5 * 5 * 3 * 11 and len({j.scan_id for j in jobs}) == 11
    assert {(s["mesh_theta"], s["mesh_h"]) for s in paper.recon} == {(5, 5), (10, 10), (20, 20)}
    assert {s["t_d"] for s in paper.recon} >= {0.3} and paper.methods == ("proposed",)
    ci = load_sweep(SWEEPS_DIR / "ci.yaml")
    assert set(ci.methods) == {"proposed", "simple", "proposed-closed"}
    # three library bodies and the first 10 validate bodies, drawn (or taken from the cache)
    drawn = [b for b in ci.bodies if b.startswith("s1000_")]
    assert len(ci.bodies) == 13 and [b[:10] for b in drawn] == [f"s1000_{i:04d}" for i in range(10)]
    assert len(ci.jobs()) == 13 * 2 * 3
    noise = load_sweep(SWEEPS_DIR / "noise.yaml")        # the library at three noise levels
    jobs = noise.jobs()
    assert len(jobs) == 21 * 3 * 3 and len({j.scan_id for j in jobs}) == 21 * 3
    assert {j.scanner["noise_sigma"] for j in jobs} == {0.0, 0.001, 0.002}
    assert {j.scanner["preset"] for j in jobs} == {"scanner"}
