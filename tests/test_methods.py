"""Bring your own method (issue 18): a method defined here, outside the package
(`tests/tiny_method.py`), as a Python callable, an entry point and an external command, is
benchmarked, swept over its own parameter and gated, in the same tables as ``proposed``."""

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from bodyscan.benchmarks import BenchError
from bodyscan.benchmarks import methods as methods_mod
from bodyscan.benchmarks.bench import BenchConfig, run_bench
from bodyscan.benchmarks.methods import MethodError, command_spec, method_name, resolve
from bodyscan.benchmarks.metrics import MetricParams

HERE = Path(__file__).parent
TINY = "tiny=tiny_method:reconstruct"
TOOL = command_spec(f"tool={sys.executable} {HERE / 'tiny_method.py'} {{cloud}} {{out}} {{max_edge}}")
METRICS = MetricParams(n_samples=20_000)


@pytest.fixture(autouse=True)
def importable(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))


def test_specs_resolve_to_named_methods(monkeypatch):
    assert resolve("proposed").kind == "recon" and resolve("bpa").kind == "peer"
    tiny = resolve(TINY)
    assert (tiny.name, tiny.kind, tiny.target) == ("tiny", "python", "tiny_method:reconstruct")
    assert tiny.defaults() == {"max_edge": 0.03}
    assert tiny.check_params({"max_edge": "0.05"}) == {"max_edge": 0.05}   # text from --param
    assert resolve("tiny_method:reconstruct").name == "tiny_method:reconstruct"
    tool = resolve(TOOL)
    assert tool.name == "tool" and tool.kind == "command" and tool.defaults() == {"max_edge": None}
    assert method_name(command_spec("mytool {cloud} {out}")) == "mytool"
    with pytest.raises(MethodError, match="unknown parameter"):
        tiny.check_params({"radius": 1})
    with pytest.raises(MethodError, match="no default"):
        tool.check_params({})
    with pytest.raises(MethodError, match="unknown method"):
        resolve("marching-cubes")
    with pytest.raises(MethodError, match=r"\{cloud\} and \{out\}"):
        resolve(command_spec("mytool {cloud}"))
    # an installed entry point (group bodyscan.methods) resolves by its name
    monkeypatch.setattr(methods_mod, "installed_methods", lambda: {"tinyep": "tiny_method:reconstruct"})
    assert resolve("tinyep").kind == "python" and resolve("tinyep").defaults() == {"max_edge": 0.03}


def _square():
    """A 1 m square sampled on a grid, seen from -y: the tiny method's mesh is known."""
    x, z = np.meshgrid(np.linspace(0, 0.1, 11), np.linspace(0, 0.1, 11))
    p = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]
    return p, np.tile([0.0, -1.0, 0.0], (len(p), 1)), np.zeros(len(p), np.int64)


def test_callable_and_command_give_the_same_mesh(tmp_path):
    p, vd, hd = _square()
    v1, f1, extra, times = resolve(TINY).run(p, vd, hd, {"max_edge": 0.05})
    v2, f2, _, _ = resolve(TOOL).run(p, vd, hd, {"max_edge": 0.05})
    assert len(f1) == 2 * 10 * 10 and np.array_equal(np.sort(f1, axis=1), np.sort(f2, axis=1))
    assert np.allclose(v1, v2) and times["total"] > 0 and "point_index" in extra
    n = np.cross(p[f1[:, 1]] - p[f1[:, 0]], p[f1[:, 2]] - p[f1[:, 0]])
    assert (n[:, 1] < 0).all()                       # facing the camera at -y


def test_a_failing_command_is_one_clear_error(tmp_path):
    p, vd, hd = _square()
    fails = resolve(command_spec(f"{sys.executable} -c \"import sys; sys.exit('tool: out of cheese')\" "
                                 "{cloud} {out}"))
    with pytest.raises(MethodError, match="exited with status 1: tool: out of cheese"):
        fails.run(p, vd, hd)
    silent = resolve(command_spec(f"{sys.executable} -c pass {{cloud}} {{out}}"))
    with pytest.raises(MethodError, match="wrote no mesh"):
        silent.run(p, vd, hd)
    missing = resolve(command_spec("no-such-tool-here {cloud} {out}"))
    with pytest.raises(MethodError, match="command not found"):
        missing.run(p, vd, hd)
    bad = resolve("builtins:len")
    with pytest.raises((MethodError, TypeError)):
        bad.run(p, vd, hd)


