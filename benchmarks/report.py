"""Reports of a sweep: ``report.md`` and a self-contained ``index.html``, and the CI accuracy gate.

`build_report` reads a sweep folder (see `benchmarks.store`) and writes, in the report folder:

- ``report.md``: tables (by method, by method and posture, the best settings, failures) and the
  figures as PNG files under ``img/``;
- ``index.html``: the same, opening offline: every image is inlined as a base64 data URI, the
  style sheet is inline, there is no script;
- ``gate.json``: the accuracy gate's verdict when a baseline was given.

Figures (matplotlib): heat maps of spurious and bridging area over T_d x T_n factor, curves of the
metrics over every other swept parameter (the (theta, h) mesh size among them), per-posture bars per
method, and the time of each stage. Pictures of reconstructions (`benchmarks.render`): the meshes a
sweep keeps (per method, the worst jobs by spurious + bridging area; ``keep_meshes`` in the sweep
file) are drawn worst first, sections in colour and spurious or bridging triangles in red, with
armpit and crotch close-ups. Keeping the meshes at sweep time, rather than recomputing the worst
cases now, is what keeps a report within seconds.

The accuracy gate compares, per method and posture, the mean of each tracked metric (`TRACKED`)
with a baseline file and lists every one that got worse than its tolerance allows.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import BenchError
from .store import ResultStore

#: Metrics the gate tracks: name -> (better, absolute tolerance, relative tolerance). A value is a
#: regression when it is worse than the baseline by more than max(absolute, relative * |baseline|).
TRACKED = {
    "spurious_area_fraction": ("lower", 0.005, 0.10),
    "bridging_area_fraction": ("lower", 0.002, 0.10),
    "fscore_seen@5mm": ("higher", 0.01, 0.0),
    "section_accuracy": ("higher", 0.01, 0.0),
    "joint_error_median_m": ("lower", 0.005, 0.10),
}

#: Metrics shown in the tables, in order: name -> (label, scale, digits). Fractions in percent.
SHOWN = {
    "spurious_area_fraction": ("spurious %", 100, 2),
    "bridging_area_fraction": ("bridging %", 100, 2),
    "bridging_area_cm2": ("bridging cm²", 1, 1),
    "fscore_seen@5mm": ("F seen@5mm", 1, 3),
    "recall_full@5mm": ("recall full@5mm", 1, 3),
    "chamfer_l1_mm": ("Chamfer-L1 mm", 1, 2),
    "section_accuracy": ("section acc.", 1, 3),
    "joint_error_median_m": ("joint err. mm", 1000, 1),
    "time_total_s": ("recon s (fit apart)", 1, 2),
}
#: Columns of the best-settings table.
SHOWN_SHORT = ("spurious_area_fraction", "bridging_area_fraction", "fscore_seen@5mm",
               "section_accuracy")
#: Derived column: seconds of a job after the stages its scan shares (scan, posture fit): its
#: ``time_total_s`` (`benchmarks.bench.evaluate` reports the shared fit apart, as ``time_fit_s``).
OWN_TIME = "time_own_s"

#: Metrics where a larger value is better (the rest: smaller is better).
HIGHER_IS_BETTER = {"precision@5mm", "recall_full@5mm", "recall_seen@5mm", "fscore_seen@5mm",
                    "fscore_full@5mm", "precision@10mm", "recall_full@10mm", "recall_seen@10mm",
                    "fscore_seen@10mm", "fscore_full@10mm", "normal_consistency",
                    "section_accuracy"}

_PICTURE_LIMIT = 6        # kept meshes drawn at most (worst first)
_VIEW_SIZE = (360, 540)   # pixels per full-body view
_CLOSE_SIZE = (360, 360)  # pixels per close-up


# -- the gate -----------------------------------------------------------------------------------

@dataclass
class GateResult:
    """The accuracy gate's verdict: ``regressions`` (one line each) and ``notes``."""

    regressions: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    compared: int = 0

    @property
    def passed(self) -> bool:
        return not self.regressions

    def text(self, baseline_path="the baseline") -> str:
        head = (f"accuracy gate: PASSED ({self.compared} values compared with {baseline_path})"
                if self.passed else
                f"accuracy gate: FAILED, {len(self.regressions)} regression(s) against "
                f"{baseline_path}:")
        lines = [head] + [f"  - {r}" for r in self.regressions]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


#: Errors that are a method's honest answer ("this cloud cannot be reconstructed"), not a defect:
#: a job failing with one is a refusal; any other error is a crash, which the gate fails on.
REFUSALS = ("ReconError",)


def _keyed(table):
    """``table`` with ``body`` keyed ``"name [preset]"`` for presets other than ``paper``."""
    import numpy as np

    if "scanner.preset" not in table.columns:
        return table
    preset = table["scanner.preset"].fillna("paper").astype(str)
    return table.assign(body=np.where(preset == "paper", table["body"].astype(str),
                                      table["body"].astype(str) + " [" + preset + "]"))


