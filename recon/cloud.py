"""Read a point cloud from a scanner file: xyz and viewing directions only, never ground truth.

Formats: PLY (ascii or binary, the simulator's or any scanner's; meshes too, their vertices become
the points), whitespace text ``.xyz``/``.txt``/``.asc``/``.pts`` (the first three columns are x y z),
and ``.pcd`` (ascii or binary). Vertex properties whose names start with ``gt_`` are dropped while
the header is parsed, so nothing returned by this module can reach them.

Rows with NaN or infinite coordinates are dropped with a warning (a real scanner writes NaN for a
missing measurement); the cloud is then checked: enough points, and metres, not millimetres.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import ReconError

#: Fewer points than this cannot hold a body.
MIN_POINTS = 300
#: A cloud wider than this (metres) is almost surely in millimetres.
MAX_EXTENT_M = 3.0

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass(frozen=True, eq=False)
class Cloud:
    """A scanned point cloud.

    Attributes
    ----------
    points : (n, 3) float64
        Metres.
    view_dir : (n, 3) float64 or None
        Per point, the unit direction towards the sensor that measured it, when the file has one.
    meta : dict
        ``comment bodyscan <key> <json>`` header lines of a PLY, as {key: value}.
    source : str
        The file read.
    head : (n,) int64 or None
        Per point, the index of the scanner head that measured it, when the file has one (a PLY
        vertex property ``head``; for registration between heads).
    """

    points: np.ndarray
    view_dir: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    source: str = ""
    head: np.ndarray | None = None


def check_points(points, where: str = "points", *, min_points: int = MIN_POINTS) -> np.ndarray:
    """Validate a cloud once at the boundary; return it as (n, 3) float64 or raise `ReconError`.

    Parameters
    ----------
    points : (n, 3) array_like, metres
    where : str
        Name used in the message (a file name).
    min_points : int
    """
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise ReconError(f"{where}: points must be an (n, 3) array of numbers") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReconError(f"{where}: points must be an (n, 3) array, got shape {p.shape}")
    if not np.isfinite(p).all():
        bad = int((~np.isfinite(p)).any(axis=1).sum())
        raise ReconError(f"{where}: {bad} points are NaN or infinite; drop them first")
    if len(p) < min_points:
        raise ReconError(f"{where}: only {len(p)} points; a body needs at least {min_points}")
    extent = float(np.ptp(p, axis=0).max())
    if extent > MAX_EXTENT_M:
        raise ReconError(f"{where}: the cloud spans {extent:.4g} units; coordinates must be metres "
                         f"(divide millimetres by 1000)")
    return p


def read_cloud(path) -> Cloud:
    """Read a point cloud file.

    Parameters
    ----------
    path : str or path
        ``.ply``, ``.xyz``, ``.txt``, ``.asc``, ``.pts`` or ``.pcd``.

    Returns
    -------
    cloud : Cloud
        Points in metres (rows with NaN dropped, with a warning), viewing directions if present.

    Raises
    ------
    ReconError
        One line naming the file: unreadable, no points, too few points, not metres.
    FileNotFoundError
        No such file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise ReconError(f"{path}: is a directory, not a point cloud file")
    suffix = path.suffix.lower()
    try:
        head = None
        if suffix == ".ply":
            points, view, meta, head = _read_ply(path)
        elif suffix in (".xyz", ".txt", ".asc", ".pts", ".csv"):
            points, view, meta = _read_text(path), None, {}
        elif suffix == ".pcd":
            points, view, meta = _read_pcd(path), None, {}
        else:   # a .npz is most likely a body of the pose library or a corpus: a mesh, not a scan
            hint = f"; a body file is scanned first: bodyscan scan {path} --out CLOUD.ply" if suffix == ".npz" else ""
            raise ReconError(f"{path}: unknown cloud file type {suffix!r} (use .ply, .xyz, .txt or .pcd){hint}")
    except ReconError:
        raise
    except Exception as exc:  # any parser failure means "not a readable cloud"
        raise ReconError(f"{path}: not a readable point cloud ({type(exc).__name__}: {exc})") from None
    if points is None or len(points) == 0:
        raise ReconError(f"{path}: holds no points")
    finite = np.isfinite(points).all(axis=1)
    if view is not None:
        view = np.asarray(view, dtype=np.float64)
        ok = np.isfinite(view).all(axis=1) & (np.linalg.norm(view, axis=1) > 0)
        view = view if ok[finite].all() else None
    if not finite.all():
        warnings.warn(f"{path}: dropped {int((~finite).sum())} points with NaN or infinite coordinates",
                      stacklevel=2)
        points = points[finite]
        view = view[finite] if view is not None else None
        head = head[finite] if head is not None else None
    points = check_points(points, str(path))
    if view is not None:
        view = view / np.linalg.norm(view, axis=1, keepdims=True)
    return Cloud(points=points, view_dir=view, meta=meta, source=str(path), head=head)


