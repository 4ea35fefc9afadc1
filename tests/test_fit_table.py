"""`benchmarks.fit_table`'s rates and its account of bodies the scanner's field cuts."""

import dataclasses

import numpy as np
import pytest

from bodyscan.benchmarks import fit_table


def _row(body, outcome, silent=False, outside=0.0):
    return dict(body=body, condition="k1", outcome=outcome, silent=silent, seconds=1.0, outside_field=outside,
                message="refused", median=0.02, max=0.2 if silent else 0.05, worst_joint="wrist_l", angle=5.0,
                unfitted=(), seen={})


def test_rates_count_met_and_silent_with_wilson_intervals():
    rows = [_row("a", "pass"), _row("b", "part"), _row("c", "fail", silent=True), _row("d", "refused")]
    lo, hi = fit_table.wilson(2, 4)
    slo, shi = fit_table.wilson(1, 4)
    text = fit_table.rates(rows)
    assert f"targets met 2/4 = 0.500 (95% CI {lo:.3f}-{hi:.3f})" in text
    assert f"1/4 = 0.250 (95% CI {slo:.3f}-{shi:.3f})" in text
    # Wilson's interval for 2 of 4 (z = 1.96), computed by hand
    assert (lo, hi) == pytest.approx((0.1500, 0.8500), abs=1e-4)


def test_rates_give_the_share_of_true_joints_the_fits_gave():
    # two fits of 16 true joints giving 14 and 16; a refused run gives none and is not counted
    rows = [{**_row("a", "pass"), "given": 14, "joints": 16}, {**_row("b", "fail"), "given": 16, "joints": 16},
            _row("c", "refused")]
    assert fit_table.rates(rows).endswith("; joints given 30/32 = 0.938")
    assert "joints given" not in fit_table.rates([_row("c", "refused")])


def test_a_run_counts_the_joints_its_fit_gave():
    from bodyscan.poses import load_body

    row = fit_table.run_one(load_body("standing"), "k1", 0.02)
    assert row["joints"] == 16 and row["given"] == len(row["errors"])


def test_summary_gives_the_rates_in_the_field_apart(monkeypatch, capsys):
    rows = {"tall": _row("tall", "fail", silent=True, outside=0.01), "short": _row("short", "pass")}
    monkeypatch.setattr("bodyscan.poses.expand_bodies", lambda names: list(names))
    monkeypatch.setattr("bodyscan.poses.load_body", lambda name: dataclasses.make_dataclass("B", ["name"])(name))
    monkeypatch.setattr(fit_table, "run_one", lambda body, c, res, params, **kw: dict(rows[body.name]))
    assert fit_table.main(["--bodies", "tall,short", "--conditions", "k1"]) == 0
    out = capsys.readouterr().out
    assert "RATES targets met 1/2 = 0.500" in out
    assert "RATES IN FIELD (left out: 1 runs of tall, " in out and "targets met 1/1 = 1.000" in out
    rows["tall"]["outside_field"] = 0.0
    assert fit_table.main(["--bodies", "tall,short", "--conditions", "k1"]) == 0
    assert "IN FIELD" not in capsys.readouterr().out


def test_a_body_beyond_the_field_is_marked():
    # the library's raised arms reach 2.10 m; made 1.2 times larger, 2.53 m, above the `paper`
    # preset's field (z up to 2.4 m): the hands are cut from the scan, and the row says so
    from bodyscan.poses import load_body

    body = load_body("arms_raised")
    tall = dataclasses.replace(body, vertices=body.vertices * 1.2, joints=body.joints * 1.2)
    z = tall.vertices[:, 2]
    row = fit_table.run_one(tall, "k1", 0.02)
    assert row["outside_field"] == pytest.approx(np.mean(z > 2.4), abs=2e-3) and row["outside_field"] > 0
    assert fit_table.run_one(body, "k1", 0.02)["outside_field"] == 0.0


