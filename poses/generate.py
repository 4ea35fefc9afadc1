"""Generate posed bodies with ground truth from the anny body model (needs the ``bodies`` extra).

A body is made from a *posture* (joint angles, `load_posture`) and a *shape* (anny phenotype
parameters, `load_shape`), both small YAML files in ``poses/postures/`` and ``poses/shapes/``:

- anny poses its mesh (linear blend skinning, topology ``anny-noeyes-notongue``, a single
  watertight mesh of 13,348 vertices);
- each vertex gets the section whose bones carry most of its skinning weight (`SECTION_BONES`);
- edges longer than `GenerateParams.max_edge_m`, or bending more than `GenerateParams.max_sag_m`,
  are split at a curved (PN-triangle) midpoint, so that the coarse torso facets (20-57 mm edges)
  do not show in a 2 mm scan (the flat facets then stay within ~0.8 mm of the smooth surface);
  labels follow the interpolated skinning weights;
- the body is put on the floor (min z = 0) and centred in x, y on the pelvis.

Posture YAML (angles in degrees, relative to anny's rest pose, which is an A-pose)::

    description: arms hanging along the body
    both:                       # left side (.L) as written, mirrored to the right side (.R)
      upperarm01: [0, 35, 0]
    bones:                      # any bone by its anny name
      spine02: [-5, 0, 0]

Each triple ``[x, y, z]`` is a rotation of the bone about its head, about the world axes
(x = subject's left, y = back, z = up) taken in that order (extrinsic xyz), composed down the
kinematic chain (anny's ``local-ref`` parameterization). Mirroring to the right side negates the
y and z angles.

Shape YAML::

    description: average adult male
    phenotype: {gender: 0.0, age: 0.7, muscle: 0.5, weight: 0.5, height: 0.5, proportions: 0.5}

(anny phenotypes in [0, 1]; gender 0 is male, 1 female; age 1/3 is a child, 2/3 a young adult.)

The cache of the anny model (about 800 MB, written at the first build, which takes a minute or
more) goes to ``$ANNY_CACHE_DIR`` when it is set, otherwise to anny's default (``~/.cache/anny``).
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .body import REQUIRED_JOINTS, SECTIONS, Body, BodyError
from .checks import vertex_normals

#: Version of this generator; stored in every generated body file.
GENERATOR_VERSION = "1"

#: Folders of the shipped postures and shapes.
POSTURES_DIR = Path(__file__).resolve().parent / "postures"
SHAPES_DIR = Path(__file__).resolve().parent / "shapes"

#: anny bones of each section (a bone belongs to the first section whose prefix it starts with).
SECTION_BONES = {
    "head": ("neck", "head", "eye", "jaw", "tongue"),
    "chest": ("spine02", "spine01", "clavicle", "shoulder01", "breast"),
    "waist": ("root", "pelvis", "spine05", "spine04", "spine03"),
    "upper_arm_l": ("upperarm01.L", "upperarm02.L"),
    "upper_arm_r": ("upperarm01.R", "upperarm02.R"),
    "forearm_l": ("lowerarm01.L", "lowerarm02.L", "wrist.L", "finger*.L", "metacarpal*.L"),
    "forearm_r": ("lowerarm01.R", "lowerarm02.R", "wrist.R", "finger*.R", "metacarpal*.R"),
    "thigh_l": ("upperleg01.L", "upperleg02.L"),
    "thigh_r": ("upperleg01.R", "upperleg02.R"),
    "lower_leg_l": ("lowerleg01.L", "lowerleg02.L", "foot.L", "toe*.L"),
    "lower_leg_r": ("lowerleg01.R", "lowerleg02.R", "foot.R", "toe*.R"),
}

#: Body-format joint name -> anny bone whose head it is.
JOINT_BONES = {
    "pelvis": "root", "chest": "spine01", "neck": "neck01", "head": "head",
    "shoulder_l": "upperarm01.L", "shoulder_r": "upperarm01.R",
    "elbow_l": "lowerarm01.L", "elbow_r": "lowerarm01.R",
    "wrist_l": "wrist.L", "wrist_r": "wrist.R",
    "hip_l": "upperleg01.L", "hip_r": "upperleg01.R",
    "knee_l": "lowerleg01.L", "knee_r": "lowerleg01.R",
    "ankle_l": "foot.L", "ankle_r": "foot.R",
}

PHENOTYPES = ("gender", "age", "muscle", "weight", "height", "proportions")


@dataclass(frozen=True)
class GenerateParams:
    """How a body is made from anny (the paper used Poser figures; these choices are ours).

    Attributes
    ----------
    max_edge_m : float
        Edges longer than this (metres) are split at a curved midpoint, repeatedly, until none is
        longer. anny's torso has 20-57 mm edges; 25 mm keeps the faceting of the torso below
        ~0.5 mm and the shipped library small (~0.3 MB a body).
    max_sag_m : float
        Edges whose curved midpoint lies farther than this (metres) from the straight one are
        split too: this bounds the faceting where the surface bends sharply (shoulders, knees).
    quantum_m : float
        Vertices are rounded to multiples of this (metres; 2**-17 m, about 7.6 micrometres), a
        power of two so that the float32 file compresses better and the value is exact.
    rig : str
        anny rig.
    topology : str
        anny topology (``anny-noeyes-notongue`` is a single watertight surface).
    """

    max_edge_m: float = 0.025
    max_sag_m: float = 0.0008
    quantum_m: float = 2.0 ** -17
    rig: str = "anny"
    topology: str = "anny-noeyes-notongue"


# ----------------------------------------------------------------------------- specs (YAML)

def _read_yaml(path: Path, what: str) -> dict:
    import yaml
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise
    except Exception as exc:
        raise BodyError(f"{path}: not a readable {what} YAML ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise BodyError(f"{path}: a {what} YAML must be a mapping")
    return data


def _resolve(spec, folder: Path, what: str) -> tuple[str, dict]:
    if isinstance(spec, dict):
        return str(spec.get("name", what)), spec
    path = Path(spec)
    if not path.suffix and not path.exists():
        path = folder / f"{spec}.yaml"
        if not path.is_file():
            known = ", ".join(sorted(p.stem for p in folder.glob("*.yaml")))
            raise BodyError(f"{spec}: no such {what} file and no such {what} in the library (known: {known})")
    if not path.is_file():
        raise BodyError(f"{path}: no such {what} file")
    data = _read_yaml(path, what)
    return str(data.get("name", path.stem)), data


def list_postures() -> list[str]:
    """Names of the shipped postures (``poses/postures/*.yaml``), sorted."""
    return sorted(p.stem for p in POSTURES_DIR.glob("*.yaml"))


def list_shapes() -> list[str]:
    """Names of the shipped body shapes (``poses/shapes/*.yaml``), sorted."""
    return sorted(p.stem for p in SHAPES_DIR.glob("*.yaml"))


def _triple(value, where: str) -> list[float]:
    arr = np.asarray(value, dtype=float) if isinstance(value, (list, tuple)) else None
    if arr is None or arr.shape != (3,) or not np.isfinite(arr).all():
        raise BodyError(f"{where}: a bone angle must be a list of three numbers [x, y, z] in degrees")
    return [float(a) for a in arr]


def load_posture(spec) -> dict:
    """Read a posture: a library name, a YAML path, or an already parsed mapping.

    Returns
    -------
    posture : dict
        ``{"name": str, "description": str, "bones": {anny bone: [x, y, z] degrees}}`` with the
        ``both`` entries expanded into ``.L`` and mirrored ``.R`` bones.
    """
    name, data = _resolve(spec, POSTURES_DIR, "posture")
    unknown = set(data) - {"name", "description", "both", "bones"}
    if unknown:
        raise BodyError(f"{name}: unknown posture keys {sorted(unknown)} (use description, both, bones)")
    bones: dict[str, list[float]] = {}
    for bone, angles in (data.get("both") or {}).items():
        x, y, z = _triple(angles, f"{name}: both.{bone}")
        bones[f"{bone}.L"] = [x, y, z]
        bones[f"{bone}.R"] = [x, 0.0 - y, 0.0 - z]
    for bone, angles in (data.get("bones") or {}).items():
        bones[str(bone)] = _triple(angles, f"{name}: bones.{bone}")
    return {"name": name, "description": str(data.get("description", "")), "bones": bones}


def load_shape(spec) -> dict:
    """Read a body shape: a library name, a YAML path, or an already parsed mapping.

    Returns
    -------
    shape : dict
        ``{"name": str, "description": str, "phenotype": {name: value in [0, 1]}}``.
    """
    name, data = _resolve(spec, SHAPES_DIR, "shape")
    unknown = set(data) - {"name", "description", "phenotype"}
    if unknown:
        raise BodyError(f"{name}: unknown shape keys {sorted(unknown)} (use description, phenotype)")
    pheno = data.get("phenotype") or {}
    if not isinstance(pheno, dict):
        raise BodyError(f"{name}: phenotype must be a mapping of {', '.join(PHENOTYPES)}")
    out = {}
    for key, value in pheno.items():
        if key not in PHENOTYPES:
            raise BodyError(f"{name}: unknown phenotype {key!r} (use {', '.join(PHENOTYPES)})")
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise BodyError(f"{name}: phenotype {key} must be a number in [0, 1]") from None
        if not 0.0 <= value <= 1.0:
            raise BodyError(f"{name}: phenotype {key} = {value} is outside [0, 1]")
        out[key] = value
    return {"name": name, "description": str(data.get("description", "")), "phenotype": out}


# ----------------------------------------------------------------------------- anny

_MODELS: dict = {}


def _import_anny():
    """Import torch and anny, or raise `BodyError` saying how to install them."""
    try:
        import torch  # noqa: F401
        import anny  # noqa: F401
    except ImportError as exc:
        raise BodyError(
            f"generating bodies needs the anny body model ({exc}); install the 'bodies' extra: "
            "pip install torch==2.13.0 && pip install -e '.[bodies]'") from None
    return torch, anny


def _model(params: GenerateParams):
    key = (params.rig, params.topology)
    if key not in _MODELS:
        torch, anny = _import_anny()
        print("building the anny model (the first build takes a few minutes and fills the anny cache)...",
              file=sys.stderr, flush=True)
        model = anny.Anny(rig=params.rig, topology=params.topology, skinning_method="lbs")
        _MODELS[key] = model.to(torch.float64)
    return _MODELS[key]


def _anny_version() -> str:
    import importlib.metadata
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _bone_sections(bone_labels) -> np.ndarray:
    """(B,) section index of each anny bone (-1: none)."""
    from fnmatch import fnmatchcase
    out = np.full(len(bone_labels), -1, dtype=int)
    for b, bone in enumerate(bone_labels):
        for s, section in enumerate(SECTIONS):
            # a pattern with * is a glob; one without is a prefix (``neck`` for neck01..03)
            if any(fnmatchcase(bone, pat) if "*" in pat else bone.startswith(pat)
                   for pat in SECTION_BONES[section]):
                out[b] = s
                break
    return out


def section_weights(bone_weights: np.ndarray, bone_labels) -> np.ndarray:
    """Sum skinning weights per section.

    Parameters
    ----------
    bone_weights : (V, B) float
        Dense skinning weights.
    bone_labels : sequence of B str
        anny bone names.

    Returns
    -------
    weights : (V, 11) float
        Weight of each section (`SECTIONS` order) at each vertex.
    """
    sec = _bone_sections(bone_labels)
    missing = [b for b, s in zip(bone_labels, sec) if s < 0 and bone_weights[:, list(bone_labels).index(b)].any()]
    if missing:
        raise BodyError(f"anny bones without a section: {missing}")
    onehot = np.zeros((len(bone_labels), len(SECTIONS)))
    onehot[sec >= 0, sec[sec >= 0]] = 1.0
    return bone_weights @ onehot


def _rotation(angles_deg) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("xyz", angles_deg, degrees=True).as_matrix()


def pose_anny(posture: dict, shape: dict, params: GenerateParams = GenerateParams()):
    """Run anny: posed vertices, faces, joints and section weights (before refinement).

    Returns
    -------
    vertices : (13348, 3) float, metres (anny's frame: origin at the pelvis)
    faces : (F, 3) int
    joints : (16, 3) float, metres, in `REQUIRED_JOINTS` order
    weights : (V, 11) float, section weights
    """
    torch, _ = _import_anny()
    model = _model(params)
    labels = list(model.bone_labels)
    unknown = [b for b in posture["bones"] if b not in labels]
    if unknown:
        raise BodyError(f"{posture['name']}: unknown anny bones {unknown} (anny bones: {', '.join(labels)})")
    deltas = {}
    for bone, angles in posture["bones"].items():
        d = torch.eye(4, dtype=torch.float64)[None].clone()
        d[0, :3, :3] = torch.as_tensor(_rotation(angles))
        deltas[bone] = d
    with torch.no_grad():
        out = model(pose_parameters=deltas or None,
                    phenotype_kwargs={k: float(v) for k, v in shape["phenotype"].items()},
                    pose_parameterization="local-ref")
    vertices = out["vertices"][0].numpy().astype(np.float64)
    heads = out["bone_poses"][0, :, :3, 3].numpy().astype(np.float64)
    joints = np.array([heads[labels.index(JOINT_BONES[n])] for n in REQUIRED_JOINTS])
    faces = model.get_triangular_faces().numpy().astype(np.int64)
    weights = section_weights(model.dense_vertex_bone_weights.numpy().astype(np.float64), labels)
    return vertices, faces, joints, weights


# ----------------------------------------------------------------------------- refinement

def split_long_edges(vertices, faces, attributes, max_edge, max_sag=np.inf):
    """Split every edge longer than ``max_edge`` once, at a curved midpoint, keeping the mesh closed.

    The new vertex of edge (a, b) is the midpoint of the PN-triangle cubic through a and b with
    the vertex normals there: ``(a + b) / 2 - ((b - a).n_a n_a + (a - b).n_b n_b) / 8``. Edges
    whose curved midpoint is farther than ``max_sag`` from the straight one are split too. Faces
    with 1, 2 or 3 split edges become 2, 3 or 4 faces (the quad of a 2-split face is cut along
    its shorter diagonal), so no T-junction appears.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int, outward winding
    attributes : (V, k) float
        Per-vertex values; new vertices get the mean of the edge's ends.
    max_edge : float, metres
    max_sag : float, metres

    Returns
    -------
    vertices : (V', 3) float
    faces : (F', 3) int
    attributes : (V', k) float
    """
    V = len(vertices)
    e = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2): v_i -> v_{i+1}
    key = np.sort(e, axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n = vertex_normals(vertices, faces)
    a, b = uniq[:, 0], uniq[:, 1]
    pa, pb, na, nb = vertices[a], vertices[b], n[a], n[b]
    d = pb - pa
    sag = ((d * na).sum(1)[:, None] * na - (d * nb).sum(1)[:, None] * nb) / 8.0
    split = (np.linalg.norm(d, axis=1) > max_edge) | (np.linalg.norm(sag, axis=1) > max_sag)
    if not split.any():
        return vertices, faces, attributes
    a, b = a[split], b[split]
    mid = 0.5 * (pa[split] + pb[split]) - sag[split]
    new_index = np.full(len(uniq), -1)
    new_index[split] = V + np.arange(split.sum())
    m = new_index[inv].reshape(-1, 3)  # (F, 3) midpoint of edge i (v_i, v_{i+1}) or -1
    verts = np.vstack([vertices, mid])
    attrs = np.vstack([attributes, 0.5 * (attributes[a] + attributes[b])])

    k = (m >= 0).sum(1)
    out = [faces[k == 0]]
    # one split edge: rotate so that it is edge 0 (v0, v1)
    sel = np.flatnonzero(k == 1)
    if len(sel):
        r = np.argmax(m[sel] >= 0, axis=1)
        idx = (r[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(faces[sel], idx, 1)
        mm = np.take_along_axis(m[sel], idx, 1)[:, 0]
        out += [np.c_[v[:, 0], mm, v[:, 2]], np.c_[mm, v[:, 1], v[:, 2]]]
    # two split edges: rotate so that the unsplit one is edge 2 (v2, v0)
    sel = np.flatnonzero(k == 2)
    if len(sel):
        u = np.argmin(m[sel] >= 0, axis=1)
        r = (u + 1) % 3
        idx = (r[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(faces[sel], idx, 1)
        mm = np.take_along_axis(m[sel], idx, 1)
        m0, m1 = mm[:, 0], mm[:, 1]
        out.append(np.c_[m0, v[:, 1], m1])
        # quad v0, m0, m1, v2: cut along the shorter diagonal
        diag_a = np.linalg.norm(verts[v[:, 0]] - verts[m1], axis=1)
        diag_b = np.linalg.norm(verts[m0] - verts[v[:, 2]], axis=1)
        use_a = diag_a <= diag_b
        out += [np.where(use_a[:, None], np.c_[v[:, 0], m0, m1], np.c_[v[:, 0], m0, v[:, 2]]),
                np.where(use_a[:, None], np.c_[v[:, 0], m1, v[:, 2]], np.c_[m0, m1, v[:, 2]])]
    sel = np.flatnonzero(k == 3)
    if len(sel):
        v, mm = faces[sel], m[sel]
        out += [np.c_[v[:, 0], mm[:, 0], mm[:, 2]], np.c_[mm[:, 0], v[:, 1], mm[:, 1]],
                np.c_[mm[:, 2], mm[:, 1], v[:, 2]], mm]
    return verts, np.vstack(out).astype(np.int64), attrs


def canonical_faces(faces):
    """Faces rotated to start at their smallest index (winding kept) and sorted: compresses better.

    Parameters
    ----------
    faces : (F, 3) int

    Returns
    -------
    faces : (F, 3) int
    """
    r = np.argmin(faces, axis=1)
    f = np.take_along_axis(faces, (r[:, None] + np.arange(3)) % 3, axis=1)
    return f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]


def refine(vertices, faces, attributes, max_edge, max_sag=np.inf):
    """Apply `split_long_edges` until no edge is longer than ``max_edge`` (at most 4 passes)."""
    for _ in range(4):
        nv = len(vertices)
        vertices, faces, attributes = split_long_edges(vertices, faces, attributes, max_edge, max_sag)
        if len(vertices) == nv:
            break
    return vertices, faces, attributes


# ----------------------------------------------------------------------------- the body

def generate(posture, shape, params: GenerateParams = GenerateParams(), name: str | None = None) -> Body:
    """Make a posed body with ground truth.

    Parameters
    ----------
    posture : str, path or dict
        Library posture name, posture YAML path, or the dict of `load_posture`.
    shape : str, path or dict
        Library shape name, shape YAML path, or the dict of `load_shape`.
    params : GenerateParams
    name : str, optional
        Body name (default: ``<shape>_<posture>``).

    Returns
    -------
    body : Body
        Vertices in metres, floor at z = 0, centred on the pelvis in x and y; extras hold what
        reproduces it (``posture``, ``shape``, ``generator_params`` as JSON strings,
        ``anny_version``, ``generator_version``).
    """
    posture = load_posture(posture)
    shape = load_shape(shape)
    vertices, faces, joints, weights = pose_anny(posture, shape, params)
    vertices, faces, weights = refine(vertices, faces, weights, params.max_edge_m, params.max_sag_m)
    labels = np.argmax(weights, axis=1).astype(np.int8)
    offset = np.array([joints[0, 0], joints[0, 1], vertices[:, 2].min()])
    vertices = vertices - offset
    joints = joints - offset
    if params.quantum_m > 0:
        vertices = np.round(vertices / params.quantum_m) * params.quantum_m
    faces = canonical_faces(faces)
    extras = {
        "posture": np.array(json.dumps(posture, sort_keys=True)),
        "shape": np.array(json.dumps(shape, sort_keys=True)),
        "generator_params": np.array(json.dumps(asdict(params), sort_keys=True)),
        "anny_version": np.array(_anny_version()),
        "generator_version": np.array(GENERATOR_VERSION),
    }
    return Body(name=name or f"{shape['name']}_{posture['name']}", vertices=vertices, faces=faces,
                vertex_section=labels, joint_names=tuple(REQUIRED_JOINTS), joints=joints,
                extras=extras, source="generated")


def regenerate(body: Body) -> Body:
    """Generate again the body from the parameters stored in its extras (see `generate`)."""
    try:
        posture = json.loads(str(body.extras["posture"]))
        shape = json.loads(str(body.extras["shape"]))
        params = GenerateParams(**json.loads(str(body.extras["generator_params"])))
    except KeyError as exc:
        raise BodyError(f"{body.source or body.name}: no stored generator parameter {exc}") from None
    return generate(posture, shape, params, name=body.name)


#: The manifest of the shipped library: body name -> posture and shape names.
SHIPPED = Path(__file__).resolve().parent / "shipped.yaml"


def shipped() -> dict[str, dict]:
    """The shipped library's manifest, ``{body name: {"posture": name, "shape": name}}``."""
    return _read_yaml(SHIPPED, "library manifest")


def build_library(out_dir=None, names=None, params: GenerateParams = GenerateParams()) -> list[Path]:
    """Generate the shipped bodies (`shipped`) into ``out_dir`` (default: the library folder).

    Parameters
    ----------
    out_dir : path, optional
    names : list of str, optional
        Only these bodies of the manifest.
    params : GenerateParams

    Returns
    -------
    paths : list of Path
    """
    from .body import save_body
    from .library import DATA_DIR

    out_dir = Path(out_dir) if out_dir is not None else DATA_DIR
    manifest = shipped()
    unknown = sorted(set(names or ()) - set(manifest))
    if unknown:
        raise BodyError(f"{SHIPPED}: no bodies named {', '.join(unknown)} (known: {', '.join(manifest)})")
    paths = []
    for i, (name, entry) in enumerate(manifest.items()):
        if names and name not in names:
            continue
        print(f"[{i + 1}/{len(manifest)}] {name}", file=sys.stderr, flush=True)
        body = generate(entry["posture"], entry["shape"], params, name=name)
        paths.append(save_body(body, out_dir / f"{name}.npz"))
    return paths
