"""`bodyscan bench` (the paper's experiment, scored) and `bodyscan score` (score any mesh)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from bodyscan._params import param_action


def _listing() -> str:
    from bodyscan.recon.params import stage_help

    return stage_help()


def _csv(text: str) -> tuple:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def _pairs(items, option) -> dict:
    from . import BenchError

    out = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise BenchError(f"{option} {item!r}: expected name=value")
        out[name.strip()] = value.strip()
    return out


def register(sub) -> None:
    """Add ``bench`` and ``score`` to the ``bodyscan`` subparsers ``sub``."""
    p = sub.add_parser(
        "bench", help="the benchmark: scan every posture, reconstruct with every method, score",
        description="The paper's experiment made numeric: every posture of the library, scanned "
                    "with the 'paper' preset at k = 1 (--k 1,2,3: the paper's three angles), "
                    "reconstructed with proposed, simple, every installed peer (poisson, "
                    "poisson-trimmed, bpa, alpha, spsr; those not installed are named with the "
                    "reason) and your own methods (--methods, --method-cmd), scored. Prints a "
                    "table (method x metric: mean and worst posture) and writes results.parquet, "
                    "report.md, run.json and pictures to reports/<run-id>/. Exits 1 when a method "
                    "failed on every scan (a scan some methods fail on, such as a refused fit, is "
                    "listed in the report and left out of the comparison).")
    p.add_argument("--bodies", type=_csv, default=(), metavar="A,B",
                   help="postures: library names, body files or folders of them, e.g. a corpus from "
                        "`poses sample` (default: every shipped posture)")
    p.add_argument("--presets", type=_csv, default=("paper",), metavar="P,Q",
                   help="scanner presets: paper (parallel, 10 mm) and/or scanner (perspective, 2 mm, "
                        "1 mm noise) (default paper)")
    p.add_argument("--k", type=_csv, default=("1",), metavar="1,2,3", dest="ks",
                   help="laser angle indices: the laser is k * 15 degrees from the camera axis "
                        "(default 1; 1,2,3 is the paper's three angles, three times the work)")
    p.add_argument("--methods", type=_csv, default=(), metavar="M,N",
                   help="methods: proposed, simple, poisson, poisson-trimmed, bpa, alpha, spsr, an "
                        "installed entry point (group bodyscan.methods) or your own Python function "
                        "as [NAME=]module:function (default: proposed, simple, every installed peer "
                        "and entry point)")
    p.add_argument("--method-cmd", action="append", default=[], metavar="'[NAME=]TOOL {cloud} {out}'",
                   help="an external command as one more method: {cloud} is replaced by a PLY of the "
                        "points, {out} by the mesh file it must write, {NAME} by --param NAME=VALUE; "
                        "repeatable (see benchmarks/methods.py)")
    p.add_argument("--no-peers", action="store_true",
                   help="only proposed and simple (when --methods is not given)")
    p.add_argument("--param", action=param_action(_listing), default=[], metavar="NAME=VALUE",
                   help="reconstruction parameter override by its name (e.g. t_d=0.3), or a "
                        "parameter of your own method; repeatable; `--param help` lists them")
    p.add_argument("--scanner", action="append", default=[], metavar="NAME=VALUE",
                   help="scanner setting override for every preset (e.g. noise_sigma=0.001, metres); "
                        "repeatable")
    p.add_argument("--metric", action="append", default=[], metavar="NAME=VALUE",
                   help="metric setting: spurious_angle_deg (30), bridging_distance_m (0.005), "
                        "n_samples (50000), seen_radius_m (0.015), exterior_rays (128: the recalls "
                        "count the outer surface; 0: every true triangle), seed (0), oriented (true), "
                        "backend (auto/open3d/numpy); repeatable")
    p.add_argument("--seed", type=int, default=0, help="scan seed (noise, outliers, misalignment) (default 0)")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                   help="postures run at once in worker processes; 1 gives uncontended stage times "
                        "(default: 2, or 1 on a one-core machine)")
    p.add_argument("--out", default=None, metavar="DIR", help="report folder (default: reports/<run-id>)")
    p.add_argument("--no-pictures", action="store_true", help="skip the pictures")
    p.set_defaults(func=bench_command)

    s = sub.add_parser(
        "score", help="score any mesh against a ground-truth body and its scan",
        description="Score a mesh from any tool: spurious and bridging area, precision/recall/F at "
                    "5 and 10 mm, Chamfer-L1, normal consistency (and section accuracy and posture "
                    "error when known). Mesh vertices that coincide with cloud points use the "
                    "point's true triangle; others the nearest point of the true surface.")
    s.add_argument("mesh", metavar="MESH", help="the mesh to score (PLY, OBJ, STL, OFF, GLB), metres")
    s.add_argument("--body", required=True, metavar="BODY",
                   help="the true body: a library name or a body .npz (with ground truth)")
    s.add_argument("--cloud", metavar="CLOUD.ply",
                   help="the scan the mesh was made from (bodyscan scan output): gives recall of the "
                        "seen surface (without it, the seen-surface measures are null), and exact "
                        "true triangles for vertices that are scan points")
    s.add_argument("--fit", metavar="FIT.json", help="a posture (bodyscan fit output): joint error")
    s.add_argument("--metric", action="append", default=[], metavar="NAME=VALUE",
                   help="metric setting (see bodyscan bench --help); repeatable")
    s.add_argument("--out", metavar="metrics.json", help="write the metrics here (default: print them)")
    s.set_defaults(func=score_command)
    add_peer_methods(sub)


def add_peer_methods(sub) -> None:
    """Let ``bodyscan reconstruct --method`` run the peers too (poisson, bpa, ...).

    `recon` imports nothing from `benchmarks`, so the peers are added here, after recon's command
    is registered: the ``--method`` choices are extended and the handler wrapped.
    """
    from .peers import PEERS

    parser = getattr(sub, "choices", {}).get("reconstruct")
    if parser is None:
        return
    for action in parser._actions:
        if "--method" in action.option_strings and action.choices is not None:
            action.choices = tuple(action.choices) + tuple(m for m in PEERS if m not in action.choices)
            action.help = (action.help or "") + "; peers (the peers extra, see benchmarks/peers.py): " \
                + ", ".join(PEERS)
    original = parser.get_default("func")

    def run(args):
        if getattr(args, "method", None) in PEERS:
            return reconstruct_peer_command(args)
        return original(args)

    parser.set_defaults(func=run)


def reconstruct_peer_command(args) -> int:
    """``bodyscan reconstruct --method <peer>``: a peer's mesh of a cloud, written as PLY."""
    import trimesh

    from bodyscan.recon.cloud import read_cloud

    from . import BenchError
    from .peers import reconstruct_peer

    for option in ("param", "fit", "preview"):
        if getattr(args, option, None):
            raise BenchError(f"--{option} is for the proposed and simple methods, not {args.method}")
    from bodyscan._io import atomic_write, check_out

    out = check_out(args.out, suffixes=(".ply",), error=BenchError)
    cloud = read_cloud(args.cloud)
    print(f"reconstruct: {len(cloud.points)} points, method {args.method}", file=sys.stderr)
    v, f, times = reconstruct_peer(args.method, cloud.points, cloud.view_dir)
    mesh = trimesh.Trimesh(v, f, process=False)
    atomic_write(out, lambda tmp: mesh.export(tmp, file_type="ply"), error=BenchError)
    t = ", ".join(f"{k} {x:.2f} s" for k, x in times.items())
    print(f"reconstruct: {len(f)} triangles -> {out} ({t})", file=sys.stderr)
    return 0


