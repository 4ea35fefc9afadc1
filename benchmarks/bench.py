"""The benchmark: scan every posture, reconstruct with every method, score, and write a report.

`run_bench` is ``bodyscan bench``: the paper's experiment (section 4.2) made numeric. Each shipped
posture is scanned with the ``paper`` preset at k = 1 (``ks=(1, 2, 3)``, ``--k 1,2,3``: the paper's
three laser angles, three times the work), reconstructed with ``proposed``, ``simple``, every
installed peer (`benchmarks.peers`) and every installed method of the ``bodyscan.methods``
entry point group (`benchmarks.methods`), and scored (`benchmarks.metrics`). The posture is fitted
once per scan and shared by ``proposed`` and ``simple``; postures run in parallel processes.
A run writes, under ``reports/<run-id>/``:

- ``results.parquet``: one row per posture x scan x method, every metric and every parameter
  (``scanner.*``, ``recon.*``, ``metric.*``, ``peer.*``), ``status`` and ``error``;
- ``report.md``: the tables (per method: mean over postures and the worst posture);
- ``img/``: per method, the reconstruction of the standing posture with spurious or bridging
  triangles in red (the paper's Fig. 13), with armpit and crotch close-ups;
- ``run.json``: the run's settings, seeds, package versions, git commit and host.

Two functions do one case each, for sweeps and other tools: `evaluate` (reconstruct and score)
and `score` (score a given mesh).

Measurements: ``time_<stage>_s`` are wall-clock seconds of each stage as the method reports them
(``time_total_s`` is the whole reconstruction, the posture fit included); ``peak_memory_mb`` is
the peak resident memory of the process above its level when the reconstruction started
(``peak_memory_scan_mb``, ``peak_memory_fit_mb`` and ``peak_memory_score_mb``: of those stages), sampled
every 5 ms by a thread reading ``/proc/self/statm`` (so it sees C++ allocations of the peers as
well as numpy's; memory freed earlier and reused counts as free, so it is a lower bound). Where
``/proc`` is missing it is the growth of ``ru_maxrss``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import subprocess
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import BenchError
from .jobs import each_done
from .metrics import SECTIONS, GroundTruth, MetricParams, head_misregistration, score_mesh
from .peers import PEERS, PeerParams, available_peers, reconstruct_peer

#: Methods of `recon` (scored with their section labels and joints).
RECON_METHODS = ("proposed", "proposed-closed", "paper", "simple")
#: Recon methods that fit the posture their own way (not the scan's shared fit; its time is theirs).
OWN_FIT_METHODS = ("paper",)
#: Every method the benchmark knows, in table order.
METHODS = RECON_METHODS + tuple(PEERS)

#: Columns of the printed table: name -> (label, scale, digits, higher is better).
TABLE = {
    "spurious_area_fraction": ("spur%", 100, 2, False),
    "bridging_area_cm2": ("bridge cm2", 1, 1, False),
    "precision@5mm": ("P@5", 1, 3, True),
    "recall_seen@5mm": ("Rseen@5", 1, 3, True),
    "recall_full@5mm": ("Rfull@5", 1, 3, True),
    "fscore_seen@5mm": ("Fseen@5", 1, 3, True),
    "chamfer_l1_mm": ("CD-L1 mm", 1, 2, False),
    "normal_consistency": ("NC", 1, 3, True),
    "section_accuracy": ("sect.acc", 1, 3, True),
    "joint_error_median_m": ("joint mm", 1000, 1, False),
    "time_total_s": ("recon s", 1, 2, False),
    "time_score_s": ("score s", 1, 2, False),
}

#: Scan seed of the default run.
DEFAULT_SEED = 0


# --------------------------------------------------------------------------------------------------
# one case


_TRUTH_CACHE: dict = {}


def ground_truth(body, metric_params: MetricParams | None = None) -> GroundTruth:
    """The prepared ground truth of ``body`` (cached: the last few bodies are kept)."""
    metric_params = metric_params or MetricParams()
    h = hashlib.sha1(np.ascontiguousarray(body.vertices).tobytes())
    h.update(np.ascontiguousarray(body.faces).tobytes())
    key = (h.hexdigest(), metric_params)
    if key not in _TRUTH_CACHE:
        if len(_TRUTH_CACHE) >= 4:
            _TRUTH_CACHE.pop(next(iter(_TRUTH_CACHE)))
        _TRUTH_CACHE[key] = GroundTruth.from_body(body, metric_params)
    return _TRUTH_CACHE[key]


def closeups(body) -> dict:
    """Close-up frames ``{name: (center (3,), radius)}`` around the armpits and the crotch,
    placed from the body's true joints (metres)."""
    j = body.joint_dict()
    out = {}
    for side in ("l", "r"):
        c = 0.5 * j[f"shoulder_{side}"] + 0.25 * j[f"elbow_{side}"] + 0.25 * j["chest"]
        out[f"armpit_{side}"] = (c, 0.15)
    hips = 0.5 * (j["hip_l"] + j["hip_r"])
    knees = 0.5 * (j["knee_l"] + j["knee_r"])
    out["crotch"] = (0.85 * hips + 0.15 * knees, 0.15)
    return out


