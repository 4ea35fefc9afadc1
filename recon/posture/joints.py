"""Front and back, joint placement, and the reported sections' boundaries (steps 5, 6 and 8 of
`recon.posture`).

`front_sign` and `swap_sides` read front and back from the body's shape (feet, knees, hips);
`place_joints` puts the rig's joints on the fitted sections (off their ends and axes,
`offset_joints`) and `place_seams` the points where the sections meet, where the clustering cuts;
`split_torso`, `split_hips`, `split_knees` and `joint_caps` make the reported sections meet where
the body file's section labels change, and `joint_caps` (with `shape_limbs`) gives the upper arms
and lower legs the labels' cross-sections, deeper front to back than the fit's round columns, and
the upper arms a start cap over the shoulder; `centre_neck` (before the joints are placed) puts the
chest's top between the sides of the neck seen in the points, the head and the shoulders following.
The measurements behind the chosen values and placements are in docs/tuning.md.
"""

from __future__ import annotations

import numpy as np

from .bodymodel import (ABOVE_SEAT, CROTCH_SPLIT, CROTCH_STRIP, HIP_OFFSET, JOINT_CAP, JOINT_OFFSET, KNEE_SPLIT,
                        LIMBS, LOWER_LEG_SHAPE, PELVIS_ABOVE_CROTCH, SEAT_STRIP, SEAT_WINDOW, SHOULDER_CAP,
                        SPINE_BACK, STATURE, TORSO_SPLIT, TORSO_SPLIT_CROTCH, TORSO_SPLIT_RANGE, UPPER_ARM_SHAPE,
                        StandardBody, kind_of)
from ..geometry import cross, turn_between, unit
from ..model import SectionShape

#: Skewness giving a front/back vote of tanh(1) = 0.76 per section (`_trunk_vote`): about the
#: head's on the library's bodies (-0.11 to -0.20). Chosen.
TRUNK_SKEW = 0.1


def front_sign(points, secs: dict, R: np.ndarray) -> float:
    """+1 if the subject faces -R[:, 1] (the provisional front), -1 if it faces +R[:, 1].

    The legs vote (`_foot_vote`: feet point forward; knees bend backwards; hips flex forwards),
    from the leg sections in ``secs`` (the caller leaves out those the scan does not show: a lower
    leg cut from the scan, placed in empty voxels, pointed anywhere and its knee "bend" voted the
    body round). When they give no vote (straight legs without feet), or a leg section is missing
    (legs cut short: the feet, the strongest cue, are gone), the head and the chest vote too
    (`_trunk_vote`: the face and the chest stick out in front of their sections' axes, the back of
    the head and the shoulder blades less behind them; on the 42 library runs at k = 1 and 3 it
    agreed with the legs' vote every time, 0.7 to 2.0 of 2)."""
    back = R[:, 1]
    up = R[:, 2]
    scale = float(np.clip(np.linalg.norm(secs["waist"].end - secs["waist"].start) / 0.364, 0.5, 1.5)) \
        if "waist" in secs else 1.0
    votes = 0.0
    for side in ("l", "r"):
        th, sh = secs.get(f"thigh_{side}"), secs.get(f"lower_leg_{side}")
        if sh is not None:
            # the floor is level in the scanner's frame (+z up): measure the foot against +z
            # unless the body lies down (a torso leaning forward would tilt the foot's "lowest part")
            vertical = np.array([0.0, 0.0, 1.0]) if abs(up[2]) > 0.5 else up
            votes += _foot_vote(points, sh, back, vertical, scale)
        if th is not None and sh is not None:
            bend = sh.axis - th.axis * (sh.axis @ th.axis)   # knees bend backwards
            b = bend @ back
            if abs(b) > 0.25:
                votes += 1.5 * np.sign(b)
        if th is not None:
            flex = th.axis - (-up) * (th.axis @ -up)           # hips flex forwards
            f = flex @ back
            if abs(f) > 0.4:
                votes -= 1.0 * np.sign(f)
    legs = {f"{k}_{x}" for k in ("thigh", "lower_leg") for x in "lr"}
    if votes == 0.0 or not legs <= set(secs):
        # no leg evidence, or a leg section missing from the scan: the head and chest vote too
        votes += _trunk_vote(points, secs, back)
    return 1.0 if votes >= 0 else -1.0


def _skew(v: np.ndarray) -> float:
    """Sample skewness of ``v`` (n,): > 0 when its long tail lies towards +."""
    v = v - v.mean()
    return float(np.mean(v ** 3) / max(float(np.mean(v ** 2)), 1e-12) ** 1.5)


def _trunk_vote(points, secs: dict, back: np.ndarray, scale: float = TRUNK_SKEW) -> float:
    """Front/back vote of the head and the chest: in [-2, 2], > 0 when their shapes say the body
    faces ``-back``.

    Across a section's axis, the points of the head (within 1.5 of its radii of the axis, along its
    length) and of the chest have a long tail in front (the face and nose; the chest and the
    arms held before it) and a shorter one behind (the back of the head, the shoulder blades):
    their skewness along ``back`` is negative when the body faces ``-back`` (on the 21 library
    bodies from their labelled points: head -0.11 to -0.20, chest -0.16 to -0.58). Each section
    votes ``-tanh(skew / scale)``; one with fewer than 30 points there votes 0."""
    points = np.asarray(points, dtype=float)
    votes = 0.0
    for name in ("head", "chest"):
        s = secs.get(name)
        if s is None:
            continue
        q = s.local(points)
        rho = np.hypot(q[:, 0], q[:, 1])
        sel = (q[:, 2] >= 0) & (q[:, 2] <= s.length) & (rho < 1.5 * float(s.radii.max()))
        if sel.sum() < 30:
            continue
        b = back - s.axis * (back @ s.axis)
        nb = float(np.linalg.norm(b))
        if nb < 0.3:
            continue
        votes -= float(np.tanh(_skew(points[sel] @ (b / nb)) / scale))
    return votes


