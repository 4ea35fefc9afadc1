"""A random body corpus: bodies nobody tuned for, each reproducible from ``(seed, index)``.

A body is drawn in three independent streams of ``numpy.random.SeedSequence([seed, index])``
(so one body never depends on another, nor on how many postures were rejected before it):

- **shape**: every anny phenotype uniform over its whole range (gender 0 male .. 1 female,
  age 1/3 child .. 1 old, muscle, weight, height, proportions 0 .. 1);
- **posture**: a family (`FAMILIES`: the poses people take in scanners and the hard ones) is
  chosen, its template ranges drawn per joint, then every angle jittered by up to `JITTER_DEG`
  and clipped to the per-bone box `DOF_BOX`; the posed joints must lie within the human range of
  motion (`ROM_LIMITS`, measured on the joints by `rom_angles`) and the body must not
  interpenetrate (`bodyscan.poses.checks.interpenetration`, the library's own check); a posture
  failing either is drawn again from the same stream (in the same family `FAMILY_ATTEMPTS`
  times, then in a newly drawn family), at most `MAX_ATTEMPTS` times;
- **scan**: scanner conditions (`draw_conditions`: k 1..3, a turn about the vertical,
  resolution 5-20 mm, noise 0-1 mm), stored with the body for whoever wants them.

Two disjoint seed ranges split the corpus: parameters may be chosen on `TUNE_SEEDS` only, numbers
are reported on `VALIDATE_SEEDS`.

Angles follow the posture YAML convention of `bodyscan.poses.generate` (degrees, rotation of the
bone about the world x, y, z axes relative to anny's rest A-pose, left side as written, right
mirrored by negating y and z).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from .body import REQUIRED_JOINTS, Body, BodyError

#: Seeds of the tune corpus (choose parameters here only).
TUNE_SEEDS = range(0, 1000)
#: Seeds of the validate corpus (report numbers here); disjoint from `TUNE_SEEDS`.
VALIDATE_SEEDS = range(1000, 2000)

#: Drawn postures failing the range of motion or the interpenetration check are drawn again
#: up to this many times; then the body is an error (never seen with the shipped families).
MAX_ATTEMPTS = 40
#: Draws within one family before another family is drawn (keeps the hard families frequent).
FAMILY_ATTEMPTS = 6
#: Per-angle jitter (degrees, uniform +-) added to every template angle.
JITTER_DEG = 6.0

SPINE = ("spine04", "spine03", "spine02", "spine01")

#: Per-bone box of drawn angles [x, y, z] (degrees, ``(lo, hi)`` each, left side convention).
#: Generous boxes around the anatomical ranges below (a box is a world-axis Euler range, not an
#: anatomical angle; the range of motion is enforced on the posed joints by `ROM_LIMITS`).
DOF_BOX = {
    "clavicle": ((-10, 10), (-25, 5), (-10, 10)),
    "upperarm01": ((-175, 60), (-135, 45), (-70, 45)),
    "lowerarm01": ((-100, 55), (-70, 75), (-120, 30)),
    "wrist": ((-30, 30), (-70, 60), (-30, 30)),
    "upperleg01": ((-120, 30), (-45, 25), (-30, 30)),
    "lowerleg01": ((0, 130), (-5, 5), (-10, 10)),
    "foot": ((-40, 25), (-10, 10), (-15, 15)),
    "spine": ((-8, 20), (-10, 10), (-12, 12)),  # each of the four spine bones
    "neck01": ((-20, 25), (-20, 20), (-30, 30)),
}

#: Human range of motion (degrees, ``(lo, hi)``) of the angles `rom_angles` measures on the
#: posed joints. Sources: American Academy of Orthopaedic Surgeons, "Joint Motion: Method of
#: Measuring and Recording" (AAOS 1965; Greene & Heckman, "The Clinical Measurement of Joint
#: Motion", AAOS 1994) and Soucie et al. 2011, "Range of motion measurements: reference values
#: and a database for comparison studies", Haemophilia 17(3):500-507 (normal males and females
#: aged 2-69). Where the two differ the wider value is kept: AAOS elbow flexion 150, knee flexion
#: 135 (Soucie ~140-150), hip flexion 120, hip extension 30, hip abduction 45, hip adduction 30,
#: shoulder flexion 180, extension 60, thoracolumbar flexion 80, extension 25, lateral flexion 35,
#: rotation 45. Angles measured on joint centres, not goniometer arms: a few degrees are added for
#: the carrying angle and the joint centres (noted per entry).
ROM_LIMITS = {
    "elbow_flexion": (0.0, 150.0),       # AAOS 0-150; 180 - angle(shoulder, elbow, wrist)
    "knee_flexion": (0.0, 140.0),        # AAOS 0-135, Soucie up to ~143
    "hip_flexion": (-30.0, 125.0),       # AAOS flexion 120 (+5 joint centres), extension 30
    "hip_abduction": (-30.0, 45.0),      # AAOS abduction 45, adduction 30
    "shoulder_elevation": (0.0, 180.0),  # AAOS flexion / abduction 180 (angle from hanging down)
    "shoulder_extension": (-90.0, 60.0),  # upper arm behind the frontal plane: AAOS extension 60
    "shoulder_across": (-50.0, 180.0),   # upper arm across the midline: horizontal adduction ~45
    "trunk_flexion": (-25.0, 80.0),      # AAOS thoracolumbar flexion 80, extension 25
    "trunk_lateral": (-35.0, 35.0),      # AAOS lateral flexion 35
    "trunk_rotation": (-45.0, 45.0),     # AAOS rotation 45
}

# Template ranges of the families (left side; ``(lo, hi)`` uniform per angle, a number is fixed).
_ARMS_HANGING = {"upperarm01": ((-10, 10), (12, 32), (-8, 8)), "lowerarm01": ((30, 50), (-5, 5), (-5, 5))}
_LEGS_STANDING = {"upperleg01": ((-5, 5), (-7, 1), (-8, 8)), "lowerleg01": ((0, 6), 0, 0)}

#: Posture families: name -> (weight, template, asymmetric). ``template`` maps a bone (``.L``
#: for one side of an asymmetric family, no suffix for both sides drawn independently,
#: ``spine`` for each spine bone) to its three angle ranges. Asymmetric families are mirrored
#: to the other side half of the time.
FAMILIES = {
    "arms_at_sides": (2, {**_ARMS_HANGING, **_LEGS_STANDING}, False),
    "arms_touching": (1, {"upperarm01": ((-5, 5), (24, 38), (-5, 5)),
                          "lowerarm01": ((35, 50), (-5, 5), (-5, 5)), **_LEGS_STANDING}, False),
    "a_pose": (1, {"upperarm01": ((-10, 10), (-15, 8), (-10, 10)),
                   "lowerarm01": ((35, 50), (-5, 5), (-5, 5)),
                   "upperleg01": ((-5, 5), (-10, 0), (-8, 8)), "lowerleg01": ((0, 6), 0, 0)}, False),
    "t_pose": (1, {"upperarm01": ((-15, 10), (-58, -38), (-15, 10)),
                   "lowerarm01": ((25, 50), (-5, 5), (-5, 5)), **_LEGS_STANDING}, False),
    "arms_raised": (1, {"clavicle": (0, (-20, -5), 0), "upperarm01": ((-25, 10), (-120, -85), (-10, 10)),
                        "lowerarm01": ((20, 50), (-5, 5), (-5, 5)), **_LEGS_STANDING}, False),
    "arms_forward": (1, {"upperarm01": ((-115, -60), (-10, 10), (-40, -12)),
                         "lowerarm01": ((0, 50), (-5, 5), (-5, 5)), **_LEGS_STANDING}, False),
    "hands_on_hips": (1, {"upperarm01": ((0, 20), (-22, 0), (-5, 5)),
                          "lowerarm01": ((35, 50), (50, 72), (-5, 5)),
                          "wrist": (0, (-60, -40), 0), **_LEGS_STANDING}, False),
    "hand_on_chest": (1, {**_ARMS_HANGING, "upperarm01.L": ((-60, -42), (12, 24), (-8, 8)),
                          "lowerarm01.L": ((-58, -40), (50, 66), (-120, -105)), **_LEGS_STANDING}, True),
    "crossed_arms": (1, {"upperarm01.L": ((-56, -46), (14, 22), (-5, 5)),
                         "lowerarm01.L": ((-56, -44), (52, 64), (-118, -108)),
                         "upperarm01.R": ((-36, -26), (-22, -14), (-5, 5)),
                         "lowerarm01.R": ((-56, -44), (-64, -52), (108, 118)), **_LEGS_STANDING}, True),
    "stride": (2, {**_ARMS_HANGING, "upperarm01.L": ((10, 30), (12, 28), 0),
                   "upperarm01.R": ((-30, -10), (-28, -12), 0),
                   "upperleg01.L": ((-35, -12), (-5, 2), (-5, 5)), "lowerleg01.L": ((5, 25), 0, 0),
                   "foot.L": ((0, 15), 0, 0), "upperleg01.R": ((8, 22), (-2, 5), (-5, 5)),
                   "lowerleg01.R": ((10, 35), 0, 0), "foot.R": ((-20, -5), 0, 0)}, True),
    "squat": (1, {"upperleg01": ((-95, -65), (-15, -3), (-8, 8)), "lowerleg01": ((85, 120), 0, 0),
                  "foot": ((-35, -15), 0, 0), "upperarm01": ((-90, -50), (-10, 10), (-35, -15)),
                  "lowerarm01": ((20, 50), (-5, 5), (-5, 5)), "spine04": ((8, 20), 0, 0),
                  "spine02": ((5, 15), 0, 0)}, False),
    "seated": (1, {"upperleg01": ((-100, -80), (-10, 0), (-5, 5)), "lowerleg01": ((75, 105), 0, 0),
                   "upperarm01": ((-35, -10), (12, 28), (-5, 5)),
                   "lowerarm01": ((-25, 15), (-5, 5), (-5, 5))}, False),
    "leaning": (1, {**_ARMS_HANGING, "upperarm01.R": ((-10, 10), (-40, -20), (-8, 8)),
                    "spine": ((-3, 8), (3, 9), (-3, 3)), **_LEGS_STANDING}, True),
    "bending": (1, {**_ARMS_HANGING, "spine": ((6, 16), (-3, 3), (-3, 3)), **_LEGS_STANDING}, False),
    "twisted": (1, {**_ARMS_HANGING, "spine": ((-3, 5), (-3, 3), (5, 11)), **_LEGS_STANDING}, True),
    "knee_raised": (1, {"upperarm01": ((-10, 10), (0, 25), (-8, 8)), "lowerarm01": ((30, 50), (-5, 5), (-5, 5)),
                        "upperleg01.L": ((-100, -55), (-8, 2), (-8, 8)), "lowerleg01.L": ((55, 110), 0, 0),
                        "upperleg01.R": ((-5, 5), (-5, 3), (-5, 5)), "lowerleg01.R": ((0, 6), 0, 0)}, True),
}


def _box(bone: str):
    base = bone.split(".")[0]
    return DOF_BOX["spine" if base in SPINE else base]


def _mirror(bones: dict) -> dict:
    """Swap left and right (``.L`` <-> ``.R``), negating y and z, and negate y, z of central bones."""
    out = {}
    for bone, (x, y, z) in bones.items():
        if bone.endswith(".L"):
            bone = bone[:-2] + ".R"
        elif bone.endswith(".R"):
            bone = bone[:-2] + ".L"
        out[bone] = [x, 0.0 - y, 0.0 - z]
    return out


def _draw_range(rng, r) -> float:
    return float(r) if np.isscalar(r) else float(rng.uniform(r[0], r[1]))


def draw_posture(rng: np.random.Generator, family: str | None = None) -> dict:
    """Draw one posture (before the range-of-motion and interpenetration checks).

    Parameters
    ----------
    rng : numpy.random.Generator
    family : str, optional
        One of `FAMILIES`; drawn by weight when None.

    Returns
    -------
    posture : dict
        ``{"name": family, "description": str, "bones": {anny bone: [x, y, z] degrees}}`` with
        every angle inside `DOF_BOX`.
    """
    names = list(FAMILIES)
    if family is None:
        w = np.array([FAMILIES[n][0] for n in names], dtype=float)
        family = names[int(rng.choice(len(names), p=w / w.sum()))]
    elif family not in FAMILIES:
        raise BodyError(f"unknown posture family {family!r} (known: {', '.join(names)})")
    _, template, asymmetric = FAMILIES[family]
    bones: dict[str, list[float]] = {}
    for key, ranges in template.items():
        targets = ([f"{b}" for b in SPINE] if key == "spine"
                   else [key] if "." in key or key in SPINE or key == "neck01" else [f"{key}.L", f"{key}.R"])
        for bone in targets:
            angles = [_draw_range(rng, r) for r in ranges]
            if bone.endswith(".R") and "." not in key:
                angles = [angles[0], -angles[1], -angles[2]]  # drawn as a left bone, mirrored
            bones[bone] = angles
    for bone in list(bones):  # per-joint jitter, then clipped to the bone's box
        jit = rng.uniform(-JITTER_DEG, JITTER_DEG, 3)
        lo_hi = np.array(_box(bone), dtype=float)
        if bone.endswith(".R"):
            lo_hi = np.array([lo_hi[0], -lo_hi[1][::-1], -lo_hi[2][::-1]])
        bones[bone] = [float(v) for v in np.clip(np.add(bones[bone], jit), lo_hi[:, 0], lo_hi[:, 1])]
    if asymmetric and rng.random() < 0.5:
        bones = _mirror(bones)
    return {"name": family, "description": f"random {family.replace('_', ' ')} posture", "bones": bones}


def in_box(posture: dict) -> bool:
    """Whether every angle of ``posture`` lies inside its bone's `DOF_BOX` (right side mirrored)."""
    for bone, angles in posture["bones"].items():
        lo_hi = np.array(_box(bone), dtype=float)
        if bone.endswith(".R"):
            lo_hi = np.array([lo_hi[0], -lo_hi[1][::-1], -lo_hi[2][::-1]])
        if not ((np.asarray(angles) >= lo_hi[:, 0] - 1e-9) & (np.asarray(angles) <= lo_hi[:, 1] + 1e-9)).all():
            return False
    return True