def score(mesh_vertices, mesh_faces, body, scan=None, *, point_index=None, point_sections=None,
          joints=None, metric_params: MetricParams | None = None, keep_masks: bool = False) -> dict:
    """Score any mesh against a ground-truth body and (optionally) its scan.

    Parameters
    ----------
    mesh_vertices : (V, 3) float, metres
    mesh_faces : (F, 3) int
    body : poses.Body
        With ground truth.
    scan : simulator.Scan, optional
        Its points give ``recall_seen`` and, for mesh vertices that are scan points, the exact
        true triangle (``gt_face``); without it every vertex uses the nearest true surface.
    point_index : (V,) int, optional
        Scan point of each vertex, -1 for none (default: matched by position, within 1 micrometre).
    point_sections : (n, 11) bool, optional
        Section labels of the scan points (section accuracy).
    joints : dict of str to (3,), optional
        Estimated joints (posture error).
    metric_params : MetricParams, optional
    keep_masks : bool
        Also return per-face ``_spurious``, ``_bridging`` and ``_true_section``.

    Returns
    -------
    dict
        One flat row: see `benchmarks.metrics.score_mesh`.
    """
    truth = ground_truth(body, metric_params)
    kw = {}
    if scan is not None:   # unknown ground truth (-1, a plain cloud) falls back to the surface
        kw = dict(scan_points=np.asarray(scan.points), scan_gt_face=np.asarray(scan.gt_face),
                  scan_gt_section=np.asarray(scan.gt_section))
    return score_mesh(mesh_vertices, mesh_faces, truth, point_index=point_index,
                      point_sections=point_sections, joints=joints, keep_masks=keep_masks, **kw)


class PeakMemory:
    """Context manager measuring the peak resident memory above the level at entry (MiB)."""

    def __init__(self, interval: float = 0.005):
        self.interval = interval
        self.peak_mb = float("nan")

    @staticmethod
    def _rss() -> int | None:
        try:
            with open("/proc/self/statm") as fh:
                return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError, IndexError):
            return None

    def _watch(self):
        while not self._stop.wait(self.interval):
            self._max = max(self._max, self._rss() or 0)

    def __enter__(self):
        self._base = self._rss()
        if self._base is None:
            import resource
            self._ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            return self
        self._max = self._base
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        if self._base is None:
            import resource
            grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - self._ru
            self.peak_mb = grown / 1024.0  # kilobytes on Linux
            return False
        self._stop.set()
        self._thread.join()
        self._max = max(self._max, self._rss() or 0)
        self.peak_mb = (self._max - self._base) / 2 ** 20
        return False


def _recon_params(params):
    from bodyscan.recon import ReconParams

    if params is None or isinstance(params, dict):
        return ReconParams.from_overrides(params or {})
    if isinstance(params, ReconParams):
        return params
    raise BenchError(f"params must be a dict of recon parameters or a ReconParams, got {type(params).__name__}")


def scan_columns(scan) -> dict:
    """The scan's settings as flat ``scanner.*`` columns (heads as JSON text)."""
    cfg = dict(scan.meta.get("config", {})) if hasattr(scan, "meta") else {}
    out = {}
    for k, v in cfg.items():
        out[f"scanner.{k}"] = json.dumps(v) if isinstance(v, (list, dict, tuple)) else v
    if "laser_angle_deg" in cfg:
        out["k"] = float(cfg["laser_angle_deg"]) / 15.0
    out["n_points"] = int(len(scan.points))
    # the fraction of the body beyond every head's field (cut from the scan; 0 for a body inside)
    out["outside_field"] = float(getattr(scan, "meta", {}).get("outside_field", 0.0))
    planted = _planted_misalignment(scan)
    if planted is not None:
        off = head_misregistration(*planted)
        out["misregistration_deg"], out["misregistration_mm"] = off["deg"], off["mm"]
    return out


def _planted_misalignment(scan):
    """``(rotation (h, 3, 3), translation (h, 3), at (3,))``: each head's planted misalignment as
    ``p -> R p + t`` and the body's centre (the middle of the scan's bounding box), from the
    scan's metadata; None for a scan without one."""
    meta = getattr(scan, "meta", None) or {}
    if "misalign_rotation" not in meta:
        return None
    r = np.asarray(meta["misalign_rotation"], dtype=float).reshape(-1, 3, 3)
    c = np.asarray(meta["scanner_center"], dtype=float)
    t = np.asarray(meta["misalign_translation"], dtype=float).reshape(-1, 3) + c - r @ c
    p = np.asarray(scan.points)
    return r, t, (p.min(axis=0) + p.max(axis=0)) / 2


def registration_error(scan, registration) -> dict:
    """``registration_error_deg``, ``registration_error_mm``: the largest offset left between two
    heads (`metrics.head_misregistration`) once ``registration`` (`recon.clean.register.Registration`)
    corrected the scan's planted misalignment; empty without either."""
    planted = _planted_misalignment(scan)
    if planted is None or registration is None or len(registration.rotation) != len(planted[0]):
        return {}
    r, t, at = planted
    q, u, c = registration.rotation, registration.translation, registration.center
    off = head_misregistration(q @ r, np.einsum("hij,hj->hi", q, t - c) + c + u, at)
    return {"registration_error_deg": off["deg"], "registration_error_mm": off["mm"]}