def _foot_vote(points, shin: SectionShape, back: np.ndarray, up: np.ndarray, scale: float = 1.0) -> float:
    """Front/back vote of one foot: in [-2, 2], > 0 when the foot sticks out towards ``-back``.

    The foot is the last ``0.06 * scale`` m of the leg chain, found from the farthest points of the
    chain, not from the shin's fitted end (in a sparse scan the sole is not detected and the end
    falls short of the foot, where the calf, which bulges backwards, would vote instead). When the
    shin points mostly down (or up), "farthest" is along the vertical ``up`` (the foot rests flat on
    the floor even when the shin leans, as in a squat) and the foot's offsets front and back are
    measured horizontally from the ankle, on the shin's axis a foot height above the lowest point;
    otherwise along the shin's axis, from the axis. The toes reach about 0.15 m forward, the heel
    about 0.05 m back.
    """
    rel = points - shin.start
    h = rel @ shin.axis
    lat = rel - np.outer(h, shin.axis)
    near = (np.linalg.norm(lat, axis=1) < 0.22 * scale) & (h > 0.5 * shin.length) & \
        (h < shin.length + 0.35 * scale)
    if near.sum() < 10:
        return 0.0
    c = float(shin.axis @ up)
    if abs(c) > 0.5:
        g = up * np.sign(c)                       # the direction the shin points, vertically
        depth = points @ g
        tip = float(np.quantile(depth[near], 0.995))
        sel = near & (depth > tip - 0.06 * scale)
        ankle = shin.start + shin.axis * ((tip - 0.075 * scale - shin.start @ g) / (shin.axis @ g))
        b = back - g * (back @ g)
        off = (points[sel] - ankle) @ (b / max(np.linalg.norm(b), 1e-9))
    else:
        tip = float(np.quantile(h[near], 0.995))
        sel = near & (h > tip - 0.06 * scale)
        b = back - shin.axis * (back @ shin.axis)
        nb = float(np.linalg.norm(b))
        if nb < 0.3:   # the shin points front-back: the foot says nothing here
            return 0.0
        off = lat[sel] @ (b / nb)
    if sel.sum() < 6:
        return 0.0
    fwd, bwd = -np.quantile(off, 0.02), np.quantile(off, 0.98)
    return float(2.0 * np.tanh((fwd - bwd) / 0.03))


def swap_sides(name: str) -> str:
    if name.endswith("_l"):
        return name[:-2] + "_r"
    if name.endswith("_r"):
        return name[:-2] + "_l"
    return name


def shank_ratio(points, shin: SectionShape, body: StandardBody) -> float | None:
    """The shank the sole shows (knee to a foot height above the sole) over the model's shank, or
    None when fewer than 6 points show the sole.

    The sole lies at the 99.5th percentile, along the shin's axis from the knee, of the points within
    0.1 m (scaled) of the axis beyond its middle: the heel and the sole below the ankle are the leg's
    farthest points along the shin, whichever way the foot points (a raised heel too); toes reach
    forward, not down the shin.
    """
    rel = points - shin.start
    h = rel @ shin.axis
    rho2 = np.einsum("ij,ij->i", rel, rel) - h * h
    near = (rho2 < (0.10 * body.scale) ** 2) & (h > 0.5 * shin.length) & (h < shin.length + 0.35 * body.scale)
    if near.sum() < 6:
        return None
    return (float(np.quantile(h[near], 0.995)) - body.length("foot_height")) / body.length("lower_leg")


def _fingertip(points, q: SectionShape, body: StandardBody, step: float = 0.03) -> float:
    """How far along the forearm's axis the fingertips lie from the elbow, metres: the forearm's own
    detected end, carried on along the run of points of any section within the forearm's radius of
    its axis that continues it without a gap of ``step``, when that end falls short of the model's
    forearm and hand (at most a hand length further, and 1.1 times the model's length: beyond the
    fingertips the axis may run on along the thigh the hand rests on).

    A hand resting against the thigh or on the hip has its points given to the thigh or the waist
    (their surfaces are nearer), so the forearm's own points end at the wrist and "tip minus a hand
    length" put the wrist 7-11 cm short (arms_close, hands_on_hips); the hand is still there, along
    the forearm's axis. A free hand's run ends at its fingertips.
    """
    full = q.length + q.caps[1]
    model = body.length("forearm") + body.length("hand")
    if full >= model:
        return full
    rel = points - q.start
    h = rel @ q.axis
    rho2 = np.einsum("ij,ij->i", rel, rel) - h * h
    near = (rho2 < q.radii.min() ** 2) & (h > full) & (h < min(full + body.length("hand"), 1.1 * model))
    if not near.any():
        return full
    k = np.floor((h[near] - full) / step).astype(int)
    gap = np.flatnonzero(np.bincount(k, minlength=k.max() + 2) == 0)[0]   # first empty step
    run = k < gap
    return float(max(full, h[near][run].max())) if run.any() else full


def place_seams(secs: dict, body: StandardBody, back: np.ndarray, points=None, arm_tolerance: float = 0.1) -> dict:
    """Where the sections meet, by joint name (`recon.model.BodyFit.seams`): the points the
    clustering's joint planes, bone directions and the extremities' cuts are taken from.

    They are the joints placed on the sections' ends and axes, the spine's moved behind the torso's
    axis (`recon.posture.bodymodel.SPINE_BACK`) and the hips behind and outside the thighs' tops
    (`recon.posture.bodymodel.HIP_OFFSET`) before a straight leg's knee is closed between hip and
    ankle (`knee_between`).

    Parameters
    ----------
    secs : dict of SectionShape
        The fitted sections.
    body : StandardBody
    back : (3,) float
        The subject's backward direction.
    points : (n, 3) float, optional
        When given, the ankles are placed a foot height above the soles, and the fingertips seen
        are followed along a hand resting on the body (`_fingertip`).
    arm_tolerance : float
        A nearly straight arm measured (shoulder to wrist) more than this fraction off the model's
        arm has its elbow placed by `elbow_between` (`FitParams.fit_arm_size_tolerance`).

    Returns
    -------
    dict of str to (3,) float
    """
    return _on_sections(secs, body, back, points, arm_tolerance, seam=True)