def draw_shape(rng: np.random.Generator) -> dict:
    """Draw an anny phenotype over its whole range (age from child, 1/3, to old, 1)."""
    pheno = {"gender": rng.uniform(0, 1), "age": rng.uniform(1 / 3, 1), "muscle": rng.uniform(0, 1),
             "weight": rng.uniform(0, 1), "height": rng.uniform(0, 1), "proportions": rng.uniform(0, 1)}
    return {"name": "random", "description": "random anny phenotype",
            "phenotype": {k: round(float(v), 4) for k, v in pheno.items()}}


def draw_conditions(rng: np.random.Generator) -> dict:
    """Draw scanner conditions: ``k`` 1..3, ``turn_deg`` 0..360, ``resolution`` 5-20 mm, ``noise`` 0-1 mm."""
    return {"k": int(rng.integers(1, 4)), "turn_deg": round(float(rng.uniform(0, 360)), 2),
            "resolution": round(float(rng.uniform(0.005, 0.02)), 5),
            "noise": round(float(rng.uniform(0.0, 0.001)), 6)}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rom_angles(joint_names, joints) -> dict[str, np.ndarray]:
    """Anatomical angles (degrees) of a posed body, measured on its joint centres.

    Frames: the pelvis frame has ``lat`` from right to left hip, ``up`` from pelvis to chest
    (made orthogonal), ``fwd = lat x up`` (the subject's front, -y at rest); the chest frame the same from
    the shoulders and chest to neck. Each two-sided angle is a (2,) array, left then right;
    abduction, "across" and lateral angles are positive outwards / to the left.

    Parameters
    ----------
    joint_names : sequence of str
        At least `REQUIRED_JOINTS`.
    joints : (J, 3) float

    Returns
    -------
    angles : dict of str to float or (2,) float
        The keys of `ROM_LIMITS`.
    """
    J = {n: np.asarray(p, dtype=float) for n, p in zip(joint_names, joints)}

    def frame(left, right, low, high):
        lat = _unit(J[left] - J[right])
        up = J[high] - J[low]
        up = _unit(up - (up @ lat) * lat)
        return lat, up, np.cross(lat, up)

    # anny's root is never rotated here: the pelvis is upright, its up is the world's +z
    p_lat = _unit(J["hip_l"] - J["hip_r"])
    p_up = _unit(np.array([0.0, 0.0, 1.0]) - p_lat[2] * p_lat)
    p_fwd = np.cross(p_lat, p_up)
    c_lat, c_up, c_fwd = frame("shoulder_l", "shoulder_r", "chest", "neck")
    out: dict = {}

    def hinge(a, b, c):
        u, v = _unit(J[a] - J[b]), _unit(J[c] - J[b])
        return 180.0 - np.degrees(np.arccos(np.clip(u @ v, -1, 1)))

    out["elbow_flexion"] = np.array([hinge(f"shoulder_{s}", f"elbow_{s}", f"wrist_{s}") for s in "lr"])
    out["knee_flexion"] = np.array([hinge(f"hip_{s}", f"knee_{s}", f"ankle_{s}") for s in "lr"])
    sign = {"l": 1.0, "r": -1.0}
    hf, ha, se, sx, sa = [], [], [], [], []
    for s in "lr":
        d = _unit(J[f"knee_{s}"] - J[f"hip_{s}"])
        hf.append(np.degrees(np.arctan2(d @ p_fwd, -(d @ p_up))))
        ha.append(np.degrees(np.arcsin(np.clip(sign[s] * (d @ p_lat), -1, 1))))
        u = _unit(J[f"elbow_{s}"] - J[f"shoulder_{s}"])
        se.append(np.degrees(np.arccos(np.clip(-(u @ c_up), -1, 1))))
        sx.append(np.degrees(np.arcsin(np.clip(-(u @ c_fwd), -1, 1))))  # > 0: arm behind the body
        sa.append(np.degrees(np.arcsin(np.clip(sign[s] * (u @ c_lat), -1, 1))))  # < 0: across
    out["hip_flexion"], out["hip_abduction"] = np.array(hf), np.array(ha)
    out["shoulder_elevation"], out["shoulder_extension"] = np.array(se), np.array(sx)
    out["shoulder_across"] = np.array(sa)
    t = _unit(J["neck"] - J["pelvis"])
    out["trunk_flexion"] = float(np.degrees(np.arctan2(t @ p_fwd, t @ p_up)))
    out["trunk_lateral"] = float(np.degrees(np.arctan2(t @ p_lat, t @ p_up)))
    # rotation of the shoulder line against the hip line, about the pelvis's up axis
    a = c_lat - (c_lat @ p_up) * p_up
    out["trunk_rotation"] = float(np.degrees(np.arctan2(np.cross(p_lat, a) @ p_up, a @ p_lat)))
    return out