def evaluate(body, scan, method: str, params=None, *, metric_params: MetricParams | None = None,
             peer_params: PeerParams | None = None, fit=None, fit_seconds: float = 0.0,
             keep_mesh: bool = True) -> dict:
    """Reconstruct one scan with one method and score it: one flat results row.

    Parameters
    ----------
    body : poses.Body
        The scanned body, with ground truth.
    scan : simulator.Scan
    method : str
        A method spec (`benchmarks.methods`): a built-in name (`METHODS`), an installed entry
        point, ``module:function`` or ``cmd:TEMPLATE``.
    params : dict or recon.ReconParams, optional
        Flat reconstruction parameter overrides (``{"t_d": 0.3}``) for ``proposed``/``simple``;
        a method of yours takes its own parameters here.
    metric_params, peer_params : optional
    fit : recon.model.BodyFit, optional
        A posture already estimated on this scan with these parameters (shared between methods);
        its ``fit_seconds`` are reported as ``time_fit_s``, apart from the method's own
        ``time_total_s``.
    keep_mesh : bool
        Add a ``_mesh`` entry (vertices, faces, face_section, spurious, bridging, closeups) for
        pictures; callers storing the row drop it.

    Returns
    -------
    dict
        Metrics (`benchmarks.metrics.score_mesh`), ``time_<stage>_s``, ``peak_memory_mb``,
        ``method``, ``body``, ``status`` (``ok``) and the parameters (``recon.*``/``peer.*``,
        ``scanner.*``, ``metric.*``).

    Raises
    ------
    BenchError
        Unknown method or missing package; errors of the method itself propagate.
    """
    from .methods import resolve

    m = resolve(method)
    metric_params = metric_params or MetricParams()
    row: dict = {"body": body.name, "method": m.name}
    if m.spec != m.name:
        row["method_spec"] = m.spec
    row.update(scan_columns(scan))
    if m.kind == "recon":
        from bodyscan import recon

        rp = _recon_params(params)
        with PeakMemory() as mem:
            rec = recon.reconstruct(scan.points, m.name, rp, view_dir=scan.view_dir, fit=fit,
                                    head=getattr(scan, "head", None))
        times = dict(rec.times)
        if fit is not None:   # shared by the methods of a scan: reported apart, not in "total"
            times.update({f"fit_{k}": float(v) for k, v in (fit.times or {}).items()})
            times["fit"] = float(fit_seconds)
        vertices, faces = rec.vertices, rec.faces
        extra = dict(point_index=rec.point_index, point_sections=rec.point_sections,
                     joints=rec.fit.joints)
        face_section = np.asarray(rec.face_section)
        row["points_unmeshed"] = int(rec.points_unmeshed)
        row["outliers_rejected"] = int(rec.outliers.sum()) if rec.outliers is not None else 0
        if rec.noise is not None:   # the range noise the reconstruction measured
            row["noise_mm"] = float(1000 * rec.noise)
        if rec.moved is not None:  # how far the vertices lie from their input points
            used = np.zeros(len(rec.moved), dtype=bool)   # input points in a face
            f = np.asarray(rec.faces).ravel()
            used[f[f < len(rec.moved)]] = True
            row["moved_mean_mm"] = float(1000 * rec.moved[used].mean()) if used.any() else 0.0
            row["moved_max_mm"] = float(1000 * rec.moved[used].max()) if used.any() else 0.0
        if rec.registration is not None and len(rec.registration.rotation) >= 2:
            row["registration_deg"], row["registration_mm"] = rec.registration.offset(0, 1)
            row.update(registration_error(scan, rec.registration))
        row.update({f"recon.{k}": (json.dumps(v) if isinstance(v, (tuple, list, dict)) else v)
                    for k, v in rp.to_dict().items()})
    elif m.kind == "peer":
        if params:
            raise BenchError(f"method {m.name!r} takes no recon parameters (got {', '.join(dict(params))})")
        peer_params = peer_params or PeerParams()
        with PeakMemory() as mem:
            vertices, faces, times = reconstruct_peer(m.name, scan.points, scan.view_dir, peer_params)
        extra, face_section = {}, None
        row.update({k.replace("peer_", "peer."): v for k, v in peer_params.as_columns().items()})
    else:   # your own method (benchmarks.methods): its parameters are its recon.* columns
        own = m.check_params(dict(params) if params else None)
        with PeakMemory() as mem:
            vertices, faces, got, times = m.run(scan.points, scan.view_dir,
                                                getattr(scan, "head", None), own)
        extra = {k: got[k] for k in ("point_index", "point_sections", "joints")
                 if got.get(k) is not None}
        face_section = got.get("face_section")
        row.update({f"recon.{k}": v for k, v in own.items()})
    row.update({f"time_{k}_s": float(v) for k, v in times.items()})
    row["peak_memory_mb"] = float(mem.peak_mb)
    t0 = time.perf_counter()
    with PeakMemory() as score_mem:
        metrics = score(vertices, faces, body, scan, metric_params=metric_params, keep_masks=True, **extra)
    row["time_score_s"] = time.perf_counter() - t0
    row["peak_memory_score_mb"] = float(score_mem.peak_mb)
    masks = {k: metrics.pop(k) for k in [k for k in metrics if k.startswith("_")]}
    row.update(metrics)
    row.update({k.replace("metric_", "metric."): v for k, v in metric_params.as_columns().items()})
    row["status"], row["error"] = "ok", None
    if keep_mesh:
        row["_mesh"] = {
            "vertices": np.asarray(vertices, dtype=np.float32), "faces": np.asarray(faces),
            "face_section": face_section if face_section is not None else masks.get("_true_section"),
            "spurious": masks.get("_spurious"), "bridging": masks.get("_bridging"),
            "closeups": closeups(body),
        }
    return row


# --------------------------------------------------------------------------------------------------
# the run


def _once(what: str, items) -> None:
    """Raise `BenchError` naming the first item given twice (its scans would run twice, their rows
    duplicated under one key)."""
    seen = set()
    for item in items:
        if item in seen:
            raise BenchError(f"{what}: {item} is given twice")
        seen.add(item)