def place_joints(secs: dict, body: StandardBody, back: np.ndarray, points=None, arm_tolerance: float = 0.1,
                 offsets: dict = JOINT_OFFSET) -> dict:
    """The joints, by name (`recon.model.BodyFit.joints`): found on the sections' ends and axes as
    for `place_seams` (without its spine and hip offsets: a straight leg's knee is closed from the
    thigh's top), then moved to where the rig's joints lie relative to their sections
    (``offsets``, `offset_joints`); with ``points``, the pelvis and hips toward the height the
    crotch or the seat seen gives them (`pelvis_from_below`).

    Parameters
    ----------
    secs, body, back, points, arm_tolerance
        As for `place_seams`.
    offsets : dict
        Joint kind -> ((out, back, along), (out, back, along)) (`recon.posture.bodymodel.JOINT_OFFSET`,
        `offset_joints`); ``{}`` leaves the joints on the sections.

    Returns
    -------
    dict of str to (3,) float
    """
    joints = offset_joints(_on_sections(secs, body, back, points, arm_tolerance, seam=False), secs, back,
                           body.stature, offsets)
    return joints if points is None else pelvis_from_below(joints, secs, points, body, back)


def pelvis_from_below(joints: dict, secs: dict, points, body: StandardBody, back: np.ndarray) -> dict:
    """The pelvis and hip joints moved along the waist's axis by the body's lowest trunk point seen:
    halfway to `recon.posture.bodymodel.PELVIS_ABOVE_CROTCH` statures above the crotch
    (`find_crotch`) between legs held down, or to their own heights above the seat (`find_seat`,
    `recon.posture.bodymodel.ABOVE_SEAT`) behind flexed hips.

    The pelvis and the hips ride with the waist column's lower end and the thighs' tops, which the
    volume and the points pin poorly along the torso's axis. Standing, the crotch is a second
    estimate about as good, so the two are averaged (the pelvis and the hips move as one bone);
    seated or squatting, where the column runs on into the buttocks, the seat is several times
    better (on the tune corpus) and replaces them. The seams (the clustering's planes) are not
    moved. Unchanged when neither is found.

    Parameters
    ----------
    joints : dict of (3,) float
        The reported joints (`place_joints`).
    secs : dict of SectionShape
        The fitted sections: the waist, and the legs for either landmark to be sought.
    points : (n, 3) float
    body : StandardBody
    back : (3,) float
        The subject's backward direction.

    Returns
    -------
    dict of (3,) float
    """
    if "pelvis" not in joints or "waist" not in secs:
        return joints
    up = secs["waist"].axis
    moved = ("pelvis", "hip_l", "hip_r")
    crotch = find_crotch(points, secs)
    if crotch is not None:
        shift = 0.5 * float((crotch + PELVIS_ABOVE_CROTCH * body.stature * up - joints["pelvis"]) @ up)
        return {k: v + shift * up if k in moved else v for k, v in joints.items()}
    seat = find_seat(points, secs, back, body.stature)
    if seat is None:
        return joints
    return {k: v + (float((seat - v) @ up) + ABOVE_SEAT[k.split("_")[0]] * body.stature) * up if k in moved else v
            for k, v in joints.items()}


def _on_sections(secs: dict, body: StandardBody, back: np.ndarray, points, arm_tolerance: float,
                 seam: bool) -> dict:
    """The joints on the sections' ends and axes (`place_joints`); with ``seam``, the spine's moved
    behind the torso's axis and the hips behind and outside the thighs' tops before the knees are
    closed (`place_seams`)."""
    j = {}
    soled = set()   # lower legs whose ankle was placed from the detected sole
    tipped = set()  # forearms of nearly straight arms whose wrist was placed from the fingertips
    if "waist" in secs:
        j["pelvis"] = secs["waist"].start
        j["chest"] = secs["waist"].end
    if "chest" in secs:
        j.setdefault("chest", secs["chest"].start)
        j["neck"] = secs["chest"].end
    if "head" in secs:
        h = secs["head"]
        j["neck"] = h.start
        j["head"] = h.start + body.length("head_joint") * h.axis
    if seam:   # the spine's seams lie behind the torso's axis
        for name, frac in SPINE_BACK.items():
            if name in j:
                j[name] = j[name] + frac * body.stature * back
    for prox, dist, a, b, c in LIMBS:
        if prox in secs:
            j[a] = secs[prox].start
            j[b] = secs[prox].end
        if dist in secs:
            q = secs[dist]
            j[b] = q.start
            if q.closed[1] and dist.startswith("forearm"):
                # the fingertips are seen: the wrist lies a hand length before them, or a model
                # forearm past the elbow; it is put at their mean. The first errs where the
                # forearm's section runs on over the body the hand rests on, the second with the
                # person's proportions; a body's size misjudged moves the two in opposite ways
                full = q.length + q.caps[1]
                if points is not None:
                    full = _fingertip(points, q, body)
                tip = max(full - body.length("hand"), 0.5 * full)
                j[c] = q.start + 0.5 * (tip + body.length("forearm")) * q.axis
                if prox in secs and float(secs[prox].axis @ q.axis) > np.cos(np.radians(ELBOW_STRAIGHT_DEG)):
                    tipped.add(dist)
            else:  # otherwise the wrist or ankle lies a standard segment length beyond the joint
                seg = body.length("forearm" if dist.startswith("forearm") else "lower_leg")
                r = shank_ratio(points, q, body) if points is not None and dist.startswith("lower_leg") else None
                if r is not None and SHANK_RANGE[0] < r < SHANK_RANGE[1]:
                    # the ankle lies a foot height above the sole (Winter 0.039 H; the rig's 0.043 H):
                    # shank lengths vary between people more than foot heights do
                    seg *= r
                    soled.add(dist)
                j[c] = q.start + seg * q.axis
    left = unit(cross(back, secs["waist"].axis)) if "waist" in secs else None
    if seam and left is not None:   # the hips' seams lie behind and outside the thighs' tops
        for side, sign in (("l", 1.0), ("r", -1.0)):
            if f"hip_{side}" in j:
                j[f"hip_{side}"] = j[f"hip_{side}"] + body.stature * (
                    HIP_OFFSET["back"] * back + sign * HIP_OFFSET["out"] * left)
    for prox, dist, a, b, c in LIMBS:
        if dist in tipped and prox in secs and a in j:
            e = elbow_between(j[a], j[c], secs[prox].axis, secs[dist].axis,
                              body.length("upper_arm") / (body.length("upper_arm") + body.length("forearm")))
            model = body.length("upper_arm") + body.length("forearm")
            if e is not None and abs(np.linalg.norm(e - j[a]) + np.linalg.norm(j[c] - e) - model) > arm_tolerance * model:
                j[b] = e
        bent = prox in secs and dist in secs and kind_of(dist) == "lower_leg" and \
            float(secs[prox].axis @ secs[dist].axis) < np.cos(np.radians(KNEE_MEET_DEG))
        if bent:
            k = bent_knee(secs[prox], secs[dist], j[c] if dist in soled else None, body.length("lower_leg"))
            if k is not None:
                j[b] = k
        elif dist in soled and prox in secs and a in j and "waist" in secs:
            k = knee_between(j[a], j[c], secs[prox].axis, secs[dist].axis, back, left,
                              body.length("thigh") / (body.length("thigh") + body.length("lower_leg")))
            if k is not None:
                j[b] = k
    return {k: np.asarray(v, dtype=float) for k, v in j.items()}