def test_summary_gives_the_rates_per_condition(monkeypatch, capsys):
    rows = {("a", "k1"): _row("a", "pass"), ("b", "k1"): _row("b", "pass"),
            ("a", "k1_turn90"): _row("a", "refused"), ("b", "k1_turn90"): _row("b", "fail", silent=True)}
    monkeypatch.setattr("bodyscan.poses.expand_bodies", lambda names: list(names))
    monkeypatch.setattr("bodyscan.poses.load_body", lambda name: dataclasses.make_dataclass("B", ["name"])(name))
    monkeypatch.setattr(fit_table, "run_one", lambda body, c, res, params, **kw: {**rows[body.name, c], "condition": c})
    assert fit_table.main(["--bodies", "a,b", "--conditions", "k1,k1_turn90"]) == 0
    out = capsys.readouterr().out
    assert "RATES targets met 2/4 = 0.500" in out
    assert "RATES k1: targets met 2/2 = 1.000" in out and "not listed) 0/2 = 0.000" in out
    line = next(s for s in out.splitlines() if s.startswith("RATES k1_turn90: "))
    assert "targets met 0/2 = 0.000" in line and "not listed) 1/2 = 0.500" in line and line.endswith("refused 1/2")
    # one condition: no per-condition line
    assert fit_table.main(["--bodies", "a,b", "--conditions", "k1"]) == 0
    assert "RATES k1:" not in capsys.readouterr().out


def test_jobs_give_the_same_rows(tmp_path):
    # two library bodies fitted in two worker processes: the same rows, in the same order, as one
    # after the other (the seconds aside), each with its per-joint errors
    import json

    args = ["--bodies", "standing,squat", "--conditions", "k1", "--resolution", "0.02"]
    rows = []
    for jobs in ("1", "2"):
        out = tmp_path / f"rows{jobs}.json"
        assert fit_table.main(args + ["--jobs", jobs, "--json", str(out)]) == 0
        rows.append([{k: v for k, v in r.items() if k != "seconds"} for r in json.loads(out.read_text())])
    assert rows[0] == rows[1]
    assert [r["body"] for r in rows[0]] == ["standing", "squat"]
    fitted = [r for r in rows[0] if r["outcome"] != "refused"]
    assert fitted and all(max(r["errors"].values()) == pytest.approx(r["max"]) for r in fitted)


def test_the_preset_and_the_views_reach_the_scan_and_the_fit(monkeypatch):
    # the fit is handed what the named scanner saw: the `scanner` preset's perspective heads (view
    # directions that differ within a head) and its 1 mm range noise (points off the true surface);
    # without views, neither view directions nor heads
    import trimesh

    from bodyscan.poses import load_body
    from bodyscan.recon import ReconError

    seen = {}

    def fit(points, params, view_dir=None, head=None):
        seen.update(points=points, view_dir=view_dir, head=head)
        raise ReconError("recorded")

    monkeypatch.setattr("bodyscan.recon.pipeline.estimate_fit", fit)
    body = load_body("standing")
    mesh = trimesh.Trimesh(body.vertices, body.faces, process=False)
    off = {}
    for preset in ("paper", "scanner"):
        assert fit_table.run_one(body, "k1", 0.02, preset=preset)["outcome"] == "refused"
        front = seen["head"] == seen["head"][0]
        spread = np.ptp(seen["view_dir"][front], axis=0).max()
        off[preset] = np.median(np.abs(trimesh.proximity.signed_distance(mesh, seen["points"][::20])))
        assert (spread > 0.1) == (preset == "scanner")
    assert off["paper"] < 1e-4 and 4e-4 < off["scanner"] < 1.2e-3      # 1 mm sigma: median |e| .67 mm
    fit_table.run_one(body, "k1_noise0", 0.02, preset="scanner")
    assert np.median(np.abs(trimesh.proximity.signed_distance(mesh, seen["points"][::20]))) < 1e-4
    fit_table.run_one(body, "k1", 0.02, views=False)
    assert seen["view_dir"] is None and seen["head"] is None


def test_an_unknown_preset_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        fit_table.main(["--bodies", "standing", "--preset", "scaner"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "use one of paper, scanner" in err and "Traceback" not in err


def test_jobs_below_one_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        fit_table.main(["--jobs", "0"])
    assert e.value.code == 2 and "--jobs must be at least 1" in capsys.readouterr().err


def test_a_bad_param_is_a_usage_error_with_the_nearest_names(capsys):
    with pytest.raises(SystemExit) as e:
        fit_table.main(["--bodies", "standing", "--param", "fit_facng=4"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "did you mean 'fit_facing'" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as e:
        fit_table.main(["--bodies", "standing", "--param", "match_arms_first_retry=1"])
    assert e.value.code == 2 and "removed" in capsys.readouterr().err


@pytest.mark.parametrize("condition", ["k1", "k3", "k1_rot137", "k1_turn90", "k2_turn", "drawn", "k1_noise1",
                                       "k1_turn90_noise0.5", "k1_without-forearm_l+upper_arm_l_noise1"])
def test_every_documented_condition_passes_the_check(condition):
    fit_table.check_condition(condition, 0.01, "paper")
    fit_table.check_condition(condition, 0.002, "scanner")