@dataclass(frozen=True)
class BenchConfig:
    """What `run_bench` runs.

    Attributes
    ----------
    bodies : tuple of str
        Library names, body files or folders of body files; empty: every shipped posture.
    presets : tuple of str
        Scanner presets (`simulator.PRESETS`).
    ks : tuple of float
        Laser angle indices (angle = k * 15 degrees), paper 4.1; the paper scans k = 1, 2, 3,
        the default run k = 1 (within 3 minutes on two cores).
    methods : tuple of str
        Empty: ``proposed``, ``simple`` and every installed peer.
    recon : dict
        Flat reconstruction parameter overrides (`recon.ReconParams.from_overrides`).
    scanner : dict
        Scanner field overrides applied to every preset (e.g. ``noise_sigma``).
    seed : int
        Scan seed (noise, outliers, misalignment).
    metric : MetricParams
    pictures : bool
    """

    bodies: tuple = ()
    presets: tuple = ("paper",)
    ks: tuple = (1,)
    methods: tuple = ()
    recon: dict = field(default_factory=dict)
    scanner: dict = field(default_factory=dict)
    seed: int = DEFAULT_SEED
    metric: MetricParams = field(default_factory=MetricParams)
    pictures: bool = True

    def resolved(self) -> "BenchConfig":
        """Defaults filled in and every name checked (raises `BenchError`)."""
        from bodyscan.poses.body import load_body
        from bodyscan.poses.library import expand_bodies

        bodies = tuple(expand_bodies(self.bodies))  # a folder (a corpus) gives its body files
        if not bodies:
            raise BenchError("no postures: the pose library is empty and --bodies names none")
        _once("postures", bodies)
        for b in bodies:
            load_body(b).require_ground_truth("the benchmark")
        from .methods import installed_methods, resolve

        methods = tuple(self.methods) or (RECON_METHODS + tuple(available_peers())
                                          + tuple(installed_methods()))
        resolved = [resolve(m) for m in methods]
        names = [m.name for m in resolved]
        if len(set(names)) != len(names):
            raise BenchError(f"methods {', '.join(names)}: a name is used twice")
        missing = [m.name for m in resolved if m.kind == "peer" and m.name not in available_peers()]
        if missing:
            raise BenchError(f"method(s) {', '.join(missing)} need the peers extra: "
                             "pip install 'bodyscan[peers]' (Open3D also needs apt-get install libusb-1.0-0)")
        for m in resolved:
            if not m.builtin:
                m.check_params(method_params(m, self.recon))
        recon = recon_params_of(resolved, self.recon)
        if any(m.kind == "recon" for m in resolved):
            _recon_params(recon)
        elif recon:
            raise BenchError(f"parameter(s) {', '.join(recon)} belong to no method that runs "
                             "(recon parameters are for proposed and simple)")
        if not self.ks or any(not 0 < float(k) < 6 for k in self.ks):
            raise BenchError(f"k values must be in (0, 6) (laser angle k * 15 degrees), got {self.ks}")
        _once("k values", [f"{float(k):g}" for k in self.ks])
        _once("presets", self.presets)
        from bodyscan import simulator

        for p in self.presets:
            simulator.preset(p, **self.scanner)
        return dataclasses.replace(self, bodies=bodies, methods=methods,
                                   ks=tuple(float(k) for k in self.ks))

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["metric"] = dataclasses.asdict(self.metric)
        return d


@dataclass
class BenchResult:
    """A finished run: its table and where it was written."""

    table: object            # pandas.DataFrame
    out: Path
    summary: str


def run_id() -> str:
    """``bench-YYYYmmdd-HHMMSS`` (UTC)."""
    return time.strftime("bench-%Y%m%d-%H%M%S", time.gmtime())


def _log(msg: str, stream) -> None:
    if stream is not None:
        print(msg, file=stream, flush=True)


def method_params(method, params: dict) -> dict:
    """The entries of the flat ``params`` that are parameters of ``method``: recon parameters
    for a recon method, its own for a method of yours, none for a peer."""
    params = dict(params or {})
    if method.kind == "recon":
        return params
    if method.kind == "peer":
        return {}
    own = method.defaults()
    return {k: v for k, v in params.items() if k in own}


def recon_params_of(methods, params: dict) -> dict:
    """The entries of ``params`` left for the recon methods: those that no method of yours
    among ``methods`` claims as its own."""
    claimed = set()
    for m in methods:
        if not m.builtin:
            claimed |= set(m.defaults())
    return {k: v for k, v in dict(params or {}).items() if k not in claimed}


def method_names(specs) -> list:
    """The table names of method specs (`benchmarks.methods.method_name`)."""
    from .methods import method_name

    return [method_name(s) for s in specs]


def skipped_peers(methods) -> dict:
    """Peers that a run of ``methods`` leaves out, and why: {peer: reason}."""
    from .peers import unavailable_peers

    missing = unavailable_peers()
    return {p: missing.get(p, "not asked for: --methods or --no-peers")
            for p in PEERS if p not in method_names(methods)}


def skipped_text(skipped: dict) -> str:
    """``{peer: reason}`` as one line, the peers of one reason together."""
    by: dict = {}
    for peer, why in skipped.items():
        by.setdefault(why, []).append(peer)
    return "; ".join(f"{', '.join(peers)} ({why})" for why, peers in by.items())


def _estimate_fit(scan, params):
    """The posture of ``scan`` with ``params``, and the seconds it took."""
    from bodyscan.recon.pipeline import estimate_fit

    t0 = time.perf_counter()
    fit = estimate_fit(np.asarray(scan.points, dtype=np.float64), params,
                       np.asarray(scan.view_dir, dtype=np.float64), head=getattr(scan, "head", None))
    return fit, time.perf_counter() - t0