def _metric_params(items):
    import dataclasses

    from . import BenchError
    from .metrics import MetricParams

    from bodyscan._params import coerce

    overrides = _pairs(items, "--metric")
    fields = {f.name: f for f in dataclasses.fields(MetricParams)}
    values = {}
    for name, text in overrides.items():
        if name not in fields:
            raise BenchError(f"--metric {name}: unknown (known: {', '.join(fields)})")
        values[name] = coerce(fields[name], text, BenchError)
    return MetricParams(**values)


def bench_command(args) -> int:
    from .bench import RECON_METHODS, BenchConfig, failed_methods, run_bench

    from bodyscan._io import check_out

    from . import BenchError
    from .methods import command_spec, installed_methods

    if args.out:
        check_out(args.out, folder=True, error=BenchError)
    methods = tuple(args.methods or ()) or (RECON_METHODS if args.no_peers else ())
    if args.method_cmd:   # added to the methods named, or to the default set
        if not methods:
            from .peers import available_peers
            methods = RECON_METHODS + tuple(available_peers()) + tuple(installed_methods())
        methods += tuple(command_spec(t) for t in args.method_cmd)
    config = BenchConfig(bodies=args.bodies, presets=args.presets, ks=tuple(_k(k) for k in args.ks),
                         methods=methods, recon=_pairs(args.param, "--param"),
                         scanner=_scanner(args.scanner), seed=args.seed,
                         metric=_metric_params(args.metric), pictures=not args.no_pictures)
    result = run_bench(config, args.out, jobs=args.jobs)
    print(result.summary)
    print(f"\nreport: {result.out / 'report.md'}")
    none = failed_methods(result.table)
    for m in none:   # a method with no result at all is broken, not a hard body: the exit says so
        first = result.table.loc[result.table["method"] == m, "error"].iloc[0]
        print(f"bodyscan bench: error: method {m} failed on every scan ({first})", file=sys.stderr)
    return 1 if none else 0