#: The section whose frame carries each joint's offset (`offset_joints`): the torso's joints the
#: column they end, the shoulders and hips the trunk's, a limb's middle and end joints the section
#: they end (elbow: upper arm, wrist: forearm, knee: thigh, ankle: lower leg).
JOINT_FRAME = dict(pelvis="waist", chest="waist", neck="chest", head="head", shoulder="chest", hip="waist",
                   elbow="upper_arm", wrist="forearm", knee="thigh", ankle="lower_leg")


def joint_frame(secs: dict, joint: str, back: np.ndarray) -> np.ndarray | None:
    """(3, 3) columns: out, back, along, of ``joint``'s section (`JOINT_FRAME`); None without that
    section or the waist.

    ``along`` is the section's axis; ``back`` the subject's backward direction (3,) with its part
    along the axis taken out; ``out`` the body's left (right for a joint of the right side; zero
    for the spine's joints, which lie on the mid-plane) with its parts along the axis and along
    ``back`` taken out. ``back`` and ``out`` are not normalised: an offset across a limb that
    points backwards, or sideways, fades with the direction it can no longer be measured in.
    """
    sided = joint.endswith(("_l", "_r"))
    kind = joint[:-2] if sided else joint
    sec = JOINT_FRAME.get(kind)
    if sec is None or "waist" not in secs:
        return None
    if sided and sec not in ("waist", "chest"):
        sec += joint[-2:]
    if sec not in secs:
        return None
    ax = secs[sec].axis
    b = back - ax * float(back @ ax)
    o = np.zeros(3)
    if sided:
        left = unit(cross(back, secs["waist"].axis)) * (1.0 if joint.endswith("_l") else -1.0)
        o = left - ax * float(left @ ax)
        nb = float(b @ b)
        if nb > 1e-12:
            o = o - b * float(o @ b) / nb
    return np.column_stack([o, b, ax])


def offset_joints(joints: dict, secs: dict, back: np.ndarray, stature: float,
                  offsets: dict = JOINT_OFFSET) -> dict:
    """The joints moved from where the sections put them to where the rig's joints lie relative
    to them: each by ``stature * (a + b * (stature / STATURE - 1))`` along (out, back, along) of
    its `joint_frame`, ``(a, b)`` = ``offsets[kind]`` (`recon.posture.bodymodel.JOINT_OFFSET`).

    Parameters
    ----------
    joints : dict of (3,) float
        Joint positions, metres.
    secs : dict of SectionShape
    back : (3,) float
        The subject's backward direction.
    stature : float
        The fitted body's stature, metres.
    offsets : dict
        Joint kind -> ((out, back, along), (out, back, along)): fractions of stature, and their
        change per unit of ``stature / STATURE - 1``.

    Returns
    -------
    dict of (3,) float
    """
    out = dict(joints)
    grow = stature / STATURE - 1.0
    for name, p in joints.items():
        kind = name[:-2] if name.endswith(("_l", "_r")) else name
        if kind not in offsets:
            continue
        F = joint_frame(secs, name, back)
        if F is None:
            continue
        a, b = (np.asarray(v, dtype=float) for v in offsets[kind])
        out[name] = p + stature * (F @ (a + b * grow))
    return out


#: An elbow bent less than this (degrees) is placed the model's upper-arm length from the shoulder
#: (or by `elbow_between`), not where the axes meet: two axes this close to parallel meet poorly
#: (1 cm across them moves the meeting point 1 / tan(35 deg) = 1.4 cm along them; fitted straight
#: arms of the library, bent 11 degrees, came out bent up to 28 degrees; the bent arms are 45 degrees
#: or more; chosen).
ELBOW_STRAIGHT_DEG = 35.0


#: A knee bent more than this (degrees, between the fitted thigh and lower-leg axes) is placed by
#: `bent_knee`, not closed by `knee_between`: the triangle hip-knee-ankle grows ill-conditioned as the
#: knee bends (with hip to ankle fixed, the bones' scale goes as 1 / sqrt(F^2 + (1-F)^2 + 2 F (1-F)
#: cos bend), F the thigh's share: an error in the fitted bend moves the knee 0.7 mm per degree on a
#: straight leg, 2.2 at 60 degrees, 4.5 at 100 and 6.3 at 118, for 0.9 m of leg), while two axes
#: crossing at a large angle meet well (an axis off by x across moves the meeting point x / sin bend).
#: The crossover, for the fits' bend errors (2-11 degrees on the library's bent knees) and axis offsets
#: (1-3 cm), lies at 75-80 degrees; a right angle (chosen). The library's fitted knees are bent
#: either below 30 or above 95 degrees.
KNEE_MEET_DEG = 90.0