def _bench_body(body_name: str, config: "BenchConfig", picture_case, verbose: bool,
                report_dir=None) -> tuple:
    """Every scan and method of one posture, in a worker process: its rows, and the pictures
    ``[(method, [files])]`` drawn into ``report_dir`` when it holds the picture case (drawn
    here, beside the other postures' work, rather than after them)."""
    from bodyscan import simulator
    from bodyscan.poses.body import load_body

    from .methods import resolve

    body = load_body(body_name)
    ground_truth(body, config.metric)
    methods = [resolve(m) for m in config.methods]
    recon_only = recon_params_of(methods, config.recon)
    uses_recon = any(m.kind == "recon" and m.name not in OWN_FIT_METHODS for m in methods)   # the shared fit
    out = []
    for preset in config.presets:
        for k in config.ks:
            cfg = simulator.preset(preset, **{**config.scanner, "k": k})
            t0 = time.perf_counter()
            try:
                with PeakMemory() as scan_mem:
                    sc = simulator.scan(body, cfg, seed=config.seed)
            except Exception as exc:  # every method of this scan fails with it
                error = f"scan failed: {type(exc).__name__}: {exc}"
                out += [({"body": body.name, "method": m.name, "preset": preset, "k": float(k),
                          "seed": config.seed, "status": "error", "error": error}, None)
                        for m in methods]
                if verbose:
                    _log(f"  {body.name} {preset} k={k:g}: {error}", sys.stderr)
                continue
            scan_s = time.perf_counter() - t0
            fit, fit_s, fit_mb, fit_error, fit_warn = None, 0.0, 0.0, None, []
            if uses_recon:
                try:
                    with PeakMemory() as mem, warnings.catch_warnings(record=True) as fit_warn:
                        warnings.simplefilter("always")
                        fit, fit_s = _estimate_fit(sc, _recon_params(recon_only))
                    fit_mb = mem.peak_mb
                except Exception as exc:  # the recon methods of this scan fail with it
                    fit_error = f"{type(exc).__name__}: {exc}"
            for m in methods:
                is_recon = m.kind == "recon"
                base = {"body": body.name, "method": m.name, "preset": preset, "k": float(k),
                        "seed": config.seed, **scan_columns(sc), "time_scan_s": scan_s,
                        "peak_memory_scan_mb": float(scan_mem.peak_mb)}
                if is_recon:
                    base["peak_memory_fit_mb"] = float(fit_mb)
                caught = list(fit_warn) if is_recon else []
                try:
                    own_fit = m.name in OWN_FIT_METHODS
                    if is_recon and not own_fit and fit_error:
                        raise BenchError(f"posture estimation failed: {fit_error}")
                    with warnings.catch_warnings(record=True) as more:
                        warnings.simplefilter("always")
                        row = evaluate(body, sc, m.spec,
                                       recon_only if is_recon else method_params(m, config.recon),
                                       metric_params=config.metric,
                                       fit=None if own_fit else fit, fit_seconds=fit_s,
                                       keep_mesh=config.pictures and (body_name, preset, k) == picture_case)
                    caught += more
                    if is_recon and not own_fit:
                        row["peak_memory_mb"] = max(row["peak_memory_mb"], fit_mb)
                    row = {**base, **row}
                except Exception as exc:
                    if isinstance(exc, (KeyboardInterrupt, MemoryError)):
                        raise
                    row = {**base, "status": "error", "error": f"{type(exc).__name__}: {exc}"}
                row["warnings"] = "; ".join(dict.fromkeys(str(w.message) for w in caught)) or None
                mesh = row.pop("_mesh", None)
                out.append((row, mesh))
                if verbose:   # the same seconds as the table's (time_total_s, time_score_s)
                    status = f"error: {row['error']}" if row["status"] != "ok" else (
                        f"spurious {100 * row['spurious_area_fraction']:.2f} %, bridging "
                        f"{row['bridging_area_cm2']:.0f} cm2, F_seen@5mm {row['fscore_seen@5mm']:.3f} "
                        f"(reconstruction {row.get('time_total_s', float('nan')):.1f} s"
                        + (f" after the shared fit {fit_s:.1f} s" if is_recon else "")
                        + f", scoring {row.get('time_score_s', float('nan')):.1f} s)")
                    _log(f"  {body.name} {preset} k={k:g} {m.name}: {status}", sys.stderr)
    meshes = {row["method"]: mesh for row, mesh in out if mesh is not None}
    pictures = []
    if meshes and report_dir is not None:
        pictures = _pictures(meshes, picture_case, Path(report_dir), sys.stderr if verbose else None)
    return [row for row, _ in out], pictures