def _k(text):
    from . import BenchError

    try:
        return float(text)
    except ValueError:
        raise BenchError(f"--k {text!r}: expected numbers like 1,2,3") from None


def _scanner(items) -> dict:
    """``--scanner`` overrides, as text: `simulator.ScannerConfig` converts and checks them."""
    import dataclasses

    from bodyscan.simulator import ScanError, ScannerConfig

    from . import BenchError

    out = _pairs(items, "--scanner")
    known = {f.name for f in dataclasses.fields(ScannerConfig)} | {"k"}
    for name in out:
        if name not in known:
            raise BenchError(f"--scanner {name}: unknown (known: {', '.join(sorted(known))})")
    try:
        ScannerConfig().replace(**out)
    except ScanError as exc:
        raise BenchError(f"--scanner: {exc}") from None
    return out


def _load_mesh(path):
    import numpy as np
    import trimesh

    from . import BenchError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such mesh file")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:
        raise BenchError(f"{path}: cannot read it as a mesh ({type(exc).__name__}: {exc})") from None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0:
        raise BenchError(f"{path}: holds no triangles (a point cloud? give the reconstructed mesh)")
    return np.asarray(mesh.vertices, dtype=np.float64), faces, mesh


def score_command(args) -> int:
    import numpy as np

    from bodyscan.poses.body import load_body

    from . import BenchError
    from .bench import score

    from bodyscan._io import check_out

    if args.out:
        check_out(args.out, error=BenchError)
    vertices, faces, mesh = _load_mesh(args.mesh)
    body = load_body(args.body)
    body.require_ground_truth("scoring")
    scan = None
    if args.cloud:
        from bodyscan import simulator

        scan = simulator.read_scan(args.cloud)
        scanned = scan.meta.get("body")
        if isinstance(scanned, str) and scanned and scanned != body.name:
            raise BenchError(f"{args.cloud}: this cloud is a scan of the body {scanned!r}, not of "
                             f"{body.name!r}: give --body {scanned}, or the cloud of {body.name!r}")
    joints = None
    if args.fit:
        try:
            joints = {k: np.asarray(v, float) for k, v in json.loads(Path(args.fit).read_text())["joints"].items()}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise BenchError(f"{args.fit}: not a fit file with joints ({exc})") from None
    scale = float(np.ptp(vertices, axis=0).max())
    if scale > 10 * body.height:
        raise BenchError(f"{args.mesh}: the mesh is {scale:.4g} units across; coordinates must be "
                         "metres, like the body")
    _warn_if_other_body(vertices, body, _metric_params(args.metric), args.mesh)
    point_sections, point_index = None, None
    if scan is not None:
        from scipy.spatial import cKDTree

        stored = _vertex_points(mesh, len(vertices), len(scan.points))
        if stored is not None:                          # a recon mesh: each vertex's input point
            point_index = stored
        elif vertices.shape == scan.points.shape and np.array_equal(vertices, scan.points):
            point_index = np.arange(len(vertices))     # the cloud's points, in order
        else:
            d, i = cKDTree(scan.points).query(vertices, distance_upper_bound=1e-6)
            point_index = np.where(np.isfinite(d), i, -1)
        point_sections = _point_sections(mesh, faces, point_index, len(scan.points))
    row = score(vertices, faces, body, scan, point_index=point_index, point_sections=point_sections,
                joints=joints, metric_params=_metric_params(args.metric))
    row = {"mesh": str(args.mesh), "body": body.name, "cloud": args.cloud, **row}
    if scan is None:   # what the scanner saw is unknown: no seen-surface measure (not the full one's copy)
        row.update({k: None for k in row if k == "seen_fraction"
                    or k.startswith(("recall_seen@", "fscore_seen@", "recall_unseen@"))})
    else:
        row["matched_vertex_fraction"] = float(np.mean(point_index >= 0))
    from bodyscan._io import dumps, write_text

    text = dumps(row, indent=1)
    if args.out:
        out = write_text(args.out, text + "\n", error=BenchError)
        print(f"bodyscan score: wrote {out}", file=sys.stderr)
    else:
        print(text)
    return 0