# -- PLY ----------------------------------------------------------------------------------------
def _read_ply(path: Path):
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ReconError(f"{path}: not a PLY file (no 'ply' magic line)")
        header = []
        while True:
            line = f.readline()
            if not line:
                raise ReconError(f"{path}: PLY header has no end_header line")
            line = line.decode("ascii", "replace").strip()
            if line == "end_header":
                break
            header.append(line)
        body_offset = f.tell()
    fmt, meta, elements = None, {}, []
    for line in header:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment" and len(words) >= 3 and words[1] == "bodyscan":
            key = words[2]
            if key.startswith("gt_"):
                continue
            raw = line.split(None, 3)[3] if len(words) > 3 else ""
            try:
                meta[key] = json.loads(raw)
            except ValueError:
                meta[key] = raw
        elif words[0] == "element":
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise ReconError(f"{path}: PLY property before any element")
            if words[1] == "list":
                elements[-1][2].append((words[-1], None))
            else:
                if words[1] not in _PLY_TYPES:
                    raise ReconError(f"{path}: unknown PLY property type {words[1]!r}")
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ReconError(f"{path}: unknown PLY format {fmt!r}")
    if not elements or elements[0][0] != "vertex":
        raise ReconError(f"{path}: PLY has no vertex element first")
    _, count, props = elements[0]
    if any(t is None for _, t in props):
        return _read_ply_trimesh(path) + (meta, None)
    names = [n for n, _ in props]
    if not all(c in names for c in "xyz"):
        raise ReconError(f"{path}: PLY vertices lack x, y, z")
    # ground-truth properties are never kept: only x y z and the viewing direction leave this function
    wanted = [n for n in ("x", "y", "z", "vx", "vy", "vz", "head") if n in names and not n.startswith("gt_")]
    if fmt == "ascii":
        cols = [names.index(n) for n in wanted]
        data = np.loadtxt(path, skiprows=len(header) + 2, max_rows=count, usecols=cols, ndmin=2,
                          dtype=np.float64)
        table = {n: data[:, i] for i, n in enumerate(wanted)}
    else:
        end = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, end + t) for n, t in props])
        raw = np.fromfile(path, dtype=dtype, count=count, offset=body_offset)
        if len(raw) < count:
            raise ReconError(f"{path}: PLY holds {len(raw)} of its {count} vertices (truncated file)")
        table = {n: raw[n].astype(np.float64) for n in wanted}
        del raw
    points = np.stack([table["x"], table["y"], table["z"]], axis=1)
    view = np.stack([table[n] for n in ("vx", "vy", "vz")], axis=1) if "vz" in table and "vx" in table \
        and "vy" in table else None
    head = table["head"].astype(np.int64) if "head" in table else None
    if head is not None and (len(head) == 0 or head.min() < 0):
        head = None
    return points, view, meta, head


def _read_ply_trimesh(path: Path):
    import trimesh

    geom = trimesh.load(path, process=False)
    vertices = getattr(geom, "vertices", None)
    if vertices is None:
        raise ReconError(f"{path}: trimesh finds no vertices in it")
    return np.asarray(vertices, dtype=np.float64), None


# -- text and PCD -------------------------------------------------------------------------------
def _read_text(path: Path) -> np.ndarray:
    """Rows of x y z (more columns ignored; comma or white-space separated; ``#`` and ``//``
    comment lines skipped). A first row that is not a row of numbers (a column header) or is one
    number alone (the point count of a .pts file) is skipped."""
    lines = path.read_text(errors="replace").splitlines()
    data_lines = [i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith(("#", "//"))]
    if not data_lines:
        return np.zeros((0, 3))
    delim = "," if "," in lines[data_lines[0]] else None
    first = lines[data_lines[0]].split(delim)
    try:
        np.asarray(first, dtype=np.float64)
        header = len(first) == 1
    except ValueError:
        header = True
    data_lines = data_lines[1:] if header else data_lines
    if not data_lines:
        return np.zeros((0, 3))
    rows = [lines[i] for i in data_lines]
    try:
        data = np.loadtxt(rows, delimiter=delim, ndmin=2, dtype=np.float64)
    except ValueError:   # name the file's first bad line (this loop runs on failure only)
        width = len(rows[0].split(delim))
        for i, row in zip(data_lines, rows):
            cells = row.split(delim)
            try:
                np.asarray(cells, dtype=np.float64)
            except ValueError:
                raise ReconError(f"{path}: line {i + 1} is not a row of numbers: {row.strip()[:60]!r}") from None
            if len(cells) != width:
                raise ReconError(f"{path}: line {i + 1} has {len(cells)} columns, the rows before it "
                                 f"{width}") from None
        raise
    if data.shape[1] < 3:
        raise ReconError(f"{path}: text cloud rows need at least 3 columns (x y z), found {data.shape[1]}")
    return data[:, :3]


def _read_pcd(path: Path) -> np.ndarray:
    raw = path.read_bytes()
    head, fields, sizes, types, counts, n, mode = {}, [], [], [], [], None, None
    pos = 0
    while True:
        nl = raw.index(b"\n", pos)
        line = raw[pos:nl].decode("ascii", "replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        head[key.upper()] = vals
        if key.upper() == "DATA":
            mode = vals[0].lower()
            break
    fields = head.get("FIELDS", [])
    sizes = [int(s) for s in head.get("SIZE", [])]
    types = head.get("TYPE", [])
    counts = [int(c) for c in head.get("COUNT", ["1"] * len(fields))]
    n = int(head.get("POINTS", head.get("WIDTH", ["0"]))[0])
    if not all(c in fields for c in "xyz"):
        raise ReconError(f"{path}: PCD has no x y z fields")
    if mode == "ascii":
        data = np.loadtxt(raw[pos:].decode("ascii", "replace").splitlines(), ndmin=2, dtype=np.float64)
        col = np.cumsum([0] + counts)
        return data[:, [col[fields.index(c)] for c in "xyz"]]
    if mode != "binary":
        raise ReconError(f"{path}: PCD DATA {mode} is not supported (use ascii or binary)")
    kinds = {"F": "f", "I": "i", "U": "u"}
    dtype = np.dtype([(f, f"<{kinds[t]}{s}", (c,)) for f, s, t, c in zip(fields, sizes, types, counts)])
    data = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
    return np.stack([data[c][:, 0].astype(np.float64) for c in "xyz"], axis=1)