def bent_knee(thigh: SectionShape, shin: SectionShape, ankle: np.ndarray | None,
              shank: float) -> np.ndarray | None:
    """The knee (3,) of a deeply bent leg (`KNEE_MEET_DEG`), on the lower leg's axis; None when the
    axes are parallel.

    The lower leg is seen well in any posture (a squat's or a seated body's from the front, 600+
    points; its axis 4-7 degrees off the bone on the library), the thigh of a deeply bent leg from
    above only: its column, fitted on its top surface, lies above the femur and droops towards the
    knee (the thigh narrows there). Along the lower leg's axis two estimates of the knee, with
    errors from different sources: where the thigh's axis comes nearest (the thigh's column lies
    high: 2-3 cm above the knee on the seated bodies), and, when the ``ankle`` (3,) was placed from
    the detected sole, the model's ``shank`` (metres, knee to ankle) above it (people's shanks differ
    from the model's); their midpoint (equal weights: their errors are alike, 2-4 cm; chosen). Without
    a measured ankle, where the thigh's axis comes nearest.

    The thigh's axis is taken as placed last, not the lower leg's start: sliding the body along the
    torso's axis to hang from the crown (`recon.posture.adjust.anchor_on_head_top`) moves a level thigh
    along itself only and the lower leg with the torso, so the lower leg's start leaves the thigh's
    axis (seated: 3-6 cm off the knee).
    """
    d1, d2 = thigh.axis, shin.axis
    w = thigh.start - shin.start
    b, d, e = float(d1 @ d2), float(d1 @ w), float(d2 @ w)
    den = 1.0 - b * b
    if den < 1e-9:
        return None
    u = (e - b * d) / den                      # along the lower leg, nearest the thigh's axis
    if ankle is not None:
        u = 0.5 * (u + float((ankle - shank * d2 - shin.start) @ d2))
    return shin.start + u * d2


def elbow_between(shoulder: np.ndarray, wrist: np.ndarray, d_upper: np.ndarray, d_fore: np.ndarray,
                  frac: float) -> np.ndarray | None:
    """The elbow (3,) of a nearly straight arm from the shoulder and the wrist joints (3,), the bend
    between the fitted upper-arm and forearm axes (unit (3,)) and the upper arm's share ``frac`` of
    upper arm + forearm (the model's 0.517; the rig's bodies 0.50-0.53); None when shoulder and wrist
    coincide.

    As `knee_between` does for a leg: on a straight arm the elbow is not seen, and placing it the
    model's upper-arm length from the shoulder puts it wherever the model's size puts it (a child
    matched at 1.20 m for 1.42 m had its raised elbows 6-7 cm short); the wrist, a hand length
    before the seen fingertips, and the shoulder are measured, and the proportion of the two bones
    varies little between people. The triangle shoulder-elbow-wrist is closed with the bend of the
    fitted axes, its apex on the side to which the upper arm's axis leaves the shoulder-wrist line.
    """
    v = wrist - shoulder
    D = float(np.linalg.norm(v))
    if D < 1e-3:
        return None
    e = v / D
    side = d_upper - e * (d_upper @ e)
    ns = float(np.linalg.norm(side))
    side = side / ns if ns > 1e-6 else np.zeros(3)
    return _apex(shoulder, e, D, frac, float(d_upper @ d_fore), side)


def knee_between(hip: np.ndarray, ankle: np.ndarray, d_thigh: np.ndarray, d_shin: np.ndarray,
                  back: np.ndarray, left: np.ndarray, frac: float) -> np.ndarray | None:
    """The knee (3,) from the hip and ankle joints (3,), the bend between the fitted thigh and shin
    axes (unit (3,)) and the thigh's share ``frac`` of thigh + shank; None when the hip and ankle
    coincide.

    Thigh and shank (lengths t and s, t / (t + s) = ``frac``, the model's 0.235 / 0.485; the rig's
    bodies 0.47-0.51) with the bend angle of the axes close the triangle hip-knee-ankle. The knee
    bends about a hinge: the axes' own (their cross product, long when the bend is large: a seated
    person's knees spread apart) plus the body's left-right axis ``left`` (unit (3,)) weighted
    sin 20 degrees (it decides for a nearly straight leg, whose axes' bend is noise), and a knee
    bends backwards only, so it lies in front (``-back``) of the hip-ankle line. The hip and the
    ankle (a foot height above the detected sole) are the leg's best-placed joints; the knee is not
    seen on a straight leg, and on a slightly bent one the meeting point of the two axes moves far
    along them for a small error in either direction (a walker's rear leg, bent 25 degrees: 10 cm),
    while the bend angle alone moves the knee little.
    """
    v = ankle - hip
    D = float(np.linalg.norm(v))
    if D < 1e-3:
        return None
    e = v / D
    hinge = cross(d_thigh, d_shin)
    if hinge @ left < 0:
        hinge = -hinge
    hinge = hinge + np.sin(np.radians(20.0)) * left
    hinge = hinge - e * (hinge @ e)
    nh = float(np.linalg.norm(hinge))
    if nh < 1e-6:
        return None
    fwd = cross(e, hinge / nh)
    if fwd @ back > 0:
        fwd = -fwd
    return _apex(hip, e, D, frac, float(d_thigh @ d_shin), fwd)


def _apex(root: np.ndarray, e: np.ndarray, D: float, frac: float, cos_bend: float,
          side: np.ndarray) -> np.ndarray:
    """The middle joint (3,) of a two-bone chain from ``root`` (3,) whose far joint lies ``D`` metres
    along the unit ``e`` (3,): the bones (lengths t, s with t / (t + s) = ``frac``) meet at an angle
    whose cosine between their directions is ``cos_bend``, and the apex lies towards the unit
    ``side`` (3,), perpendicular to ``e``."""
    F = frac
    cb = float(np.clip(cos_bend, -1.0, 1.0))
    L = D / np.sqrt(F ** 2 + (1 - F) ** 2 + 2 * F * (1 - F) * cb)
    t, s = F * L, (1 - F) * L
    ca = float(np.clip((t * t + D * D - s * s) / (2 * t * D), -1.0, 1.0))
    return root + t * (ca * e + np.sqrt(1.0 - ca * ca) * side)