#: `score` warns when fewer of the mesh's vertices than this lie within `MATCH_DISTANCE` of the body.
MATCH_FRACTION, MATCH_DISTANCE = 0.5, 0.03


def _warn_if_other_body(vertices, body, metric_params, where) -> None:
    """Warn (one line) when the mesh does not lie on the body: a mesh of another body, or moved."""
    import warnings

    import numpy as np

    from .bench import ground_truth

    step = max(1, len(vertices) // 20000)
    near = ground_truth(body, metric_params).index.upper_bound(vertices[::step]) <= MATCH_DISTANCE
    if near.mean() < MATCH_FRACTION:
        warnings.warn(f"{where}: only {100 * near.mean():.0f} % of the mesh's vertices lie within "
                      f"{100 * MATCH_DISTANCE:g} cm of the body {body.name!r}: is it a mesh of this body, "
                      "in the body's frame (metres)?", stacklevel=2)


def _vertex_points(mesh, n_vertices, n_points):
    """(V,) int input point of each vertex from a `recon` mesh's vertex property ``point``
    (-1: none), or None when the mesh has none or it does not fit this cloud."""
    import numpy as np

    raw = getattr(mesh, "metadata", {}).get("_ply_raw", {})
    data = raw.get("vertex", {}).get("data")
    if data is None or "point" not in (data.dtype.names or ()):
        return None
    point = np.asarray(data["point"]).astype(np.int64).reshape(-1)
    if len(point) != n_vertices or point.max(initial=-1) >= n_points:
        return None
    return point


def _point_sections(mesh, faces, point_index, n_points):
    """(n, 11) bool section labels of the cloud points, from a `recon` mesh: the vertices'
    ``sections`` property (bit s: section s), exactly the labels `bench` scores; from a mesh
    written before it, the sections of the faces around each point (points on no face get none).
    None when the mesh has neither or no vertex is a cloud point."""
    import numpy as np

    from .metrics import SECTIONS

    raw = getattr(mesh, "metadata", {}).get("_ply_raw", {})
    if not (point_index >= 0).any():
        return None
    out = np.zeros((n_points, len(SECTIONS)), bool)
    vertex_attr = raw.get("vertex", {}).get("data")
    if vertex_attr is not None and "sections" in (vertex_attr.dtype.names or ()):
        bits = np.asarray(vertex_attr["sections"]).astype(np.int64).reshape(-1)
        keep = point_index >= 0
        out[point_index[keep]] = (bits[keep, None] >> np.arange(len(SECTIONS))) & 1 == 1
        return out
    face_attr = raw.get("face", {}).get("data")
    section = None
    if face_attr is not None and "section" in (face_attr.dtype.names or ()):
        section = np.asarray(face_attr["section"]).astype(np.int64).reshape(-1)
    if section is None or len(section) != len(faces):
        return None
    ok = (section >= 0) & (section < len(SECTIONS))
    for c in range(3):
        pi = point_index[faces[ok, c]]
        keep = pi >= 0
        out[pi[keep], section[ok][keep]] = True
    return out
