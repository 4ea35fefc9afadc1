"""Reports and the accuracy gate, on a sweep folder filled with known rows and meshes.

The HTML is checked as a user would see it: headless Chromium loads it from disk with no network,
every image must have loaded (complete, natural width > 0) and the tables must be there.
"""

import base64
import io
import itertools
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
import trimesh
from PIL import Image

from bodyscan.benchmarks import report
from bodyscan.benchmarks.cli import main as bodyscan
from bodyscan.benchmarks.store import ResultStore
from bodyscan.benchmarks.sweep import Job

BODIES = ("standing", "t_pose")
METHODS = ("proposed", "simple")   # with the grid of recon parameters
ALL_METHODS = METHODS + ("bpa",)    # and a peer without them
T_D = (0.1, 0.3)
T_N = (0.3, 0.5)   # 0.5, with t_d 0.3 and 10 x 10 cells: the defaults
MESH = ((5, 5), (10, 10))


def spurious_of(method, body, t_d, t_n, mesh_theta):
    return (0.02 if method == "proposed" else 0.06) * t_d / 0.1 + 0.01 * t_n \
        + (0.005 if body == "t_pose" else 0.0)


def fill(root, *, shift=0.0, drop=(), fail=1, meshes=2):
    """Rows whose metrics are known functions of the parameters; ``shift`` worsens spurious area.
    Returns the store."""
    store = ResultStore(root).open_for_writing()
    rows = []
    for body, method, t_d, t_n, (mt, mh) in itertools.product(BODIES, METHODS, T_D, T_N, MESH):
        if (method, body) in drop:
            continue
        recon = {"t_d": t_d, "t_n_factor": t_n, "mesh_theta": mt, "mesh_h": mh}
        job = Job(f"{body}-{method}-{t_d}-{t_n}-{mt}".replace(".", "p"), f"s-{body}", body, 0,
                  {"preset": "paper", "k": 1}, method, recon)
        row = job.row()
        row.update(status="ok", error=None, traceback=None, wall_s=1.0, worker="h:1",
                   finished_at=0.0,
                   spurious_area_fraction=spurious_of(method, body, t_d, t_n, mt) + shift,
                   bridging_area_fraction=0.004 * t_d / 0.1 + 0.001 * mt / 5,
                   section_accuracy=0.97 - t_d / 10, joint_error_median_m=0.02,
                   time_fit_s=1.0, time_cluster_s=0.2 * mt, time_surface_s=0.7,
                   time_total_s=1.7 + 0.2 * mt, **{"fscore_seen@5mm": 0.9 - t_d / 10})
        rows.append(row)
    for body in BODIES:   # a peer: no reconstruction parameters, one job per posture
        if ("bpa", body) in drop:
            continue
        job = Job(f"{body}-bpa", f"s-{body}", body, 0, {"preset": "paper", "k": 1}, "bpa", {})
        row = job.row()
        row.update(status="ok", error=None, traceback=None, wall_s=1.0, worker="h:1",
                   finished_at=0.0, spurious_area_fraction=0.01 + shift,
                   bridging_area_fraction=0.0, section_accuracy=None, time_bpa_s=2.0,
                   time_total_s=2.0, **{"fscore_seen@5mm": 0.85})
        rows.append(row)
    for row in rows[:fail]:
        row.update(status="error", error="ReconError: the fit failed", traceback="Traceback...")
        for k in [k for k in row if k.startswith(("spur", "brid", "fscore", "section", "joint"))]:
            del row[k]
    for row in rows:
        store.put(row)
    torso = trimesh.creation.capsule(height=1.0, radius=0.15, count=[32, 32])
    torso.apply_translation([0, 0, 0.9])
    arm = trimesh.creation.capsule(height=0.5, radius=0.05, count=[16, 16])
    arm.apply_translation([0.25, 0, 1.2])
    mesh = trimesh.util.concatenate([torso, arm])
    section = np.r_[np.full(len(torso.faces), 1), np.full(len(arm.faces), 3)]
    for row in rows[fail:fail + meshes]:
        store.put_mesh(row["job_id"], {
            "vertices": mesh.vertices, "faces": mesh.faces, "face_section": section,
            "spurious": mesh.triangles_center[:, 2] > 1.5,
            "bridging": np.zeros(len(mesh.faces), bool),
            "closeups": {"armpit_l": ([0.18, 0.0, 1.35], 0.15), "crotch": ([0.0, 0.0, 0.5], 0.2)}})
    store.write_json("meta.json", {"sweep": "fake", "git_commit": "0123456789abcdef", "runs": []})
    return store


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """One sweep folder and its report (pictures included), shared by the tests below."""
    root = tmp_path_factory.mktemp("report")
    fill(root / "sweep")
    index = report.build_report(root / "sweep", root / "rep")
    return root, index