def split_torso(points, secs: dict, split: float = TORSO_SPLIT, from_crotch: float = TORSO_SPLIT_CROTCH,
                limits: tuple = TORSO_SPLIT_RANGE) -> dict:
    """The reported waist and chest sections: split where the body's labels change, not at the
    chest joint where the fit joins the two columns.

    The waist column (pelvis joint to chest joint) is cut across its axis ``from_crotch`` of the way
    from the crotch seen in the points (`find_crotch`) to the chest joint, along the axis
    (`recon.posture.bodymodel.TORSO_SPLIT_CROTCH`), or, when no crotch is found (hips flexed, legs
    together), at ``split`` of its length from the pelvis (`recon.posture.bodymodel.TORSO_SPLIT`); the cut
    stays within ``limits`` of the column (`recon.posture.bodymodel.TORSO_SPLIT_RANGE`). The chest column
    runs from the cut to its top; the joints are not moved. Both sections then meet at the section
    boundary of the body file format, which is what the clustering separates: split at the chest
    joint, 5-17 % of a body's points (the lower ribs) were labelled waist. The crotch, seen on the
    points, replaces the fitted pelvis, which rides with the waist column and is the torso's
    worst-placed landmark along the axis (3-4 cm off on a_pose, child_arms_raised, heavy_standing,
    tall_walking). The chest's radii become the length-weighted mean of the two columns' radii over
    its new extent (the model's radii are means along a section; the lower ribs, fitted by the waist
    column, are narrower than the shoulders).
    """
    if "waist" not in secs or "chest" not in secs:
        return secs
    w, c = secs["waist"], secs["chest"]
    crotch = find_crotch(points, secs) if points is not None else None
    if crotch is not None:
        below = float((crotch - w.start) @ w.axis)      # along the column, from the pelvis end
        split = (below + from_crotch * (w.length - below)) / w.length
    split = float(np.clip(split, *limits))
    cut = w.start + split * w.length * w.axis
    low = (1.0 - split) * w.length     # the part of the waist column that becomes chest
    radii = (low * w.radii + c.length * c.radii) / (low + c.length)
    chest = c.replace(start=cut, radii=radii, caps=np.array([min(c.caps[0], radii.min()), c.caps[1]]))
    out = {**secs, "waist": w.replace(end=cut), "chest": chest}
    return out


#: `centre_neck`: the neck's sides are sought in a slab from ``NECK_SLAB[0]`` to ``NECK_SLAB[1]``
#: head lengths above the chest's top end, along the head's axis (above the trapezius, below the
#: jaw), within ``NECK_REACH`` head lengths of the chest's top (clear of arms raised beside the
#: head); their midpoint is taken between the ``NECK_QUANTILE`` and ``1 - NECK_QUANTILE`` quantiles
#: across the body. (chosen) like `recon.posture.adjust._neck_shift`'s slab (0.02-0.06 statures, within
#: 0.08), in head lengths, which the reported sections carry.
NECK_SLAB = (0.1, 0.3)
NECK_REACH = 0.6
NECK_QUANTILE = 0.1


def neck_sides(points, top: np.ndarray, up: np.ndarray, lat: np.ndarray, heights: tuple, reach: float,
               q: float = 0.1) -> tuple[float, float] | None:
    """The sides of the neck across the body: the ``q`` and ``1 - q`` quantiles of the points'
    offsets along ``lat`` (unit (3,), across the body) from ``top`` (3,, the chest's top end), over
    the points between ``heights`` (metres, low and high) above it along ``up`` (unit (3,)) and within
    ``reach`` metres of it across and front to back; None with fewer than 10 points there."""
    rel = np.asarray(points, dtype=float) - top
    h, x, y = rel @ up, rel @ lat, rel @ cross(up, lat)
    sel = (h > heights[0]) & (h < heights[1]) & (np.abs(x) < reach) & (np.abs(y) < reach)
    if sel.sum() < 10:
        return None
    lo, hi = np.quantile(x[sel], [q, 1.0 - q])
    return float(lo), float(hi)


def centre_neck(points, secs: dict, slab: tuple = NECK_SLAB, reach: float = NECK_REACH,
                q: float = NECK_QUANTILE) -> dict:
    """The reported chest's top end (the neck) midway between the sides of the neck seen in the
    points, the head hanging from it and the shoulders turned with the chest.

    The neck is left-right symmetric in any posture: its sides, in a slab just above the chest's
    top end (`NECK_SLAB`, `NECK_REACH`, `NECK_QUANTILE`), lie at the same distance either side of
    it (they are silhouettes, seen by front and back sensors alike). The chest's sideways tilt is
    poorly fixed by its own points (the arms hang beside it, and a torso bent sideways is fitted
    as one straight column): the top of a leaning chest came out 6.6 cm to the side of the neck.
    The chest turns about its lower end (the cut of `split_torso`) so that its top lies midway;
    the head keeps its top (the crown is measured) and hangs from the moved neck. The shoulders
    ride with the chest: each turned shoulder is taken onto its upper arm's axis (the axis is
    fitted on the arm's own points), the upper arm slides along it and its elbow with it, and the
    forearm keeps its end (the fingertips are measured). Across is the chest's wide axis, taken
    across the head's axis; the head's axis leans with a misplaced top, so the slab's midpoint
    falls a little short of the neck (extending the line from the crown through it instead
    overshot: leaning's neck, 6.2 cm to the side, ended 1.1 cm to the other side, against 0.2 cm).
    Without a head, with fewer than 10 points in the slab, or with the slab wider than the head
    (not the neck alone: arms raised beside it, shoulders), ``secs`` is returned unchanged.

    Made before the joints are placed (`recon.posture`), so that the neck, shoulder and elbow
    joints follow. `recon.posture.adjust._neck_shift` does the same during the fine adjustment, within 25 degrees of the
    waist's axis; this one follows the head's axis and carries the shoulders.

    Parameters
    ----------
    points : (n, 3) float, metres
    secs : dict of SectionShape
        With ``chest`` and ``head``.

    Returns
    -------
    dict of SectionShape
    """
    if "chest" not in secs or "head" not in secs:
        return secs
    c, hd = secs["chest"], secs["head"]
    up = hd.axis
    fx, fy, _ = c.frame
    wide = fx if c.radii[0] >= c.radii[1] else fy
    lat = wide - up * float(wide @ up)
    if np.linalg.norm(lat) < 1e-6:
        return secs
    lat = unit(lat)
    L = hd.length
    sides = neck_sides(points, c.end, up, lat, (slab[0] * L, slab[1] * L), reach * L, q)
    if sides is None:
        return secs
    lo, hi = sides
    if 0.5 * (hi - lo) >= float(hd.radii.max()):
        return secs    # wider than the head: not the neck alone (arms or shoulders in the slab)
    move = 0.5 * float(lo + hi) * lat
    top = c.end + move
    d_old, d_new = c.axis, unit(top - c.start)
    turn = turn_between(d_old, d_new)
    out = {**secs, "chest": c.replace(end=top), "head": hd.replace(start=hd.start + move)}
    for prox, dist, *_ in LIMBS:
        if kind_of(prox) != "upper_arm" or prox not in secs:
            continue
        u = secs[prox]
        root = c.start + turn @ (u.start - c.start)
        t = float((root - u.start) @ u.axis) * u.axis
        out[prox] = u.replace(start=u.start + t, end=u.end + t)
        if dist in secs:
            out[dist] = secs[dist].replace(start=secs[dist].start + t)
    return out


