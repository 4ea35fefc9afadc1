"""The posed-body file format: a mesh with ground-truth sections and joints, loaded and checked once.

A body file is an ``.npz`` with

- ``vertices`` (V, 3) float, metres, +z up, floor at z = 0, the subject faces -y, left is +x;
- ``faces`` (F, 3) int, outward-facing winding;
- ``vertex_section`` (V,) int8, ground-truth body section of each vertex (see `SECTIONS`);
- ``joint_names`` (J,) str and ``joints`` (J, 3) float, at least `REQUIRED_JOINTS`;
- any extra keys (shape parameters, pose angles, generator version), kept as they are.

Anything that takes a body accepts a library name, the path of such an ``.npz``, or any mesh file
trimesh reads (then the body has no ground truth and `Body.require_ground_truth` says so).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The 11 body sections, in label order (``vertex_section`` values). ``_l`` is the subject's left (+x).
SECTIONS = (
    "head",         # 0, neck included
    "chest",        # 1
    "waist",        # 2, abdomen and pelvis
    "upper_arm_l",  # 3
    "upper_arm_r",  # 4
    "forearm_l",    # 5, hand included
    "forearm_r",    # 6
    "thigh_l",      # 7
    "thigh_r",      # 8
    "lower_leg_l",  # 9, foot included
    "lower_leg_r",  # 10
)

#: Joint names every body file with ground truth carries.
REQUIRED_JOINTS = (
    "pelvis", "chest", "neck", "head",
    "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r",
    "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r",
)

#: Mesh file types read through trimesh (no ground truth).
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")

#: A body taller than this (metres) is almost surely in millimetres or centimetres.
MAX_HEIGHT_M = 3.0
#: A body smaller than this (metres) is almost surely in the wrong units too.
MIN_HEIGHT_M = 0.3


class BodyError(ValueError):
    """A body file or body array that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True, eq=False)