def test_bench_runs_your_methods_beside_proposed(tmp_path):
    config = BenchConfig(bodies=("standing",), ks=(1,), methods=("proposed", TINY, TOOL),
                         recon={"max_edge": "0.05"}, metric=METRICS)
    result = run_bench(config, tmp_path / "bench", jobs=1, progress=None)
    t = result.table.set_index("method")
    assert list(t.index) == ["proposed", "tiny", "tool"] and (t["status"] == "ok").all(), t["error"]
    assert t.loc["tiny", "recon.max_edge"] == 0.05 and t.loc["tiny", "method_spec"] == TINY
    for column in ("spurious_area_fraction", "bridging_area_fraction", "fscore_seen@5mm"):
        assert t.loc["tiny", column] == pytest.approx(t.loc["tool", column], abs=1e-9)
        assert np.isfinite(t.loc["proposed", column])
    # the proposed method keeps its own recon parameters (T_d: the paper's 30 %); max_edge was only
    # the tiny methods', which have no T_d
    assert t.loc["proposed", "recon.t_d"] == 0.3 and pd.isna(t.loc["proposed", "recon.max_edge"])
    assert pd.isna(t.loc["tiny", "recon.t_d"]) and pd.isna(t.loc["tool", "recon.t_d"])
    lines = result.summary.splitlines()
    assert any(line.startswith("tiny") for line in lines) and any(line.startswith("tool") for line in lines)
    report = (result.out / "report.md").read_text()
    assert "| tiny |" in report and "| proposed |" in report
    assert (result.out / "img" / "tiny_standing.png").is_file()
    with pytest.raises(BenchError, match="unknown method"):
        BenchConfig(bodies=("standing",), methods=("proposed", "nope")).resolved()


def test_sweep_over_its_own_parameter_and_the_gate(tmp_path):
    from bodyscan.benchmarks.report import build_report, check_gate, make_baseline
    from bodyscan.benchmarks.store import ResultStore
    from bodyscan.benchmarks.sweep import load_sweep, run_sweep

    path = tmp_path / "own.yaml"
    path.write_text(yaml.safe_dump({
        "name": "own", "bodies": ["standing"], "methods": ["proposed", TINY],
        "scanner": {"preset": "paper", "resolution": 0.02},
        "method_params": {"tiny": {"max_edge": [0.03, 0.06]}}, "keep_meshes": 1}))
    sweep = load_sweep(path)
    jobs = sweep.jobs()
    assert [(j.method, j.recon) for j in jobs] == [("proposed", {}), (TINY, {"max_edge": 0.03}),
                                                    (TINY, {"max_edge": 0.06})]
    summary = run_sweep(sweep, tmp_path / "out", workers=1, progress=None)
    table = ResultStore(tmp_path / "out").read()
    assert summary.ok == 3, table.get("traceback")
    tiny = table[table["method"] == "tiny"].sort_values("recon.max_edge")
    assert list(tiny["recon.max_edge"]) == [0.03, 0.06]
    # longer edges allowed: more of the surface covered, and more of it in the air
    assert tiny["recall_full@5mm"].iloc[1] > tiny["recall_full@5mm"].iloc[0]
    index = build_report(tmp_path / "out", tmp_path / "report", pictures=False)
    md = (index.parent / "report.md").read_text()
    assert "| tiny |" in md and "max_edge" in md
    # gated like proposed: passes against itself, fails when tiny's F-score was better before
    baseline = make_baseline(table, sweep="own")
    assert set(baseline["metrics"]) == {"proposed", "tiny"}
    assert check_gate(table, baseline).passed
    worse = json.loads(json.dumps(baseline))
    worse["metrics"]["tiny"]["standing"]["fscore_seen@5mm"] += 0.05
    gate = check_gate(table, worse)
    assert not gate.passed and any(r.startswith("tiny / standing: fscore_seen@5mm") for r in gate.regressions)
    # a misnamed method_params entry is a one-line error naming the file
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"bodies": ["standing"], "methods": [TINY],
                                   "method_params": {"tiny": {"radius": [1, 2]}}}))
    with pytest.raises(BenchError, match="bad.yaml.*radius"):
        load_sweep(bad)