#: The crotch is sought along the thighs only while both thighs point within this angle of the
#: waist's downward axis, degrees: with the hips flexed (seated, squatting) the gap between the
#: thighs opens forward, and the crotch lies behind them, not along them.
CROTCH_MAX_FLEX_DEG = 45.0


def find_crotch(points, secs: dict, strip: float = CROTCH_STRIP,
                max_flex_deg: float = CROTCH_MAX_FLEX_DEG) -> np.ndarray | None:
    """The crotch seen in the points: the lowest point, along the thighs, of the strip about the
    mid-plane between the two thighs (half-width ``strip`` radii of the thinner thigh, within the
    waist's larger radius front to back, down to half a thigh's length below the thigh starts).
    Between legs held apart the mid-plane crosses the body only above the crotch.

    Parameters
    ----------
    points : (n, 3) float, metres
    secs : dict of SectionShape
        With ``thigh_l``, ``thigh_r`` and ``waist``.

    Returns
    -------
    crotch : (3,) float or None
        None without both thighs and the waist, with the hips flexed beyond ``max_flex_deg`` or
        fewer than 5 points in the strip.
    """
    if not {"thigh_l", "thigh_r", "waist"} <= set(secs):
        return None
    tl, tr, w = secs["thigh_l"], secs["thigh_r"], secs["waist"]
    mid = 0.5 * (tl.start + tr.start)
    down = -w.axis if np.linalg.norm(w.start - mid) < np.linalg.norm(w.end - mid) else w.axis
    cos_max = np.cos(np.radians(max_flex_deg))
    if tl.axis @ down < cos_max or tr.axis @ down < cos_max:
        return None
    along = unit(tl.axis + tr.axis)
    lat = tl.start - tr.start
    lat = unit(lat - (lat @ along) * along)
    fwd = cross(along, lat)
    q = np.asarray(points, dtype=float) - mid
    t = q @ along
    sel = ((np.abs(q @ lat) < strip * min(float(tl.radii.min()), float(tr.radii.min())))
           & (np.abs(q @ fwd) < float(w.radii.max())) & (t > -0.5 * float(w.radii.min()))
           & (t < 0.5 * min(tl.length, tr.length)))
    if sel.sum() < 5:
        return None
    return np.asarray(points, dtype=float)[np.flatnonzero(sel)[np.argmax(t[sel])]]


def find_seat(points, secs: dict, back: np.ndarray, stature: float, window: tuple = SEAT_WINDOW,
              strip: float = SEAT_STRIP, step: float = 0.03,
              max_flex_deg: float = CROTCH_MAX_FLEX_DEG) -> np.ndarray | None:
    """The seat seen in the points with the hips flexed: the lowest point of the buttocks, where
    the trunk's back ends with nothing below it.

    It is sought in the column behind the waist's axis, within ``strip`` times the waist's larger
    radius of its mid-plane, over ``window`` statures along the axis from the waist's lower end:
    the lowest of the points seen there from the top down to the first empty ``step`` (metres),
    with none below that step.
    Seated or squatting, the thighs leave forward and nothing of the body lies under the buttocks;
    standing, the backs of the thighs continue the column and no seat is found.

    Parameters
    ----------
    points : (n, 3) float, metres
    secs : dict of SectionShape
        With the waist and at least one leg: a thigh, or without it the lower leg, whose start
        (the knee) shows the hip's flexion from the waist's lower end.
    back : (3,) float
        The subject's backward direction.
    stature : float
        The fitted body's stature, metres.

    Returns
    -------
    seat : (3,) float or None
        None without the waist or a leg, with a leg (its thigh) within ``max_flex_deg`` of the
        waist's downward axis (legs held down: `find_crotch`), or with no end to the column.
    """
    if "waist" not in secs:
        return None
    w = secs["waist"]
    up = w.axis
    legs = [secs[f"thigh_{s}"].axis if f"thigh_{s}" in secs else unit(secs[f"lower_leg_{s}"].start - w.start)
            for s in "lr" if f"thigh_{s}" in secs or f"lower_leg_{s}" in secs]
    if not legs or any(float(d @ -up) > np.cos(np.radians(max_flex_deg)) for d in legs):
        return None
    b = unit(back - up * float(back @ up))
    points = np.asarray(points, dtype=float)
    q = points - w.start
    h = q @ up
    lo, hi = window[0] * stature, window[1] * stature
    reach = float(w.radii.max())
    sel = np.flatnonzero((np.abs(q @ cross(up, b)) < strip * reach) & (q @ b > 0) & (q @ b < 1.5 * reach)
                        & (h > lo) & (h < hi))
    if len(sel) < 5:
        return None
    k = np.floor((hi - h[sel]) / step).astype(int)        # steps down from the window's top
    empty = np.flatnonzero(np.bincount(k, minlength=k.max() + 2) == 0)[0]
    if empty == 0 or (empty + 1) * step > hi - lo or (k > empty).any():
        return None                                         # no top, no end, or more body below
    return points[sel[np.argmin(h[sel])]]