class Body:
    """A posed body mesh, with ground truth when it comes from a body file.

    Attributes
    ----------
    name : str
        Library name or file stem.
    vertices : (V, 3) float
        Metres, +z up, subject facing -y.
    faces : (F, 3) int
        Outward-facing winding.
    vertex_section : (V,) int8 or None
        Ground-truth section of each vertex, index into `SECTIONS`; None for a plain mesh.
    joint_names : tuple of str
        Names of ``joints`` rows (empty for a plain mesh).
    joints : (J, 3) float or None
        Joint centres, metres.
    extras : dict
        Any other arrays of the file (shape parameters, pose angles, generator version).
    source : str
        Where the body was loaded from.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    vertex_section: np.ndarray | None = None
    joint_names: tuple = ()
    joints: np.ndarray | None = None
    extras: dict = field(default_factory=dict)
    source: str = ""

    @property
    def has_ground_truth(self) -> bool:
        return self.vertex_section is not None and self.joints is not None

    @property
    def height(self) -> float:
        """Extent along z, metres."""
        return float(np.ptp(self.vertices[:, 2])) if len(self.vertices) else 0.0

    def joint(self, name: str) -> np.ndarray:
        """Position (3,) of the joint called ``name``."""
        self.require_ground_truth("joint positions")
        try:
            return self.joints[self.joint_names.index(name)]
        except ValueError:
            raise BodyError(f"{self.source or self.name}: no joint named {name!r}") from None

    def joint_dict(self) -> dict[str, np.ndarray]:
        """Joints as {name: (3,) float}."""
        self.require_ground_truth("joint positions")
        return dict(zip(self.joint_names, self.joints))

    def face_section(self) -> np.ndarray:
        """(F,) int8 section of each face: the majority label of its three vertices."""
        self.require_ground_truth("section labels")
        lab = self.vertex_section[self.faces]
        # majority of three; when all differ, the first vertex's label
        return np.where(lab[:, 1] == lab[:, 2], lab[:, 1], lab[:, 0]).astype(np.int8)

    def require_ground_truth(self, what: str = "ground truth") -> None:
        """Raise `BodyError` when this body is a plain mesh without section labels and joints."""
        if not self.has_ground_truth:
            raise BodyError(
                f"{self.source or self.name}: a plain mesh has no ground truth, but {what} "
                "is needed; use a body .npz from the library (see `bodyscan poses list`)")

    def to_trimesh(self):
        """The mesh as a `trimesh.Trimesh` (no processing, so vertex order is kept)."""
        import trimesh
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def validate(body: Body, *, check_units: bool = True) -> Body:
    """Check array shapes, types, ranges and units; return the body or raise `BodyError`.

    Parameters
    ----------
    body : Body
    check_units : bool
        Reject bodies whose height is outside [`MIN_HEIGHT_M`, `MAX_HEIGHT_M`] metres.
    """
    where = body.source or body.name
    v, f = body.vertices, body.faces
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise BodyError(f"{where}: vertices must be a non-empty (V, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise BodyError(f"{where}: faces must be a non-empty (F, 3) array, got shape {f.shape}")
    if not np.issubdtype(v.dtype, np.floating):
        raise BodyError(f"{where}: vertices must be floats, got {v.dtype}")
    if not np.issubdtype(f.dtype, np.integer):
        raise BodyError(f"{where}: faces must be integers, got {f.dtype}")
    if not np.isfinite(v).all():
        raise BodyError(f"{where}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices are NaN or infinite")
    if f.min() < 0 or f.max() >= len(v):
        raise BodyError(f"{where}: faces index vertices outside 0..{len(v) - 1}")
    if check_units:
        h = body.height
        if h > MAX_HEIGHT_M:
            raise BodyError(f"{where}: the body is {h:.4g} units tall; coordinates must be metres "
                            f"(divide millimetres by 1000)")
        if h < MIN_HEIGHT_M:
            raise BodyError(f"{where}: the body is {h:.4g} units tall; coordinates must be metres")
    if body.vertex_section is not None:
        s = body.vertex_section
        if s.shape != (len(v),):
            raise BodyError(f"{where}: vertex_section must have shape ({len(v)},), got {s.shape}")
        if not np.issubdtype(s.dtype, np.integer) or s.min() < 0 or s.max() >= len(SECTIONS):
            raise BodyError(f"{where}: vertex_section must hold integers 0..{len(SECTIONS) - 1}")
    if body.joints is not None:
        j = body.joints
        if j.ndim != 2 or j.shape[1] != 3 or len(j) != len(body.joint_names):
            raise BodyError(f"{where}: joints must be (J, 3) with one name per row")
        if not np.isfinite(j).all():
            raise BodyError(f"{where}: joints hold NaN or infinite values")
        missing = [n for n in REQUIRED_JOINTS if n not in body.joint_names]
        if missing:
            raise BodyError(f"{where}: joints missing: {', '.join(missing)}")
    return body


def _from_npz(path: Path) -> Body:
    import zipfile
    if path.is_file() and not zipfile.is_zipfile(path):  # np.load would try it as a pickle
        raise BodyError(f"{path}: not a .npz body file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # zipfile, pickle, OSError: all mean "not a readable npz"
        raise BodyError(f"{path}: not a readable .npz body file ({type(exc).__name__}: {exc})") from None
    missing = [k for k in ("vertices", "faces", "vertex_section", "joint_names", "joints") if k not in data]
    if missing:
        raise BodyError(f"{path}: body file lacks {', '.join(missing)}")
    extras = {k: data[k] for k in data if k not in ("vertices", "faces", "vertex_section", "joint_names", "joints")}
    return Body(
        name=path.stem,
        vertices=np.asarray(data["vertices"], dtype=np.float64) if np.issubdtype(data["vertices"].dtype, np.floating) else data["vertices"],
        faces=data["faces"].astype(np.int64) if np.issubdtype(data["faces"].dtype, np.integer) else data["faces"],
        vertex_section=data["vertex_section"],
        joint_names=tuple(str(n) for n in data["joint_names"]),
        joints=np.asarray(data["joints"], dtype=np.float64) if np.issubdtype(data["joints"].dtype, np.number) else data["joints"],
        extras=extras,
        source=str(path),
    )


def _from_mesh(path: Path) -> Body:
    import trimesh
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:
        raise BodyError(f"{path}: trimesh cannot read it as a mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise BodyError(f"{path}: holds no triangles")
    return Body(name=path.stem, vertices=np.asarray(mesh.vertices, dtype=np.float64),
                faces=np.asarray(mesh.faces, dtype=np.int64), source=str(path))


def load_body(spec: str | os.PathLike, *, check_units: bool = True) -> Body:
    """Load a body from a library name, a body ``.npz`` or any mesh file trimesh reads.

    Parameters
    ----------
    spec : str or path
        ``standing`` (a name from `poses.list_bodies`), ``path/to/body.npz``, or ``scan.obj``.
    check_units : bool
        Reject bodies that are not plausibly in metres.

    Returns
    -------
    body : Body

    Raises
    ------
    BodyError
        One line naming the file and what is wrong.
    """
    from .library import find_body, list_bodies

    path = Path(spec)
    if not path.exists():
        found = find_body(str(spec))
        if found is None:
            names = ", ".join(list_bodies()) or "(none shipped)"
            raise BodyError(f"{spec}: no such file and no such body in the library (known: {names})")
        path = found
    if path.is_dir():
        raise BodyError(f"{path}: is a directory, not a body file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        body = _from_npz(path)
    elif suffix in MESH_SUFFIXES:
        body = _from_mesh(path)
    else:
        raise BodyError(f"{path}: unknown body file type {suffix!r} (use .npz or one of {', '.join(MESH_SUFFIXES)})")
    return validate(body, check_units=check_units)


def save_body(body: Body, path: str | os.PathLike) -> Path:
    """Write ``body`` (which must carry ground truth) as a compressed body ``.npz``; return the path."""
    validate(body)
    body.require_ground_truth("saving a body file")
    path = Path(path)
    from bodyscan._io import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = dict(
        vertices=np.asarray(body.vertices, dtype=np.float32),
        faces=np.asarray(body.faces, dtype=np.int32),
        vertex_section=np.asarray(body.vertex_section, dtype=np.int8),
        joint_names=np.asarray(body.joint_names, dtype=str),
        joints=np.asarray(body.joints, dtype=np.float32),
        **body.extras,
    )

    def write(tmp):
        with open(tmp, "wb") as fh:   # a file object: numpy adds no ".npz" to the name
            np.savez_compressed(fh, **arrays)
    return atomic_write(path, write, error=BodyError)