def run_bench(config: BenchConfig | None = None, out=None, *, jobs: int = 1,
              progress=sys.stderr) -> BenchResult:
    """Run the benchmark and write its report folder.

    Parameters
    ----------
    config : BenchConfig, optional
        Default: the paper's experiment on the shipped library.
    out : str or Path, optional
        Report folder; default ``reports/<run-id>`` under the current directory.
    jobs : int
        Postures run at the same time, in worker processes. Stage times are then measured while
        the other workers run too; use 1 for uncontended times.
    progress : file or None
        Where progress lines go (stderr); None for silence.

    Returns
    -------
    BenchResult
    """
    import pandas as pd

    started = time.time()
    config = (config or BenchConfig()).resolved()
    if jobs < 1:
        raise BenchError(f"jobs must be at least 1, got {jobs}")
    from bodyscan._io import check_out

    out = check_out(Path(out) if out is not None else Path("reports") / run_id(), folder=True,
                    error=BenchError)
    out.mkdir(parents=True, exist_ok=True)
    n_cases = len(config.bodies) * len(config.presets) * len(config.ks) * len(config.methods)
    _log(f"bodyscan bench: {len(config.bodies)} posture(s) x {len(config.presets)} preset(s) x "
         f"{len(config.ks)} k x {len(config.methods)} method(s) = {n_cases} reconstructions, "
         f"{jobs} process(es) -> {out}", progress)
    skipped = skipped_peers(config.methods)
    _log("bodyscan bench: methods " + ", ".join(method_names(config.methods)) + (
        "; peers not run: " + skipped_text(skipped)
        if skipped else "; every peer runs"), progress)
    picture_body = "standing" if "standing" in config.bodies else config.bodies[0]
    picture_case = (picture_body, config.presets[0], config.ks[0])
    verbose = progress is not None
    results: dict = {}
    pictures: list = []

    def finished(name, done):
        results[name], drawn = done
        pictures.extend(drawn)
        bad = sum(r["status"] != "ok" for r in results[name])
        _log(f"[{len(results)}/{len(config.bodies)} postures, {time.time() - started:.0f} s] "
             f"{name} done" + (f", {bad} failed" if bad else ""), progress)

    for name, done in each_done(_bench_body, config.bodies, config, picture_case, verbose, out, jobs=jobs):
        finished(name, done)
    rows = [r for name in config.bodies for r in results[name]]
    table = pd.DataFrame(rows)
    from bodyscan._io import atomic_write, write_json, write_text

    atomic_write(out / "results.parquet", lambda tmp: table.to_parquet(tmp, index=False))
    summary = summary_table(table) + ("\npeers not run: " + skipped_text(skipped) if skipped else "")
    meta = run_metadata(config, started, jobs)
    meta["peers_not_run"] = skipped
    write_json(out / "run.json", meta, indent=2)
    write_text(out / "report.md", report_markdown(table, config, summary, pictures, picture_case,
                                                  skipped))
    _log(f"bodyscan bench: done in {time.time() - started:.0f} s; wrote {out}/results.parquet, "
         f"report.md, run.json" + (f" and pictures of {len(pictures)} method(s) in img/" if pictures else ""),
         progress)
    return BenchResult(table=table, out=out, summary=summary)


# --------------------------------------------------------------------------------------------------
# tables, pictures, metadata


def method_order(names) -> list:
    """Distinct method names in table order: the built-in ones (`METHODS`), then the others as
    they come."""
    names = list(dict.fromkeys(names))
    return [m for m in METHODS if m in names] + [m for m in names if m not in METHODS]


def common_cases(table):
    """The rows of the scans that every method of the table reconstructed (like with like).

    A method that reconstructed no scan at all (a broken command; `failed_methods`) is left out
    of "every method", so that it does not empty the comparison of the others."""
    key = ["body", "preset", "k"]
    ok = table[table["status"] == "ok"]
    n = ok["method"].nunique()
    counts = ok.groupby(key)["method"].nunique()
    keep = counts[counts == n].index
    return ok.set_index(key).loc[lambda t: t.index.isin(keep)].reset_index()


def failed_methods(table) -> list[str]:
    """The methods of the table that failed on every one of their scans, in the table's order."""
    ok = set(table.loc[table["status"] == "ok", "method"])
    return [m for m in method_order(table["method"]) if m not in ok]


def method_summary(table):
    """Per method and metric: mean over postures (each the mean over its scans), the worst
    posture's value and its name, over the scans every method reconstructed (`common_cases`).
    Returns a DataFrame indexed by method (with ``cases`` used and ``failed``)."""
    import pandas as pd

    methods = method_order(table["method"])
    records = []
    ok = common_cases(table)
    for m in methods:
        rec = {"method": m, "cases": int((ok["method"] == m).sum()), "failed": int(
            ((table["method"] == m) & (table["status"] != "ok")).sum())}
        for metric, (_, _, _, higher) in TABLE.items():
            if metric not in ok.columns:
                continue
            per = ok[ok["method"] == m].groupby("body")[metric].mean().dropna()
            if per.empty:
                rec[metric], rec[f"{metric}:worst"], rec[f"{metric}:worst_body"] = np.nan, np.nan, ""
                continue
            worst = per.idxmin() if higher else per.idxmax()
            rec[metric], rec[f"{metric}:worst"], rec[f"{metric}:worst_body"] = per.mean(), per[worst], worst
        records.append(rec)
    return pd.DataFrame(records).set_index("method") if records else pd.DataFrame()


def _fmt(metric, value) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    _, scale, digits, _ = TABLE[metric]
    return f"{value * scale:.{digits}f}"


def summary_table(table) -> str:
    """The compact text table: method x metric, ``mean`` and below it ``worst (posture)``."""
    s = method_summary(table)
    if s.empty:
        return "(no results)"
    metrics = [m for m in TABLE if m in s.columns]
    head = ["method"] + [TABLE[m][0] for m in metrics]
    lines = []
    for method, rec in s.iterrows():
        fail = f" ({rec['failed']} failed)" if rec["failed"] else ""
        lines.append([method + fail] + [_fmt(m, rec[m]) for m in metrics])
        if table["body"].nunique() > 1:
            lines.append(["  worst"] + [_fmt(m, rec[f"{m}:worst"]) for m in metrics])
    width = [max(len(str(r[i])) for r in [head] + lines) for i in range(len(head))]
    fmt = lambda r: "  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w)  # noqa: E731
                              for i, (c, w) in enumerate(zip(r, width)))
    out = [fmt(head), "  ".join("-" * w for w in width)] + [fmt(r) for r in lines]
    common = common_cases(table)
    n_scans = len(common.groupby(["body", "preset", "k"]))
    n_all = len(table.groupby(["body", "preset", "k"]))
    out.append(shared_times(table))
    registration = registration_line(table)
    if registration:
        out.append(registration)
    field = field_line(table)
    if field:
        out.append(field)
    none = failed_methods(table)
    if none:
        out.append(f"no result at all (failed on every scan, left out of the comparison): {', '.join(none)}")
    out.append(f"mean over the {n_scans} of {n_all} scans ({common['body'].nunique()} posture(s)) that "
               "every method reconstructed, each posture averaged over its scans; 'worst': the worst "
               "posture. spur%: spurious area %, bridge: area in the air (cm2), P/R/F at 5 mm, "
               "Rseen: recall of the surface the scanner saw, CD-L1: Chamfer-L1 (mean of both "
               "directions), NC: normal consistency, joint: median joint error; recon s: the "
               "method's own seconds (the shared posture fit apart), score s: scoring.")
    return "\n".join(out)