def rom_violations(joint_names, joints) -> list[str]:
    """Names (with values) of the `rom_angles` outside `ROM_LIMITS`; empty when within range."""
    bad = []
    for name, value in rom_angles(joint_names, joints).items():
        lo, hi = ROM_LIMITS[name]
        for v in np.atleast_1d(value):
            if not lo <= v <= hi:
                bad.append(f"{name}={v:.0f}")
    return bad


def corpus_set(seed: int) -> str:
    """``"tune"``, ``"validate"`` or ``"other"``: the seed range ``seed`` belongs to."""
    return "tune" if seed in TUNE_SEEDS else "validate" if seed in VALIDATE_SEEDS else "other"


def _streams(seed: int, index: int):
    if seed < 0 or index < 0:
        raise BodyError(f"seed and index must be non-negative integers, got {seed}, {index}")
    shape, posture, scan = np.random.SeedSequence([int(seed), int(index)]).spawn(3)
    return np.random.default_rng(shape), np.random.default_rng(posture), np.random.default_rng(scan)


def body_name(seed: int, index: int, family: str) -> str:
    """File stem of body ``index`` of seed ``seed``: ``s<seed>_<index>_<family>``."""
    return f"s{seed}_{index:04d}_{family}"


def posture_draws(seed: int, index: int):
    """The `MAX_ATTEMPTS` postures body ``(seed, index)`` may take, in the order they are tried.

    A family is drawn, then `FAMILY_ATTEMPTS` postures of it, then another family... The draws
    do not depend on which were rejected: `sample_body` takes the first acceptable one.

    Yields
    ------
    posture : dict
        As `draw_posture`.
    """
    _, rng, _ = _streams(seed, index)
    family = None
    for attempt in range(MAX_ATTEMPTS):
        if attempt % FAMILY_ATTEMPTS == 0:
            family = draw_posture(rng)["name"]
        yield draw_posture(rng, family)