def tracked_values(table) -> dict:
    """{method: {posture: {metric: mean over the ok jobs, "n_jobs": count}}} of `TRACKED`; a
    posture scanned with a preset other than ``paper`` is keyed ``"name [preset]"``."""
    ok = _keyed(table[table["status"] == "ok"])
    out: dict = {}
    for (method, body), group in ok.groupby(["method", "body"], sort=True):
        values = {"n_jobs": int(len(group))}
        for metric in TRACKED:
            if metric in group.columns:
                column = group[metric].astype(float)
                values[metric] = float(column.mean()) if column.notna().any() else None
        out.setdefault(str(method), {})[str(body)] = values
    return out


def make_baseline(table, *, sweep: str = "", commit: str | None = None) -> dict:
    """The baseline file's content for ``table``: tracked means and the tolerances used."""
    return {
        "format": "bodyscan-baseline-1",
        "sweep": sweep, "git_commit": commit, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "tolerances": {m: {"better": b, "abs": a, "rel": r} for m, (b, a, r) in TRACKED.items()},
        "metrics": tracked_values(table),
    }


def check_gate(table, baseline: dict) -> GateResult:
    """Compare ``table`` with a baseline (see `make_baseline`).

    A tracked metric of a (method, posture) of the baseline is a regression when it is worse than
    the baseline by more than its tolerance (the baseline file's own ``tolerances`` win over
    `TRACKED`), when it is missing or NaN now, or when the (method, posture) has no successful job.
    A job that crashed (an error other than a `REFUSALS` one) is a regression wherever it is; a
    refusal of a (method, posture) the baseline does not hold is a note.
    """
    current = tracked_values(table)
    result = GateResult()
    failed = _keyed(table[table["status"] != "ok"])
    for row in failed.itertuples():
        error = str(getattr(row, "error", "") or "unknown error").strip().splitlines()[0][:300]
        kind = error.split(":", 1)[0].strip()
        if kind in REFUSALS:
            if row.body not in (baseline.get("metrics") or {}).get(row.method, {}):
                result.notes.append(f"{row.method} / {row.body}: refused ({error})")
        else:
            result.regressions.append(f"{row.method} / {row.body}: crashed ({error})")
    tolerances = {m: {"better": b, "abs": a, "rel": r} for m, (b, a, r) in TRACKED.items()}
    tolerances.update(baseline.get("tolerances") or {})
    for method, bodies in sorted((baseline.get("metrics") or {}).items()):
        for body, base_values in sorted(bodies.items()):
            now = current.get(method, {}).get(body)
            if now is None:
                result.regressions.append(f"{method} / {body}: no successful job (the baseline "
                                          f"has {base_values.get('n_jobs', '?')})")
                continue
            if base_values.get("n_jobs") not in (None, now["n_jobs"]):
                result.notes.append(f"{method} / {body}: {now['n_jobs']} jobs now, "
                                    f"{base_values['n_jobs']} in the baseline")
            for metric, base in sorted(base_values.items()):
                if metric == "n_jobs" or base is None or metric not in tolerances:
                    continue
                tol = tolerances[metric]
                value = now.get(metric)
                result.compared += 1
                if value is None or not math.isfinite(value):
                    result.regressions.append(f"{method} / {body}: {metric} is missing now "
                                              f"(baseline {base:.4g})")
                    continue
                worse = (value - base) if tol["better"] == "lower" else (base - value)
                allowed = max(float(tol["abs"]), float(tol["rel"]) * abs(base))
                if worse > allowed:
                    result.regressions.append(
                        f"{method} / {body}: {metric} {base:.4g} -> {value:.4g} "
                        f"(worse by {worse:.4g}; tolerance {allowed:.4g})")
    for method, bodies in sorted(current.items()):
        for body in sorted(bodies):
            if body not in (baseline.get("metrics") or {}).get(method, {}):
                result.notes.append(f"{method} / {body}: not in the baseline (not gated)")
    return result


# -- the report ---------------------------------------------------------------------------------

@dataclass
class _Doc:
    """The report being written, as parallel Markdown and HTML parts; figures as PNG bytes."""

    md: list = field(default_factory=list)
    html: list = field(default_factory=list)
    images: dict = field(default_factory=dict)

    def heading(self, text, level=2):
        self.md.append(f"{'#' * level} {text}\n")
        self.html.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def para(self, text):
        self.md.append(text + "\n")
        self.html.append(f"<p>{html.escape(text)}</p>")

    def table(self, header, rows, caption=None):
        if caption:
            self.para(caption)
        md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        md += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
        self.md.append("\n".join(md) + "\n")
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                       for row in rows)
        self.html.append(f'<div class="scroll"><table><thead><tr>{head}</tr></thead>'
                         f"<tbody>{body}</tbody></table></div>")

    def image(self, name, png: bytes, alt, width=None):
        self.images[name] = png
        self.md.append(f"![{alt}](img/{name})\n")
        data = base64.b64encode(png).decode("ascii")
        style = f' style="max-width:{width}px"' if width else ""
        self.html.append(f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(alt)}"'
                         f'{style}><figcaption>{html.escape(alt)}</figcaption></figure>')

    def pre(self, text):
        self.md.append("```\n" + text + "\n```\n")
        self.html.append(f"<pre>{html.escape(text)}</pre>")