def shared_times(table) -> str:
    """One line: mean seconds per scan of the stages shared by the methods of a scan (the scan,
    and the posture fit of the recon methods, counted once)."""
    ok = table[table["status"] == "ok"]
    per_scan = ok.groupby(["body", "preset", "k"])
    parts = []
    if "time_scan_s" in ok.columns and ok["time_scan_s"].notna().any():
        parts.append(f"scan {per_scan['time_scan_s'].first().mean():.2f} s")
    if "time_fit_s" in ok.columns and ok["time_fit_s"].notna().any():
        fit = ok[ok["time_fit_s"].notna() & ~ok["method"].isin(OWN_FIT_METHODS)]
        users = ", ".join(method_order(fit["method"]))
        parts.append(f"posture fit {fit.groupby(['body', 'preset', 'k'])['time_fit_s'].first().mean():.2f} s "
                     f"(shared by {users}; not in their recon s)")
    return "per scan, shared by its methods: " + ("; ".join(parts) or "-")


def registration_line(table) -> str:
    """One line for scans whose heads were misaligned: the planted offset between heads and what
    ``register_heads`` left of it (largest pair of heads; mean and worst over scans); empty for
    scans without a misalignment."""
    ok = table[table["status"] == "ok"]
    if "misregistration_deg" not in ok.columns or ok["misregistration_deg"].isna().all():
        return ""
    scan = ok[ok["misregistration_deg"].notna()].groupby(["body", "preset", "k"]).first()
    out = (f"heads misaligned by {scan['misregistration_deg'].mean():.2f} deg / "
           f"{scan['misregistration_mm'].mean():.1f} mm (largest pair, at the body's centre; mean over scans)")
    if "registration_error_deg" not in ok.columns or ok["registration_error_deg"].isna().all():
        return out + "; not corrected (--param register_heads=true registers the heads)"
    left = ok[ok["registration_error_deg"].notna()].groupby(["body", "preset", "k"]).first()
    return out + (f"; left by register_heads: {left['registration_error_deg'].mean():.3f} deg / "
                  f"{left['registration_error_mm'].mean():.2f} mm (worst {left['registration_error_deg'].max():.3f} "
                  f"deg / {left['registration_error_mm'].max():.2f} mm)")


def field_line(table) -> str:
    """One line naming the scans whose body reached beyond the heads' fields (``outside_field``:
    the part there was not measured, and every method is scored against the whole body); empty
    when every body lay inside."""
    if "outside_field" not in table.columns:
        return ""
    scan = table.groupby(["body", "preset", "k"])["outside_field"].first()
    cut = scan[scan > 0]
    if not len(cut):
        return ""
    which = ", ".join(f"{b} {p} k={k:g} ({100 * v:.1f} %)" for (b, p, k), v in cut.items())
    return (f"{len(cut)} of {len(scan)} scans cut by the heads' fields (share of the body's vertices "
            f"not measured): {which}")


