"""Point clouds on disk: a binary PLY with per-point sensor data, ground truth and scan metadata.

Vertex properties, in this order::

    double x, y, z          metres
    uchar  head             index of the head that measured the point
    float  vx, vy, vz       unit vector from the point toward its camera
    int    gt_face          ground truth: source triangle of the body mesh
    char   gt_section       ground truth: body section (-1: none)
    float  gt_nx, gt_ny, gt_nz   ground truth: outward unit normal of that triangle

Metadata goes in header lines ``comment bodyscan <key> <json>``. MeshLab rejects header lines over
about 500 characters, so a long dict or list value is split over dotted keys (``config.projection``,
``config.heads.0``, ...), which `read_scan` joins again. trimesh, Open3D, MeshLab and CloudCompare
read the file as a point cloud; `read_scan` reads everything back.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from . import ScanError
from .scan import Scan

#: PLY vertex layout (name, numpy little-endian type, PLY type).
FIELDS = (
    ("x", "<f8", "double"), ("y", "<f8", "double"), ("z", "<f8", "double"),
    ("head", "u1", "uchar"),
    ("vx", "<f4", "float"), ("vy", "<f4", "float"), ("vz", "<f4", "float"),
    ("gt_face", "<i4", "int"),
    ("gt_section", "i1", "char"),
    ("gt_nx", "<f4", "float"), ("gt_ny", "<f4", "float"), ("gt_nz", "<f4", "float"),
)

#: PLY scalar type names (both spellings) to numpy little-endian types.
PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}

COMMENT = "comment bodyscan "

#: Longest JSON text on one header line before a dict or list value is split over dotted keys.
MAX_JSON = 400


def _header_items(key: str, value) -> list[tuple[str, str]]:
    """(key, json) pairs for ``value``, splitting long dicts and lists over ``key.sub`` keys."""
    text = json.dumps(value, separators=(",", ":"), allow_nan=False)
    if len(text) <= MAX_JSON or not isinstance(value, (dict, list)) or not value:
        return [(key, text)]
    items = value.items() if isinstance(value, dict) else enumerate(value)
    return [pair for sub, v in items for pair in _header_items(f"{key}.{sub}", v)]


def _join_dotted(meta: dict) -> dict:
    """Inverse of `_header_items`: nest ``a.b.0`` keys back into dicts and lists."""
    out: dict = {}
    for key, value in meta.items():
        *path, last = key.split(".")
        node = out
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value

    def lists(node):
        if not isinstance(node, dict):
            return node
        node = {k: lists(v) for k, v in node.items()}
        if node and all(k.isdigit() for k in node) and sorted(map(int, node)) == list(range(len(node))):
            return [node[str(i)] for i in range(len(node))]
        return node

    return {k: lists(v) for k, v in out.items()}


def write_cloud(scan: Scan, path: str | os.PathLike) -> Path:
    """Write ``scan`` as a binary little-endian PLY; return the path.

    Parameters
    ----------
    scan : Scan
    path : str or path
        Output file (parent folders are created), written atomically (`bodyscan._io`).
    """
    path = Path(path)
    n = len(scan.points)
    if n and int(scan.head.max()) > 255:
        raise ScanError(f"{path}: head indices above 255 do not fit the PLY 'head' property")
    data = np.empty(n, dtype=[(name, t) for name, t, _ in FIELDS])
    for i, c in enumerate("xyz"):
        data[c] = scan.points[:, i]
        data[f"v{c}"] = scan.view_dir[:, i]
        data[f"gt_n{c}"] = scan.gt_normal[:, i]
    data["head"] = scan.head
    data["gt_face"] = scan.gt_face
    data["gt_section"] = scan.gt_section
    lines = ["ply", "format binary_little_endian 1.0"]
    for key, value in scan.meta.items():
        if not key or any(c in key for c in " .\n"):
            raise ScanError(f"{path}: metadata key {key!r} cannot be written to a PLY header")
        lines += [f"{COMMENT}{k} {text}" for k, text in _header_items(key, value)]
    lines.append(f"element vertex {n}")
    lines += [f"property {ply} {name}" for name, _, ply in FIELDS]
    lines.append("end_header")
    from bodyscan._io import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)

    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(("\n".join(lines) + "\n").encode("ascii"))
            fh.write(data.tobytes())
    return atomic_write(path, write, error=ScanError)


def read_header(fh, path) -> tuple[int, list[tuple[str, str]], dict]:
    """Parse a binary little-endian PLY header.

    Returns
    -------
    n : int
        Vertex count.
    properties : list of (name, numpy type)
        Vertex properties in file order.
    meta : dict
        ``comment bodyscan`` entries, JSON-decoded.
    """
    if fh.readline().strip() != b"ply":
        raise ScanError(f"{path}: not a PLY file")
    n, props, meta, element = None, [], {}, None
    while True:
        raw = fh.readline()
        if not raw:
            raise ScanError(f"{path}: PLY header has no end_header")
        line = raw.decode("ascii", errors="replace").strip()
        if line == "end_header":
            break
        if line.startswith(COMMENT):
            key, _, text = line[len(COMMENT):].partition(" ")
            try:
                meta[key] = json.loads(text)
            except json.JSONDecodeError:
                meta[key] = text
            continue
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and words[1:2] != ["binary_little_endian"]:
            raise ScanError(f"{path}: PLY format {words[1]!r} is not supported (binary_little_endian only)")
        if words[0] == "element":
            element = words[1]
            if element == "vertex":
                if n is not None or props:
                    raise ScanError(f"{path}: unexpected PLY layout")
                n = int(words[2])
            elif n is None:
                raise ScanError(f"{path}: PLY element {element!r} before the vertices is not supported")
        elif words[0] == "property" and element == "vertex":
            if words[1] == "list" or words[1] not in PLY_TYPES:
                raise ScanError(f"{path}: unsupported vertex property {' '.join(words[1:])!r}")
            props.append((words[2], PLY_TYPES[words[1]]))
    if n is None:
        raise ScanError(f"{path}: PLY file has no vertex element")
    return n, props, _join_dotted(meta)


def read_scan(path: str | os.PathLike) -> Scan:
    """Read a cloud written by `write_cloud` back into a `Scan` (every field and the metadata).

    Parameters
    ----------
    path : str or path

    Returns
    -------
    scan : Scan
        Ground-truth fields missing from the file are filled with -1 (``gt_face``,
        ``gt_section``) or zeros (``gt_normal``); a missing ``head`` is 0.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such cloud file")
    with open(path, "rb") as fh:
        n, props, meta = read_header(fh, path)
        dtype = np.dtype(props)
        data = np.fromfile(fh, dtype=dtype, count=n)
    if len(data) != n:
        raise ScanError(f"{path}: PLY file is truncated ({len(data)} of {n} vertices)")
    names = set(dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise ScanError(f"{path}: PLY vertices lack x, y, z")

    def cols(keys, typ, fill):
        if set(keys) <= names:
            return np.stack([data[k] for k in keys], axis=1).astype(typ)
        return np.full((n, len(keys)), fill, typ)

    return Scan(
        points=cols(("x", "y", "z"), np.float64, 0),
        head=data["head"].astype(np.int16) if "head" in names else np.zeros(n, np.int16),
        view_dir=cols(("vx", "vy", "vz"), np.float32, 0),
        gt_face=data["gt_face"].astype(np.int64) if "gt_face" in names else np.full(n, -1, np.int64),
        gt_section=data["gt_section"].astype(np.int8) if "gt_section" in names else np.full(n, -1, np.int8),
        gt_normal=cols(("gt_nx", "gt_ny", "gt_nz"), np.float32, 0),
        meta=meta,
    )