def test_report_files_and_tables(built):
    root, index = built
    md = (root / "rep" / "report.md").read_text()
    assert "# Sweep report: fake" in md
    assert "## By method" in md and "## By method and posture" in md
    assert "## Failed jobs (1)" in md and "ReconError: the fit failed" in md
    # the by-method-and-posture mean is the mean of the known rows (first row failed)
    jobs = list(itertools.product(T_D, T_N, MESH))
    values = [spurious_of("proposed", "t_pose", t_d, t_n, m[0]) for t_d, t_n, m in jobs]
    expected = f"{np.mean(values) * 100:.2f}"
    line = next(l for l in md.splitlines() if l.startswith("| proposed | t_pose |"))
    assert line.split("|")[3].strip() == str(len(jobs)) and line.split("|")[4].strip() == expected
    # the same table at the default settings: one job each, t_d 0.3, T_n factor 0.5, 10 x 10
    section = md.split("## By method and posture, at the default settings")[1].split("##")[0]
    line = next(l for l in section.splitlines() if l.startswith("| proposed | t_pose |"))
    expected = f"{spurious_of('proposed', 't_pose', 0.3, 0.5, 10) * 100:.2f}"
    assert line.split("|")[3].strip() == "1" and line.split("|")[4].strip() == expected
    # every picture the markdown names exists
    names = re.findall(r"\]\(img/([^)]+)\)", md)
    assert names and all((root / "rep" / "img" / n).is_file() for n in names)
    for kind in ("heatmap_proposed", "heatmap_simple", "curve_mesh_size", "curve_recon_t_d",
                 "postures", "time", "armpit_l", "crotch"):
        assert any(kind in n for n in names), kind
    # the peer has no heat map, and parameters that are not swept get no curve
    assert not any("heatmap_bpa" in n or "voxel" in n for n in names)


def test_html_is_self_contained(built):
    root, index = built
    page = index.read_text()
    assert "<script" not in page and "<link" not in page
    assert not re.search(r'(src|href)="(?!data:)', page)
    sources = re.findall(r'<img src="data:image/png;base64,([^"]+)"', page)
    assert len(sources) == page.count("<img")
    for data in sources:
        image = Image.open(io.BytesIO(base64.b64decode(data)))
        image.load()
        assert image.width > 50 and image.height > 50


def _chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.fail("headless Chromium is needed to check the report: apt-get install -y chromium")
    return exe


def _chromium_args(exe, profile):
    return [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}"]