def report_markdown(table, config: BenchConfig, summary: str, pictures: list, picture_case,
                    skipped: dict | None = None) -> str:
    """The ``report.md`` text."""
    s = method_summary(table)
    none = failed_methods(table)
    registration = registration_line(table)
    field = field_line(table)
    metrics = [m for m in TABLE if m in s.columns]
    md = ["# bodyscan bench", "",
          f"{table['body'].nunique()} posture(s) ({', '.join(sorted(table['body'].unique()))}), "
          f"presets {', '.join(config.presets)}, k = {', '.join(f'{k:g}' for k in config.ks)}, "
          f"methods {', '.join(config.methods)}; scan seed {config.seed}. "
          f"Every number is in `results.parquet`; settings in `run.json`.", "",
          *([f"Peers not run: {skipped_text(skipped)}.", ""]
            if skipped else []),
          shared_times(table) + ".", "",
          *([registration + ".", ""] if registration else []),
          *([field + ".", ""] if field else []),
          "## By method", "",
          "Mean over postures (each posture averaged over its scans); below, the worst posture. "
          "Only the scans that every method reconstructed count here (failures are listed below "
          "and kept in the per-case table)."
          + (f" Left out of it, as they failed on every scan: {', '.join(none)}." if none else ""), "",
          "| method | " + " | ".join(TABLE[m][0] for m in metrics) + " |",
          "|---|" + "---:|" * len(metrics)]
    for method, rec in s.iterrows():
        md.append(f"| {method} | " + " | ".join(_fmt(m, rec[m]) for m in metrics) + " |")
        md.append("| worst | " + " | ".join(
            f"{_fmt(m, rec[f'{m}:worst'])} ({rec[f'{m}:worst_body']})" if rec[f"{m}:worst_body"] else "-"
            for m in metrics) + " |")
    ok = table[table["status"] == "ok"]
    if len(ok):
        md += ["", "## By method, posture and k", "",
               "| method | posture | preset | k | " + " | ".join(TABLE[m][0] for m in metrics) + " |",
               "|---|---|---|---:|" + "---:|" * len(metrics)]
        for _, r in ok.sort_values(["method", "body", "preset", "k"],
                                   key=lambda c: c.map({m: i for i, m in enumerate(method_order(c))})
                                   if c.name == "method" else c).iterrows():
            md.append(f"| {r['method']} | {r['body']} | {r['preset']} | {r['k']:g} | "
                      + " | ".join(_fmt(m, r.get(m, np.nan)) for m in metrics) + " |")
        if "bridging_pairs" in ok.columns:
            md += ["", "## Where the surface in the air is (cm², summed over scans)", ""]
            for method, g in ok.groupby("method"):
                tot: dict = {}
                for text in g["bridging_pairs"].dropna():
                    for key, v in json.loads(text).items():
                        tot[key] = tot.get(key, 0.0) + v
                top = sorted(tot.items(), key=lambda kv: -kv[1])[:6]
                md.append(f"- **{method}**: " + (", ".join(f"{k} {v:.0f}" for k, v in top) or "none"))
    if "warnings" in table.columns and table["warnings"].notna().any():
        w = table[table["warnings"].notna()]
        md += ["", f"## Warnings ({len(w)} case(s))", ""]
        md += [f"- {r['method']} / {r['body']} / {r['preset']} k={r['k']:g}: {r['warnings']}"
               for _, r in w.head(40).iterrows()]
    failed = table[table["status"] != "ok"]
    if len(failed):
        md += ["", f"## Failed ({len(failed)})", ""]
        md += [f"- {r['method']} / {r['body']} / {r['preset']} k={r['k']:g}: {r['error']}"
               for _, r in failed.iterrows()]
    if pictures:
        body, preset, k = picture_case
        md += ["", f"## Reconstructions of {Path(body).stem} ({preset}, k = {k:g})", "",
               "Sections in colour (peers: the true section of the nearest surface); spurious "
               "(normal more than the threshold from the true one) or bridging triangles in red, "
               "as in the paper's Fig. 13. Close-ups: a slab around each armpit and the crotch.", ""]
        for method, files in pictures:
            md.append(f"### {method}")
            md += [f"![{method} {Path(f).stem}]({f})" for f in files]
            md.append("")
    md += ["", "## Summary (as printed)", "", "```", summary, "```", ""]
    return "\n".join(md)


def _pictures(meshes: dict, case, out: Path, progress) -> list:
    """Render the kept meshes to ``out/img``; returns [(method, [relative paths])]."""
    try:
        from .render import render_mesh, section_face_colors
    except ImportError as exc:
        _log(f"bodyscan bench: no pictures ({exc})", progress)
        return []
    done = []
    body = Path(case[0]).stem     # a body file's name, not its path
    for method in method_order(meshes):
        mesh = meshes[method]
        red = np.zeros(len(mesh["faces"]), bool)
        for key in ("spurious", "bridging"):
            if mesh.get(key) is not None:
                red |= np.asarray(mesh[key], bool)
        sec = mesh.get("face_section")
        colors = section_face_colors(np.full(len(red), -1) if sec is None else sec, red)
        files = []
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                name = f"img/{method}_{body}.png"
                render_mesh(mesh["vertices"], mesh["faces"], colors, out / name,
                            views=("front", "side", "back"), size=(360, 540),
                            title=f"{method} / {body}: red = spurious or bridging")
                files.append(name)
                for cname, (center, radius) in mesh["closeups"].items():
                    name = f"img/{method}_{body}_{cname}.png"
                    render_mesh(mesh["vertices"], mesh["faces"], colors, out / name, views=("front",),
                                size=(360, 360), close_up=(center, radius), title=f"{method}: {cname}")
                    files.append(name)
        except Exception as exc:  # pictures are a bonus: never lose the run for them
            _log(f"bodyscan bench: picture of {method} failed ({type(exc).__name__}: {exc})", progress)
        if files:
            done.append((method, files))
    return done


def _git_commit() -> str | None:
    try:
        root = Path(__file__).resolve().parents[1]
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "") if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def package_versions() -> dict:
    """Versions of the packages that shape the numbers."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in ("bodyscan", "numpy", "scipy", "trimesh", "embreex", "open3d", "pymeshlab",
                 "pandas", "pyarrow", "pyrender"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def run_metadata(config: BenchConfig, started: float, jobs: int = 1) -> dict:
    """Settings, seeds, versions, commit and host of a run (``run.json``)."""
    from bodyscan.recon import ReconParams

    from .methods import resolve

    meta = {
        "command": " ".join(sys.argv),
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)),
        "seconds": round(time.time() - started, 1),
        "jobs": jobs,
        "config": config.to_dict(),
        "recon_params": ReconParams.from_overrides(recon_params_of(
            [resolve(m) for m in config.methods], config.recon)).to_dict(),
        "peer_params": dataclasses.asdict(PeerParams()),
        "metric_params": dataclasses.asdict(config.metric),
        "seeds": {"scan": config.seed, "metric_samples": config.metric.seed},
        "versions": package_versions(),
        "git_commit": _git_commit(),
        "host": {"machine": platform.machine(), "system": platform.system(), "cpus": os.cpu_count()},
        "sections": list(SECTIONS),
    }
    if _TRUTH_CACHE:
        meta["closest_point_backend"] = next(iter(_TRUTH_CACHE.values())).index.backend
    return json.loads(json.dumps(meta, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