def split_hips(points, secs: dict, above: float = CROTCH_SPLIT) -> dict:
    """The reported thighs start no higher than ``above`` thigh lengths above the crotch seen in
    the points (`find_crotch`), along each thigh (`recon.posture.bodymodel.CROTCH_SPLIT`): the body file
    labels the buttocks and the groin waist down to about there. The fit's thigh columns start
    at its hip joints, which ride with the waist: a waist fitted 3-4 cm high (a_pose,
    child_arms_raised) started the thighs as much above the labels' boundary, and the thighs took
    the lower waist. The joints are not moved; a thigh that already starts lower is left alone, and
    so are both with the hips flexed (no crotch sought: `find_crotch`).
    """
    crotch = find_crotch(points, secs)
    if crotch is None:
        return secs
    out = dict(secs)
    for name in ("thigh_l", "thigh_r"):
        s = secs[name]
        t = (crotch - s.start) @ s.axis - above * s.length
        if 0.0 < t < 0.5 * s.length:
            out[name] = s.replace(start=s.start + t * s.axis)
    return out


def split_knees(secs: dict, seams: dict, body: StandardBody, drop: float = KNEE_SPLIT) -> dict:
    """The reported thigh ends at the knee's seam (``seams``: `place_seams`; placed by `knee_between`
    when the ankle was found from the sole, not where the fitted axes meet), and the lower leg starts ``drop`` statures below
    it along the shank, where the body file's labels change (`recon.posture.bodymodel.KNEE_SPLIT`).
    """
    out = dict(secs)
    for thigh, shin, _, knee, _ in LIMBS:
        if kind_of(shin) != "lower_leg" or shin not in secs:
            continue
        s = secs[shin]
        meet = thigh in secs and knee in seams
        top = seams[knee] if meet else s.start
        if meet:
            out[thigh] = secs[thigh].replace(end=top)
        axis = unit(s.end - top)
        out[shin] = s.replace(start=top + drop * body.stature * axis)
    return out


#: Section ends that are free (not a joint): (section, 0 for the start or 1 for the end).
_FREE_ENDS = {("waist", 0), ("head", 1)} | {(dist, 1) for _, dist, *_ in LIMBS}


def joint_caps(secs: dict, height: float = JOINT_CAP, shoulder: tuple = SHOULDER_CAP,
               limb_shapes: dict | None = None) -> dict:
    """The reported sections with flat caps where they meet at a joint (``height`` minor radii,
    `recon.posture.bodymodel.JOINT_CAP`), as the ground truth's sections have: the fit's hemispheres there
    reach into the neighbour (a thigh's, 9 cm into the waist, took its points). Free ends keep
    their caps.

    The upper arms and lower legs first get their cross-sections (`shape_limbs`, ``limb_shapes``);
    the upper arms' start cap at the shoulder is ``shoulder[0] + shoulder[1] * cos`` minor radii
    high (flatter than ``height`` on an arm raised overhead), ``cos`` the cosine between the arm's
    axis and the chest's downward axis (`recon.posture.bodymodel.SHOULDER_CAP`): the body file labels the
    deltoid, which covers the shoulder joint from above, upper arm, so the labels reach past the
    joint along a hanging arm's axis (0.04 statures on the oracle's sections, which span their
    labels) more than along a raised one's (0.016-0.026).
    """
    secs = shape_limbs(secs, limb_shapes)
    down = -secs["chest"].axis if "chest" in secs else None
    out = {}
    for name, s in secs.items():
        caps = s.caps.copy()
        for end in (0, 1):
            if (name, end) not in _FREE_ENDS:
                caps[end] = min(caps[end], height * float(s.radii.min()))
        if kind_of(name) == "upper_arm" and down is not None:
            deltoid = max(shoulder[0] + shoulder[1] * float(s.axis @ down), 0.0)
            caps[0] = deltoid * float(s.radii.min())
        out[name] = s.replace(caps=caps)
    return out


def shape_limbs(secs: dict, shapes: dict | None = None, min_sin: float = 0.5) -> dict:
    """The reported upper arms and lower legs with an elliptic cross-section: front to back
    ``shapes[kind][0]``, across ``shapes[kind][1]`` times the fitted (round) radius
    (`recon.posture.bodymodel.UPPER_ARM_SHAPE`, `recon.posture.bodymodel.LOWER_LEG_SHAPE`).

    Both are deeper front to back than across: the upper arm (biceps in front, triceps behind, the
    deltoid over the joint), the lower leg (the calf behind the shin bone): the oracle's sections
    (the principal radii of the labels' cross-sections) measure 1.16-1.25 (upper arm) and 1.08-1.23
    (lower leg) times deeper than wide on the 21 shipped bodies, the larger radius front to back
    for arms hanging, held sideways and raised overhead, and for legs standing, walking and seated.
    The fit's limb columns are round: the shoulder's points in front of a round upper arm lay
    beyond its reach and went to the chest alone, the calf's to the thigh. Front to back is the
    body's: across the chest's axis and its larger radius (the chest is wider than deep), taken
    across the limb's axis. A limb within ``asin(min_sin)`` of pointing front or back (arms held
    forward) keeps its round section (front to back is then along it), and so does a section
    already elliptic (applied once).

    Parameters
    ----------
    secs : dict of SectionShape
    shapes : dict, optional
        Section kind -> (2,) front-back and across radii over the fitted radius (product 1: the
        fitted area is kept). Default: upper arms `UPPER_ARM_SHAPE`, lower legs `LOWER_LEG_SHAPE`.
    min_sin : float

    Returns
    -------
    dict of SectionShape
        ``secs`` with those limbs replaced.
    """
    if shapes is None:
        shapes = {"upper_arm": UPPER_ARM_SHAPE, "lower_leg": LOWER_LEG_SHAPE}
    if "chest" not in secs:
        return secs
    c = secs["chest"]
    fx, fy, _ = c.frame
    back = fy if c.radii[0] >= c.radii[1] else fx
    out = dict(secs)
    for name, s in secs.items():
        shape = shapes.get(kind_of(name))
        if shape is None or not s.is_cylinder:
            continue
        fb = back - s.axis * float(back @ s.axis)
        if np.linalg.norm(fb) < min_sin:
            continue
        r = float(s.radii.mean())
        out[name] = s.replace(radii=np.array([shape[0] * r, shape[1] * r]), frame_x=unit(fb))
    return out


#: A shank (knee to a foot height above the detected sole) outside these multiples of the model's
#: shank for the estimated stature: the body's size or posture was misjudged (the library's fits:
#: all within; a walker whose torso came out 15 cm high, sized 1.59 m for 1.97 m: 1.8).
SHANK_RANGE = (0.6, 1.6)