def sample_body(seed: int, index: int, params=None, log=None) -> Body:
    """Draw body ``index`` of the corpus of ``seed``: a function of ``(seed, index)`` only.

    Parameters
    ----------
    seed, index : int, >= 0
    params : bodyscan.poses.generate.GenerateParams, optional
    log : callable, optional
        Called with a line per rejected posture.

    Returns
    -------
    body : Body
        With ground truth; extras as `bodyscan.poses.generate.generate` plus ``sample`` (JSON:
        seed, index, set, family, attempts, rejections) and ``scan_conditions`` (JSON,
        `draw_conditions`).
    """
    from .checks import interpenetration
    from .generate import GenerateParams, generate, pose_anny

    params = params or GenerateParams()
    rng_shape, _, rng_scan = _streams(seed, index)
    shape = draw_shape(rng_shape)
    conditions = draw_conditions(rng_scan)
    rejections = []
    for attempt, posture in enumerate(posture_draws(seed, index), start=1):
        vertices, faces, joints, weights = pose_anny(posture, shape, params)
        why = rom_violations(REQUIRED_JOINTS, joints)
        if not why:  # the check on anny's own mesh first (fast), then on the refined body
            raw = Body(name="raw", vertices=vertices, faces=faces,
                       vertex_section=np.argmax(weights, axis=1).astype(np.int8),
                       joint_names=tuple(REQUIRED_JOINTS), joints=joints)
            bad = int(interpenetration(raw).sum())
            if not bad:
                body = generate(posture, shape, params, name=body_name(seed, index, posture["name"]))
                bad = int(interpenetration(body).sum())
                if not bad:
                    break
            why = [f"{bad} interpenetrating vertices"]
        rejections.append(f"{posture['name']}: {', '.join(why)}")
        if log:
            log(f"{body_name(seed, index, posture['name'])}: rejected ({rejections[-1]})")
    else:
        raise BodyError(f"seed {seed} index {index}: no acceptable posture in {MAX_ATTEMPTS} draws")
    extras = dict(body.extras)
    extras["sample"] = np.array(json.dumps({"seed": int(seed), "index": int(index), "set": corpus_set(seed),
                                            "family": posture["name"], "attempts": attempt,
                                            "rejections": rejections}))
    extras["scan_conditions"] = np.array(json.dumps(conditions, sort_keys=True))
    from dataclasses import replace
    return replace(body, extras=extras)


def sample(n: int, seed: int, out_dir, start: int = 0, params=None) -> list[Path]:
    """Write bodies ``start .. start + n - 1`` of seed ``seed`` into ``out_dir`` (existing ones kept).

    Returns
    -------
    paths : list of Path
    """
    from .body import save_body

    if n < 1:
        raise BodyError(f"--n must be at least 1, got {n}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for index in range(start, start + n):
        done = sorted(out.glob(f"s{seed}_{index:04d}_*.npz"))
        if done:
            paths.append(done[0])
            continue
        body = sample_body(seed, index, params, log=lambda m: print(m, file=sys.stderr, flush=True))
        paths.append(save_body(body, out / f"{body.name}.npz"))
        print(paths[-1], flush=True)
    return paths