_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222;padding:0 1em}
table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f0f0f0} td:first-child,td:nth-child(2){text-align:left}
figure{display:inline-block;margin:.5em;vertical-align:top} figcaption{font-size:.85em;color:#555}
img{max-width:100%;height:auto;border:1px solid #eee}
pre{background:#f7f7f7;padding:.8em;overflow-x:auto}
.scroll{overflow-x:auto}
"""


def build_report(sweep_dir, out, *, pictures: bool = True, gate: GateResult | None = None,
                 baseline_path=None) -> Path:
    """Write ``report.md``, ``index.html`` and ``img/*.png`` for a sweep folder.

    Parameters
    ----------
    sweep_dir : str or Path
        A sweep folder (``bodyscan sweep --out``).
    out : str or Path
        The report folder (created).
    pictures : bool
        Render the kept meshes (`benchmarks.render`).
    gate : GateResult, optional
        Shown at the top when given.

    Returns
    -------
    Path
        ``out / "index.html"``.
    """
    import pandas as pd

    store = ResultStore(sweep_dir)
    table = store.read()
    meta = store.read_json("meta.json")
    out = Path(out)
    name = meta.get("sweep") or Path(sweep_dir).name
    ok = table[table["status"] == "ok"].copy()
    failed = table[table["status"] != "ok"]
    doc = _Doc()
    doc.heading(f"Sweep report: {name}", 1)
    commit = meta.get("git_commit") or "unknown"
    doc.para(f"{len(table)} jobs: {len(ok)} succeeded, {len(failed)} failed; "
             f"{table['body'].nunique()} posture(s), {table['method'].nunique()} method(s). "
             f"Sweep folder {Path(sweep_dir)}; code {commit[:12]}; report written "
             f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}.")
    if gate is not None:
        doc.heading("Accuracy gate")
        doc.pre(gate.text(baseline_path or "the baseline"))

    metrics = [m for m in SHOWN if m in ok.columns and ok[m].notna().any()]
    if len(ok) and metrics:
        doc.heading("By method")
        rows = []
        for method, group in ok.groupby("method", sort=True):
            row = [method, len(group)]
            for m in metrics:
                worst = group[m].min() if m in HIGHER_IS_BETTER else group[m].max()
                row.append(f"{_fmt(m, group[m].mean())} ({_fmt(m, worst)})")
            rows.append(row)
        doc.table(["method", "jobs"] + [SHOWN[m][0] for m in metrics], rows,
                  "Mean over every successful job (worst job in brackets).")
        doc.heading("By method and posture")
        rows = []
        for (method, body), group in ok.groupby(["method", "body"], sort=True):
            rows.append([method, body, len(group)] + [_fmt(m, group[m].mean()) for m in metrics])
        doc.table(["method", "posture", "jobs"] + [SHOWN[m][0] for m in metrics], rows,
                  "Mean over the jobs of each method and posture (all swept settings).")
        _at_defaults(doc, ok, metrics)
        _best_settings(doc, ok, metrics)
        _axis_effects(doc, ok)
        _against_clean(doc, ok)
        _figures(doc, ok, pd)
    if pictures:
        _pictures(doc, store, table)
    if len(failed):
        doc.heading(f"Failed jobs ({len(failed)})")
        rows = [[r.method, r.body, _settings(r), str(r.error).splitlines()[0][:160]]
                for r in failed.head(50).itertuples()]
        doc.table(["method", "posture", "settings", "error"], rows,
                  "Tracebacks are in the results table (column traceback)."
                  + (" First 50 shown." if len(failed) > 50 else ""))
    if "warnings" in table.columns and table["warnings"].notna().any():
        counts: dict = {}
        for text in table["warnings"].dropna():
            for line in set(str(text).splitlines()):
                counts[line] = counts.get(line, 0) + 1
        rows = sorted(counts.items(), key=lambda kv: -kv[1])[:20]
        doc.heading("Warnings")
        doc.table(["jobs", "warning"], [[n, w[:200]] for w, n in rows],
                  "Warnings raised while running the jobs (column warnings of the results).")
    doc.heading("Provenance")
    doc.pre(json.dumps({k: meta.get(k) for k in ("sweep", "runner", "git_commit", "versions",
                                                  "python", "host", "runs")},
                       indent=2, default=str))

    from bodyscan._io import write_bytes, write_text

    out.mkdir(parents=True, exist_ok=True)
    (out / "img").mkdir(exist_ok=True)
    for image_name, png in doc.images.items():
        write_bytes(out / "img" / image_name, png)
    write_text(out / "report.md", "\n".join(doc.md))
    page = (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>Sweep report: {html.escape(name)}</title><style>{_CSS}</style></head>"
            f"<body>{''.join(doc.html)}</body></html>")
    write_text(out / "index.html", page)
    return out / "index.html"


def _fmt(metric, value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    _, scale, digits = SHOWN.get(metric, ("", 1, 3))
    return f"{float(value) * scale:.{digits}f}"


def _param_columns(table) -> list:
    """Parameter columns (``scanner.*``, ``recon.*``) that take more than one value."""
    cols = [c for c in table.columns if c.startswith(("scanner.", "recon."))]
    return [c for c in cols if table[c].dropna().astype(str).nunique() > 1]


def _settings(row) -> str:
    parts = []
    for key in ("scanner_json", "recon_json"):
        try:
            parts += [f"{k}={v}" for k, v in json.loads(getattr(row, key)).items()]
        except (TypeError, ValueError, AttributeError):
            pass
    return ", ".join(parts)


def _at_defaults(doc, ok, metrics):
    """The by-posture table again, for the jobs whose swept reconstruction parameters have their
    default values (the paper's, where it gives them): the paper's experiment within the sweep."""
    swept = [c for c in _param_columns(ok) if c.startswith("recon.")]
    if not swept:
        return
    try:
        from bodyscan.recon import ReconParams
        defaults = ReconParams().to_dict()
    except ImportError:
        return
    mask = np.ones(len(ok), bool)
    for column in swept:
        default = defaults.get(column[len("recon."):])
        if default is None or isinstance(default, (tuple, list, dict)):
            return
        values = ok[column]
        mask &= (values.isna() | (values.astype(object) == default)).to_numpy()
    chosen = ok[mask]
    if not len(chosen):
        return
    names = ", ".join(f"{c[len('recon.'):]}={defaults[c[len('recon.'):]]}" for c in swept)
    doc.heading("By method and posture, at the default settings")
    rows = [[method, body, len(group)] + [_fmt(m, group[m].mean()) for m in metrics]
            for (method, body), group in chosen.groupby(["method", "body"], sort=True)]
    doc.table(["method", "posture", "jobs"] + [SHOWN[m][0] for m in metrics], rows,
              f"The jobs whose swept parameters have their defaults ({names}).")


#: The objective of "best settings": maximise this, within the budgets of `BUDGETED`.
OBJECTIVE = "fscore_seen@5mm"
#: Metrics held to a budget: a setting is allowed when its mean is no worse than the default
#: settings' mean plus the CI gate's tolerance (`TRACKED`).
BUDGETED = ("spurious_area_fraction", "bridging_area_fraction")


def _is_default(method: str, spec: str, setting: dict) -> bool:
    """Whether ``setting`` gives every parameter it names its default value (recon's defaults
    for proposed and simple, the function's own for a method of yours)."""
    try:
        if method in ("proposed", "simple") or not spec:
            from bodyscan.recon import ReconParams
            defaults = ReconParams().to_dict()
        else:
            from .methods import resolve
            defaults = resolve(spec).defaults()
    except Exception:
        return False
    return all(k in defaults and _same(defaults[k], v) for k, v in setting.items())


def _same(a, b) -> bool:
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return str(a) == str(b)


def _budget(metric, reference) -> float:
    better, absolute, relative = TRACKED[metric]
    return reference + max(absolute, relative * abs(reference))


def _best_settings(doc, ok, metrics):
    """Reconstruction settings ranked by the stated objective: the largest mean F_seen@5mm among
    the settings whose spurious and bridging area stay within budget; settings with identical
    results share a row."""
    if "recon_json" not in ok.columns or ok["recon_json"].nunique() < 2:
        return
    need = [OBJECTIVE, *BUDGETED]
    if not all(m in ok.columns for m in need):
        return
    doc.heading("Best reconstruction settings")
    shown = [m for m in metrics if m in SHOWN_SHORT]
    rows, notes = [], []
    for method, group in ok.groupby("method", sort=True):
        if group["recon_json"].nunique() < 2:
            continue
        spec = group["method_spec"].dropna().iloc[0] if "method_spec" in group.columns and \
            group["method_spec"].notna().any() else ""
        # per setting: mean over postures (each the mean over its scanner settings and seeds)
        per_body = group.groupby(["recon_json", "body"])[list(dict.fromkeys(need + shown))].mean()
        means = per_body.groupby(level="recon_json").mean()
        defaults = [j for j in means.index if _is_default(method, spec, json.loads(j))]
        if defaults:
            reference, where = means.loc[defaults[0]], "the default settings"
        else:
            reference, where = means.median(), "the median setting"
        budget = {m: _budget(m, float(reference[m])) for m in BUDGETED}
        allowed = np.logical_and.reduce([means[m] <= budget[m] for m in BUDGETED])
        notes.append(f"{method}: spurious ≤ {100 * budget[BUDGETED[0]]:.2f} %, bridging ≤ "
                     f"{100 * budget[BUDGETED[1]]:.2f} % ({where} plus the gate's tolerance); "
                     f"{int(allowed.sum())} of {len(means)} settings within budget")
        ranked = means[allowed].sort_values(OBJECTIVE, ascending=False)
        groups: dict = {}
        for recon_json, row in ranked.iterrows():     # identical results: one row
            key = tuple(np.round(row[need].to_numpy(dtype=float), 12))
            groups.setdefault(key, []).append((recon_json, row))
        for members in list(groups.values())[:5]:
            recon_json, row = members[0]
            settings = ", ".join(f"{k}={v}" for k, v in json.loads(recon_json).items()) or "defaults"
            if len(members) > 1:
                settings += f" (and {len(members) - 1} more setting(s) with identical results)"
            rows.append([method, settings] + [_fmt(m, row[m]) for m in shown])
    if not rows:
        return
    doc.para(f"Objective: maximise the mean {SHOWN[OBJECTIVE][0]} over postures (each posture the "
             "mean of its scanner settings and seeds), among the settings whose mean spurious "
             "and bridging area are no worse than the reference's plus the CI gate's tolerance "
             "(spurious: 0.5 points or 10 %, bridging: 0.2 points or 10 %, whichever is larger). "
             "Budgets: " + "; ".join(notes) + ".")
    doc.table(["method", "settings"] + [SHOWN[m][0] for m in shown], rows,
              "Per method, the five best distinct results within budget, best first.")


def _axis_effects(doc, ok):
    """Per swept parameter and method, how far its levels move the tracked metrics; an axis that
    moves none of them by more than the CI gate's absolute tolerance is flagged: no effect
    beyond noise."""
    axes = [c for c in _param_columns(ok) if c.startswith("recon.")]
    tracked = [m for m in (OBJECTIVE, *BUDGETED) if m in ok.columns]
    if not axes or not tracked:
        return
    rows = []
    for axis in axes:
        for method, group in ok.groupby("method", sort=True):
            levels = group[axis].dropna()
            if levels.astype(str).nunique() < 2:
                continue
            means = group.groupby(group[axis].astype(str))[tracked].mean()
            spread = (means.max() - means.min())
            moved = [m for m in tracked if spread[m] > TRACKED[m][1]]
            identical = bool((spread.abs() < 1e-12).all())
            verdict = ("no effect: identical results" if identical else
                       "no effect beyond noise" if not moved else
                       "moves " + ", ".join(SHOWN[m][0] for m in moved))
            rows.append([axis[len("recon."):], method, len(means)]
                        + [_fmt(m, spread[m]) for m in tracked] + [verdict])
    if not rows:
        return
    doc.heading("Which swept parameters matter")
    doc.table(["parameter", "method", "levels"] + [f"{SHOWN[m][0]} range" for m in tracked]
              + ["verdict"], rows,
              "Range: the largest minus the smallest mean over the parameter's levels (each level "
              "averaged over every other setting and posture). Noise: a range within the CI "
              "gate's absolute tolerance (F 0.01, spurious 0.5 points, bridging 0.2 points) is "
              "no effect beyond noise.")


#: Scanner conditions a clean scan lacks (`simulator.ScannerConfig`): at their lowest level a scan
#: is the reference the others are measured against (`_against_clean`).
CONDITIONS = ("scanner.noise_sigma", "scanner.outlier_fraction", "scanner.misalign_deg",
              "scanner.misalign_mm")
#: Budgets against the clean scan (issue 19): spurious area at most this many times the clean
#: scan's, and F_seen@5mm at most this far below it.
SPURIOUS_RATIO, F_DROP = 1.5, 0.01


def against_clean(table):
    """Each job of a swept scanner condition (`CONDITIONS`) beside the same job on the clean scan.

    The clean scan is the same method, posture, seed and other settings with every swept
    condition at its lowest level in ``table`` (the successful jobs of a sweep). Returns a
    DataFrame with a row per method and level, over the jobs that have a clean twin:
    ``method``, ``condition`` (the levels, as text), ``jobs``, ``ratio_median``, ``ratio_max``
    (spurious area over the clean scan's), ``within_ratio`` (jobs within `SPURIOUS_RATIO`),
    ``df_mean``, ``df_worst`` (F_seen@5mm minus the clean scan's) and ``within_f`` (jobs within
    `F_DROP`); None when no condition is swept.
    """
    import numpy as np
    import pandas as pd

    swept = _param_columns(table)
    axes = [c for c in CONDITIONS if c in swept]
    spur, f = "spurious_area_fraction", "fscore_seen@5mm"
    if not axes or spur not in table.columns or f not in table.columns:
        return None
    rest = [c for c in swept if c not in axes]
    keys = ["method", "body", "seed"] + rest
    t = table.copy()
    for c in keys:                       # NaN (a setting a method does not take) groups as text
        t[c] = t[c].map(str)
    level = t[axes].astype(float)
    clean = (level == level.min()).all(axis=1)
    ref = t[clean].drop_duplicates(keys).set_index(keys)[[spur, f]]
    other = t[~clean].join(ref.add_suffix("_clean"), on=keys, how="inner")
    if other.empty:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        other["ratio"] = np.where(other[spur + "_clean"] > 0, other[spur] / other[spur + "_clean"],
                                  np.where(other[spur] > 0, np.inf, 1.0))
    other["df"] = other[f] - other[f + "_clean"]
    other["condition"] = other[axes].astype(float).apply(
        lambda r: ", ".join(f"{a[len('scanner.'):]}={v:g}" for a, v in r.items()), axis=1)
    rows = []
    for (method, cond), g in other.groupby(["method", "condition"], sort=True):
        rows.append(dict(method=method, condition=cond, jobs=len(g),
                         ratio_median=float(g["ratio"].median()), ratio_max=float(g["ratio"].max()),
                         within_ratio=int((g["ratio"] <= SPURIOUS_RATIO).sum()),
                         df_mean=float(g["df"].mean()), df_worst=float(g["df"].min()),
                         within_f=int((g["df"] >= -F_DROP).sum())))
    return pd.DataFrame(rows)


def _against_clean(doc, ok):
    """The report's section of `against_clean`."""
    res = against_clean(ok)
    if res is None:
        return
    doc.heading("Against the clean scan")
    doc.table(["method", "condition", "jobs", "spurious x clean (median, worst)",
               f"within {SPURIOUS_RATIO:g}x", "ΔF (mean, worst)", f"within {F_DROP:g} F"],
              [[r.method, r.condition, r.jobs, f"{r.ratio_median:.2f}, {r.ratio_max:.2f}",
                f"{r.within_ratio}/{r.jobs}", f"{r.df_mean:+.4f}, {r.df_worst:+.4f}",
                f"{r.within_f}/{r.jobs}"] for r in res.itertuples()],
              "Each job beside the same method, posture, seed and settings on the clean scan (the "
              "swept conditions at their lowest level): its spurious area over the clean scan's, "
              "and its F_seen@5mm minus the clean scan's. A job whose clean twin failed is left out.")


# -- figures ------------------------------------------------------------------------------------

def _png(fig) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    buffer = io.BytesIO()
    FigureCanvasAgg(fig)
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def _figures(doc, ok, pd):
    from matplotlib.figure import Figure

    methods = sorted(ok["method"].unique())
    if "time_total_s" in ok.columns:   # the job's own time: bench's total leaves the shared fit out
        ok[OWN_TIME] = ok["time_total_s"]
    area = [m for m in ("spurious_area_fraction", "bridging_area_fraction") if m in ok.columns]
    params = _param_columns(ok)
    mesh_axis = None
    if {"recon.mesh_theta", "recon.mesh_h"} <= set(ok.columns) and \
            ({"recon.mesh_theta", "recon.mesh_h"} & set(params)):
        theta, h = ok["recon.mesh_theta"], ok["recon.mesh_h"]
        ok["mesh size"] = [f"{int(a)}x{int(b)}" if pd.notna(a) and pd.notna(b) else "default"
                           for a, b in zip(theta, h)]
        mesh_axis = "mesh size"
        params = [p for p in params if p not in ("recon.mesh_theta", "recon.mesh_h")]

    # heat maps over T_d x T_n factor
    if area and {"recon.t_d", "recon.t_n_factor"} <= set(params):
        doc.heading("Spurious and bridging area over T_d and the T_n factor")
        for method in methods:
            group = ok[ok["method"] == method]
            fig = Figure(figsize=(5.2 * len(area), 4.2), layout="constrained")
            for i, metric in enumerate(area):
                grid = group.pivot_table(index="recon.t_n_factor", columns="recon.t_d",
                                         values=metric, aggfunc="mean") * 100
                if grid.empty:      # a method without these parameters (a peer)
                    break
                ax = fig.add_subplot(1, len(area), i + 1)
                image = ax.imshow(grid.values, origin="lower", cmap="magma_r", aspect="auto")
                ax.set_xticks(range(len(grid.columns)), [f"{v:g}" for v in grid.columns])
                ax.set_yticks(range(len(grid.index)), [f"{v:g}" for v in grid.index])
                ax.set_xlabel("T_d (fraction of section width)")
                ax.set_ylabel("T_n factor")
                ax.set_title(f"{method}: {SHOWN[metric][0]}")
                for (r, c), v in np.ndenumerate(grid.values):
                    if np.isfinite(v):
                        ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=7,
                                color="white" if v > np.nanmean(grid.values) else "black")
                fig.colorbar(image, ax=ax, label="% of the mesh area")
            if not fig.axes:
                continue
            doc.image(f"heatmap_{_safe(method)}.png", _png(fig),
                      f"{method}: spurious and bridging area (%) over T_d and T_n factor "
                      "(mean over postures and other settings)")
    # curves over every other swept parameter (mesh size first)
    curve_metrics = [m for m in ("spurious_area_fraction", "bridging_area_fraction",
                                 "fscore_seen@5mm", OWN_TIME) if m in ok.columns]
    axes = ([mesh_axis] if mesh_axis else []) + params
    if curve_metrics and axes:
        doc.heading("Metrics over the swept parameters")
    for axis in axes:
        fig = Figure(figsize=(3.6 * len(curve_metrics), 3.2), layout="constrained")
        for i, metric in enumerate(curve_metrics):
            ax = fig.add_subplot(1, len(curve_metrics), i + 1)
            _, scale, _ = SHOWN.get(metric, ("", 1, 2))
            for method in methods:
                group = ok[ok["method"] == method]
                stats = group.groupby(axis)[metric].agg(["mean", "min", "max"])
                stats = stats.loc[_sorted_values(stats.index)]
                x = np.arange(len(stats))
                ax.plot(x, stats["mean"] * scale, marker="o", label=method)
                ax.fill_between(x, stats["min"] * scale, stats["max"] * scale, alpha=0.15)
                ax.set_xticks(x, [_tick(v) for v in stats.index])
            ax.set_xlabel(axis.split(".", 1)[-1])
            ax.set_title("reconstruction s (fit excluded)" if metric == OWN_TIME
                         else SHOWN[metric][0])
            ax.grid(alpha=0.3)
        fig.axes[0].legend(fontsize=8)
        doc.image(f"curve_{_safe(axis)}.png", _png(fig),
                  f"Metrics over {axis} (mean; band: min to max over the other settings)")
    # per-posture bars per method
    bar_metrics = [m for m in ("spurious_area_fraction", "bridging_area_fraction",
                               "fscore_seen@5mm") if m in ok.columns]
    if bar_metrics:
        doc.heading("Per posture")
        bodies = sorted(ok["body"].unique())
        width_in = max(6.0, 0.55 * len(bodies) * len(methods) + 2)
        fig = Figure(figsize=(width_in, 2.8 * len(bar_metrics)), layout="constrained")
        width = 0.8 / len(methods)
        for i, metric in enumerate(bar_metrics):
            ax = fig.add_subplot(len(bar_metrics), 1, i + 1)
            _, scale, _ = SHOWN[metric]
            for j, method in enumerate(methods):
                means = ok[ok["method"] == method].groupby("body")[metric].mean()
                ax.bar(np.arange(len(bodies)) + j * width,
                       [means.get(b, np.nan) * scale for b in bodies], width, label=method)
            ax.set_xticks(np.arange(len(bodies)) + 0.4 - width / 2, bodies, rotation=30, ha="right",
                          fontsize=8)
            ax.set_ylabel(SHOWN[metric][0])
            ax.grid(axis="y", alpha=0.3)
        fig.axes[0].legend(fontsize=8, ncol=len(methods))
        doc.image("postures.png", _png(fig), "Per posture and method (mean over the settings)")
    # time per stage
    stages = [c for c in ok.columns if c.startswith("time_") and c.endswith("_s")
              and c != "time_total_s" and ok[c].notna().any()
              and not (c.startswith("time_fit_") and c != "time_fit_s")]   # fit's sub-stages
    if stages:
        doc.heading("Time per stage")
        fig = Figure(figsize=(8, 0.6 * len(methods) + 1.8), layout="constrained")
        ax = fig.add_subplot(1, 1, 1)
        left = np.zeros(len(methods))
        for stage in stages:
            means = np.array([ok.loc[ok["method"] == m, stage].mean() for m in methods])
            means = np.nan_to_num(means)
            ax.barh(methods, means, left=left, label=stage[5:-2])
            left += means
        ax.set_xlabel("seconds per job (mean)")
        ax.legend(fontsize=8, ncol=len(stages), loc="lower left", bbox_to_anchor=(0, 1))
        doc.image("time.png", _png(fig), "Mean time of each stage per job (the stages shared by "
                  "the jobs of one scan, scan and posture fit, are drawn with each job, although "
                  "they ran once per scan)")


def _sorted_values(index) -> list:
    try:
        return sorted(index, key=lambda v: (float(str(v).split("x")[0]), str(v)))
    except ValueError:
        return sorted(index, key=str)


def _tick(value) -> str:
    return f"{value:g}" if isinstance(value, (float, np.floating)) else str(value)


def _safe(text) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(text))


# -- pictures -----------------------------------------------------------------------------------

def _pictures(doc, store: ResultStore, table):
    from .render import render_mesh, section_face_colors

    ids = store.mesh_ids()
    if not ids:
        return
    rows = table[table["job_id"].isin(ids)].copy()
    if not len(rows):
        return
    bad = sum(rows[c].fillna(0) for c in ("spurious_area_fraction", "bridging_area_fraction")
              if c in rows.columns)
    rows = rows.assign(_bad=bad).sort_values("_bad", ascending=False)
    # distinct cases: one mesh per method and scan, its worst setting (settings without effect
    # give the same mesh under several job ids)
    same = [c for c in ("method", "scan_id") if c in rows.columns] or ["method", "body", "_bad"]
    rows = rows.drop_duplicates(same).head(_PICTURE_LIMIT)
    doc.heading("Reconstructions, worst first")
    doc.para("One mesh per method and scan (its worst setting), worst first (spurious + "
             "bridging area). Sections in colour as in "
             "the key under each picture; spurious or bridging triangles in red. Close-ups show "
             "the slab around each armpit and the crotch, seen from the front.")
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        for rank, row in enumerate(rows.itertuples(), 1):
            mesh = store.get_mesh(row.job_id)
            red = np.zeros(len(mesh["faces"]), bool)
            for key in ("spurious", "bridging"):
                if key in mesh:
                    red |= mesh[key].astype(bool)
            colors = section_face_colors(mesh.get("face_section", np.full(len(red), -1)), red)
            spurious = _fmt("spurious_area_fraction", getattr(row, "spurious_area_fraction", None))
            bridging = _fmt("bridging_area_fraction", getattr(row, "bridging_area_fraction", None))
            title = (f"#{rank} {row.method} / {row.body}: spurious {spurious} %, "
                     f"bridging {bridging} %")
            settings = _settings(row)
            path = render_mesh(mesh["vertices"], mesh["faces"], colors, Path(tmp) / "full.png",
                               views=("front", "side", "back"), size=_VIEW_SIZE, title=title)
            doc.image(f"mesh_{rank}_{row.job_id}.png", path.read_bytes(),
                      f"#{rank} {row.method} / {row.body} ({settings})")
            for name, (center, radius) in sorted(mesh.get("closeups", {}).items()):
                path = render_mesh(mesh["vertices"], mesh["faces"], colors, Path(tmp) / "c.png",
                                   views=("front",), size=_CLOSE_SIZE,
                                   close_up=(center, radius))
                doc.image(f"mesh_{rank}_{row.job_id}_{_safe(name)}.png", path.read_bytes(),
                          f"#{rank} {name}", width=_CLOSE_SIZE[0])


# -- the command --------------------------------------------------------------------------------

def report_command(args) -> int:
    """``bodyscan report``: write the report; check or update the baseline."""
    sweep_dir = Path(args.sweep_dir)
    if not sweep_dir.is_dir():
        raise BenchError(f"{sweep_dir}: no such sweep folder (bodyscan sweep ... --out DIR)")
    if (args.fail_on_regression or args.update_baseline) and not args.baseline:
        raise BenchError("--fail-on-regression and --update-baseline need --baseline FILE")
    from bodyscan._io import check_out, write_json

    started = time.perf_counter()
    store = ResultStore(sweep_dir)
    meta = store.read_json("meta.json")
    out = Path(args.out) if args.out else Path("reports") / (meta.get("sweep") or sweep_dir.name)
    check_out(out, folder=True, error=BenchError)
    if args.update_baseline:
        check_out(args.baseline, option="--baseline", error=BenchError)
    table = store.read()
    aside = store.quarantined()
    if aside:
        print(f"report: {len(aside)} damaged result part(s) set aside in {store.quarantine} "
              f"(rerun the sweep to redo them); reporting on the {len(table)} other job(s)",
              file=sys.stderr)
    gate = None
    if args.baseline and not args.update_baseline:
        if not Path(args.baseline).is_file():
            raise BenchError(f"--baseline {args.baseline}: no such file (create it with "
                             "--update-baseline)")
        try:
            baseline = json.loads(Path(args.baseline).read_text())
        except ValueError as exc:
            raise BenchError(f"--baseline {args.baseline}: not valid JSON ({exc})") from None
        gate = check_gate(table, baseline)
    index = build_report(sweep_dir, out, pictures=not args.no_pictures, gate=gate,
                         baseline_path=args.baseline)
    if gate is not None:
        write_json(out / "gate.json",
                   {"passed": gate.passed, "regressions": gate.regressions, "notes": gate.notes,
                    "baseline": str(args.baseline)}, indent=2)
    print(f"report: {index} and {out / 'report.md'} ({time.perf_counter() - started:.1f} s)",
          file=sys.stderr)
    if args.update_baseline:
        path = Path(args.baseline)
        path.parent.mkdir(parents=True, exist_ok=True)
        content = make_baseline(table, sweep=meta.get("sweep", ""), commit=meta.get("git_commit"))
        write_json(path, content, indent=2, sort_keys=True)
        n = sum(len(b) for b in content["metrics"].values())
        print(f"report: baseline {path} written ({n} method/posture entries)", file=sys.stderr)
        return 0
    if gate is not None:
        print(gate.text(args.baseline), file=sys.stderr if not gate.passed else sys.stdout)
        if args.fail_on_regression and not gate.passed:
            return 1
    return 0