CHECK_SCRIPT = """
<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var out = {images: imgs.length,
             loaded: imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length,
             tables: document.querySelectorAll('table').length,
             rows: document.querySelectorAll('tbody tr').length};
  var pre = document.createElement('pre');
  pre.id = 'bodyscan-check';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""


def test_html_opens_in_headless_chromium(built, tmp_path):
    root, index = built
    exe = _chromium()
    # a copy with a checking script (the report itself has none), opened from disk, no network
    probe = tmp_path / "probe.html"
    probe.write_text(index.read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    dom = subprocess.run(_chromium_args(exe, tmp_path / "profile") +
                         ["--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=120)
    found = re.search(r'<pre id="bodyscan-check">([^<]+)</pre>', dom.stdout)
    assert found, dom.stderr[-2000:]
    check = json.loads(found.group(1).replace("&quot;", '"'))
    assert check["images"] >= 10 and check["loaded"] == check["images"]
    assert check["tables"] >= 4 and check["rows"] >= 8
    # and a screenshot of the page as a user sees it
    shot = tmp_path / "shot.png"
    subprocess.run(_chromium_args(exe, tmp_path / "profile") +
                   ["--window-size=1280,2400", f"--screenshot={shot}", index.as_uri()],
                   capture_output=True, text=True, timeout=120)
    pixels = np.asarray(Image.open(shot).convert("L"))
    assert pixels.shape == (2400, 1280)
    assert (pixels < 200).mean() > 0.02      # text, tables and figures, not a blank page


def test_gate_passes_on_itself_and_lists_regressions(tmp_path):
    base_store = fill(tmp_path / "base")
    baseline = report.make_baseline(base_store.read(), sweep="fake")
    assert report.check_gate(base_store.read(), baseline).passed
    # worse within the tolerance (abs 0.005, rel 10 %): still passes
    small = fill(tmp_path / "small", shift=0.004).read()
    assert report.check_gate(small, baseline).passed
    # worse beyond it: one regression per method and posture, naming the metric and values
    worse = fill(tmp_path / "worse", shift=0.05).read()
    result = report.check_gate(worse, baseline)
    assert len(result.regressions) == len(BODIES) * len(ALL_METHODS)
    assert all("spurious_area_fraction" in r for r in result.regressions)
    assert not result.passed and "FAILED" in result.text()
    # better is never a regression
    assert report.check_gate(fill(tmp_path / "better", shift=-0.01).read(), baseline).passed
    # a method/posture that no longer succeeds is a regression
    gone = fill(tmp_path / "gone", drop=[("simple", "t_pose")]).read()
    result = report.check_gate(gone, baseline)
    assert result.regressions == ["simple / t_pose: no successful job (the baseline has 8)"]


def test_gate_fails_on_a_crash_and_notes_a_refusal(tmp_path):
    import pandas as pd

    table = fill(tmp_path / "base").read()
    baseline = report.make_baseline(table, sweep="fake")
    row = table.iloc[0].to_dict()
    refused = {**row, "body": "new_body", "status": "error", "error": "ReconError: the fit explains 49 %"}
    crashed = {**row, "body": "other_body", "status": "error", "error": "IndexError: index 6 is out of bounds"}
    result = report.check_gate(pd.concat([table, pd.DataFrame([refused])], ignore_index=True), baseline)
    assert result.passed and f"{row['method']} / new_body: refused (ReconError: the fit explains 49 %)" in result.notes
    result = report.check_gate(pd.concat([table, pd.DataFrame([crashed])], ignore_index=True), baseline)
    assert result.regressions == [f"{row['method']} / other_body: crashed (IndexError: index 6 is out of bounds)"]
    # a refusal of a posture the baseline holds is a regression (no successful job for it)
    body = row["body"]
    gone = table[~((table["method"] == row["method"]) & (table["body"] == body))]
    result = report.check_gate(pd.concat([gone, pd.DataFrame([{**row, "status": "error",
                                                                 "error": "ReconError: no"}])]), baseline)
    assert any(r.startswith(f"{row['method']} / {body}: no successful job") for r in result.regressions)


def test_gate_tolerances_come_from_the_baseline_file(tmp_path):
    table = fill(tmp_path / "a").read()
    baseline = report.make_baseline(table)
    baseline["tolerances"]["spurious_area_fraction"] = {"better": "lower", "abs": 0.1, "rel": 0}
    assert report.check_gate(fill(tmp_path / "b", shift=0.05).read(), baseline).passed


def test_report_command_gate_and_baseline_update(tmp_path, capsys):
    fill(tmp_path / "base")
    fill(tmp_path / "worse", shift=0.05)
    baseline = tmp_path / "reports" / "baseline.json"
    common = ["--no-pictures", "--baseline", str(baseline)]
    assert bodyscan(["report", str(tmp_path / "worse"), "--out", str(tmp_path / "r0"),
                     "--fail-on-regression", *common]) == 2          # no baseline yet
    assert "--update-baseline" in capsys.readouterr().err
    assert bodyscan(["report", str(tmp_path / "base"), "--out", str(tmp_path / "r1"),
                     "--update-baseline", *common]) == 0
    stored = json.loads(baseline.read_text())
    assert set(stored["metrics"]) == set(ALL_METHODS)
    assert bodyscan(["report", str(tmp_path / "base"), "--out", str(tmp_path / "r2"),
                     "--fail-on-regression", *common]) == 0
    assert "PASSED" in capsys.readouterr().out
    assert bodyscan(["report", str(tmp_path / "worse"), "--out", str(tmp_path / "r3"),
                     "--fail-on-regression", *common]) == 1
    err = capsys.readouterr().err
    assert "FAILED, 6 regression(s)" in err and "proposed / standing: spurious_area_fraction" in err
    assert json.loads((tmp_path / "r3" / "gate.json").read_text())["passed"] is False
    assert "Accuracy gate" in (tmp_path / "r3" / "report.md").read_text()
    # without --fail-on-regression the gate is reported, and the exit code stays 0
    assert bodyscan(["report", str(tmp_path / "worse"), "--out", str(tmp_path / "r4"),
                     *common]) == 0


def test_report_user_errors(tmp_path, capsys):
    assert bodyscan(["report", str(tmp_path / "nothing")]) == 2
    assert "no such sweep folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert bodyscan(["report", str(tmp_path / "empty")]) == 2
    assert "no sweep results" in capsys.readouterr().err
    fill(tmp_path / "s")
    assert bodyscan(["report", str(tmp_path / "s"), "--fail-on-regression"]) == 2
    assert "need --baseline" in capsys.readouterr().err


def test_report_of_only_failures(tmp_path):
    fill(tmp_path / "s", fail=10_000, meshes=0)
    index = report.build_report(tmp_path / "s", tmp_path / "rep")
    assert "Failed jobs" in index.read_text()


def test_best_settings_state_their_objective_and_flat_axes_are_flagged(built, tmp_path):
    """Issue 18: "best settings" by F_seen@5mm within a spurious and bridging budget, the
    objective written out; settings with identical results share a row, distinct ones do not; an
    axis that moves no tracked metric beyond the gate's tolerance is flagged; the worst cases drawn
    are distinct meshes."""
    root, _ = built
    md = (root / "rep" / "report.md").read_text()
    best = md.split("## Best reconstruction settings")[1].split("\n## ")[0]
    assert "Objective: maximise the mean F seen@5mm" in best and "spurious ≤" in best
    first = next(l for l in best.splitlines() if l.startswith("| proposed |"))
    # F depends on t_d alone (0.9 - t_d / 10): t_d 0.1 is best, and within budget (less spurious)
    assert "t_d=0.1" in first and "0.890" in first
    # here every setting's (F, spurious, bridging) differs (spurious moves with t_n, bridging with
    # mesh_theta): the five best are five rows, none merged
    assert len([l for l in best.splitlines() if l.startswith("| proposed |")]) == 5
    assert "identical results" not in best
    # settings differing only in a parameter without effect (mesh_theta below) share a row
    store = ResultStore(tmp_path / "sweep").open_for_writing()
    for body, t_d, mt in itertools.product(BODIES, T_D, (5, 10)):
        job = Job(f"{body}-{t_d}-{mt}".replace(".", "p"), f"s-{body}", body, 0, {"preset": "paper", "k": 1},
                  "proposed", {"t_d": t_d, "mesh_theta": mt})
        row = job.row()
        row.update(status="ok", error=None, spurious_area_fraction=0.02 * t_d / 0.1, bridging_area_fraction=0.004,
                   **{"fscore_seen@5mm": 0.9 - t_d / 10})
        store.put(row)
    store.write_json("meta.json", {"sweep": "flat", "runs": []})
    flat = (report.build_report(tmp_path / "sweep", tmp_path / "rep", pictures=False).parent
            / "report.md").read_text()
    rows = [l for l in flat.split("## Best reconstruction settings")[1].split("\n## ")[0].splitlines()
            if l.startswith("| proposed |")]
    assert len(rows) == len(T_D), rows                  # one row per t_d: its two mesh_theta merged
    assert all("(and 1 more setting(s) with identical results)" in l for l in rows), rows
    assert "t_d=0.1" in rows[0] and "0.890" in rows[0]
    effects = md.split("## Which swept parameters matter")[1].split("\n## ")[0]
    verdicts = {(cells[1].strip(), cells[2].strip()): cells[-2].strip()
                for cells in (l.split("|") for l in effects.splitlines() if l.startswith("| ")
                              and not l.startswith("| parameter"))}
    assert verdicts[("t_n_factor", "proposed")] == "no effect beyond noise"   # spurious +0.2 points
    assert verdicts[("mesh_theta", "proposed")] == "no effect beyond noise"   # bridging +0.1 points
    assert verdicts[("t_d", "proposed")].startswith("moves")


def test_worst_cases_are_distinct_meshes(tmp_path):
    """Three settings of an axis without effect give one mesh under three job ids (the paper
    sweep drew the same mesh three times): the report draws one mesh per scan, its worst."""
    store = ResultStore(tmp_path / "sweep").open_for_writing()
    mesh = trimesh.creation.capsule(height=1.0, radius=0.15, count=[16, 16])
    cases = [("s-standing", "standing", 0.1, 0.05), ("s-standing", "standing", 0.3, 0.05),
             ("s-standing", "standing", 0.5, 0.05), ("s-standing", "standing", 0.7, 0.04),
             ("s-t_pose", "t_pose", 0.1, 0.01)]
    for i, (scan, body, t_n, spurious) in enumerate(cases):
        job = Job(f"job{i}", scan, body, 0, {"preset": "paper"}, "proposed",
                  {"t_d": 0.3, "t_n_factor": t_n})
        row = job.row()
        row.update(status="ok", error=None, spurious_area_fraction=spurious,
                   bridging_area_fraction=0.01, n_faces=len(mesh.faces), **{"fscore_seen@5mm": 0.9})
        store.put(row)
        store.put_mesh(job.job_id, {"vertices": mesh.vertices, "faces": mesh.faces,
                                    "face_section": np.ones(len(mesh.faces), int),
                                    "spurious": np.zeros(len(mesh.faces), bool),
                                    "bridging": np.zeros(len(mesh.faces), bool), "closeups": {}})
    store.write_json("meta.json", {"sweep": "same", "runs": []})
    report.build_report(tmp_path / "sweep", tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    drawn = re.findall(r"!\[#(\d+) proposed / (\w+) \(([^)]*)\)\]", md)
    assert [(n, body) for n, body, _ in drawn] == [("1", "standing"), ("2", "t_pose")], drawn
    assert "t_n_factor=0.1" in drawn[0][2]      # the first of the equally bad settings


def test_against_clean_scan(tmp_path):
    """Jobs on noisy scans beside the same job without noise: known ratios and F changes; a job
    whose clean twin failed is left out."""
    store = ResultStore(tmp_path / "sweep").open_for_writing()
    for body, method, t_d, noise in itertools.product(BODIES, ("proposed", "bpa"), T_D, (0.0, 0.001, 0.002)):
        if method == "bpa" and t_d != T_D[0]:
            continue
        recon = {"t_d": t_d} if method == "proposed" else {}
        job = Job(f"{body}-{method}-{t_d}-{noise}".replace(".", "p"), f"s-{body}-{noise}", body, 0,
                  {"preset": "scanner", "noise_sigma": noise}, method, recon)
        row = job.row()
        clean_spur = 0.01 * t_d / 0.1 if method == "proposed" else 0.02
        failed = method == "bpa" and body == "t_pose" and noise == 0.0
        row.update(status="error" if failed else "ok", error="ReconError" if failed else None,
                   traceback=None, wall_s=1.0, worker="h:1", finished_at=0.0)
        if not failed:
            row.update(spurious_area_fraction=clean_spur * (1 + 400 * noise),
                       bridging_area_fraction=0.0, **{"fscore_seen@5mm": 0.95 - 8 * noise})
        store.put(row)
    store.write_json("meta.json", {"sweep": "noise", "git_commit": "0123456789abcdef", "runs": []})
    table = store.read()
    res = report.against_clean(table[table["status"] == "ok"]).set_index(["method", "condition"])
    one, two = res.loc[("proposed", "noise_sigma=0.001")], res.loc[("proposed", "noise_sigma=0.002")]
    assert one.jobs == two.jobs == 4                   # 2 postures x 2 values of t_d
    assert one.ratio_median == pytest.approx(1.4) and one.ratio_max == pytest.approx(1.4)
    assert two.ratio_max == pytest.approx(1.8)
    assert (one.within_ratio, two.within_ratio) == (4, 0)
    assert one.df_mean == pytest.approx(-0.008) and two.df_worst == pytest.approx(-0.016)
    assert (one.within_f, two.within_f) == (4, 0)          # -0.008 is within 0.01, -0.016 is not
    assert res.loc[("bpa", "noise_sigma=0.001")].jobs == 1   # t_pose's clean scan failed
    md = (report.build_report(tmp_path / "sweep", tmp_path / "rep", pictures=False).parent
          / "report.md").read_text()
    assert "## Against the clean scan" in md and "| proposed | noise_sigma=0.002 | 4 | 1.80, 1.80 | 0/4 |" in md
    assert report.against_clean(table[table["scanner.noise_sigma"] == 0.0]) is None   # nothing swept
