"""Oracle posture: the body model built from a body's ground truth, for ablations and tests.

`fit_from_body` places each section's axis between its ground-truth joints (the free ends, head
top, hands and soles, at the extreme of the section's own vertices), and sizes its elliptic
cross-section by PCA of the section's vertices around that axis. It is what a perfect posture
estimation would give, so the clustering and surface stages can be measured on their own.
"""

from __future__ import annotations

import numpy as np

from bodyscan.recon.posture.bodymodel import JOINT_CAP
from bodyscan.recon.model import SECTIONS, BodyFit, SectionShape

#: section: (start joint, direction joint, free end?). The axis runs along start -> direction joint,
#: through the centre of the section's vertices; a free end (head top, hand, sole) is closed by a
#: cap that reaches the section's extreme vertex. The cross-section is sized between the start and
#: the direction joint only (so hands and feet do not inflate forearms and lower legs).
_AXES = {
    "head": ("neck", "head", True),
    "chest": ("chest", "neck", False),
    "waist": ("chest", "pelvis", True),
    "upper_arm_l": ("shoulder_l", "elbow_l", False),
    "upper_arm_r": ("shoulder_r", "elbow_r", False),
    "forearm_l": ("elbow_l", "wrist_l", True),
    "forearm_r": ("elbow_r", "wrist_r", True),
    "thigh_l": ("hip_l", "knee_l", False),
    "thigh_r": ("hip_r", "knee_r", False),
    "lower_leg_l": ("knee_l", "ankle_l", True),
    "lower_leg_r": ("knee_r", "ankle_r", True),
}


#: Percentiles of the vertices' positions along the axis taken as the section's extent (robust to
#: a few stray labels).
_EXTENT = (0.5, 99.5)


def section_from_vertices(name: str, start: np.ndarray, target: np.ndarray, verts: np.ndarray,
                          free_end: bool = False, size_whole: bool = False) -> SectionShape:
    """A closed section along ``start -> target`` sized to its vertices ``verts`` (m, 3).

    The column spans the vertices' extent along the axis (so adjacent sections meet where their
    ground-truth labels meet); a free end is shortened by its cap so that the cap reaches the
    extreme vertex. The axis is moved to the centre of the vertices' cross-sections; radii are
    sqrt(2 * variance) along the principal directions of the cross-section coordinates between
    ``start`` and ``target`` (exact for points spread evenly on an ellipse); with ``size_whole``
    over the whole extent (the head, whose direction joint lies inside it: sized on the neck
    alone, the model would miss the back of the skull).
    """
    d = target - start
    reach = float(np.linalg.norm(d))
    d = d / reach
    helper = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
    fx = np.cross(d, helper)
    fx /= np.linalg.norm(fx)
    fy = np.cross(d, fx)
    q = verts - start
    t = q @ d
    t0, t1 = np.percentile(t, _EXTENT)
    body = (t >= max(t0, 0.0)) & (t <= (t1 if size_whole else min(t1, reach)))
    sel = q[body] if body.sum() >= 10 else q
    xy = np.column_stack([sel @ fx, sel @ fy])
    centre = xy.mean(axis=0)
    w, v = np.linalg.eigh(np.cov((xy - centre).T))
    radii = np.sqrt(2 * np.maximum(w[::-1], 1e-8))
    major = v[:, 1]
    if size_whole:  # a head is no column: take its extent (2.5-97.5 percentiles) across the axis
        along = (xy - centre) @ v[:, ::-1]
        lo, hi = np.percentile(along, [2.5, 97.5], axis=0)
        radii = (hi - lo) / 2
        centre = centre + v[:, ::-1] @ ((hi + lo) / 2)
    frame_x = major[0] * fx + major[1] * fy
    base = start + centre[0] * fx + centre[1] * fy
    length = max(float(t1 - t0), 1e-3)
    joint_cap = JOINT_CAP * float(radii.min())
    end_cap = float(min(radii.mean(), 0.45 * length))
    if free_end:
        length = max(length - end_cap, 0.5 * length)
    a = base + t0 * d
    return SectionShape(name=name, start=a, end=a + d * length, radii=radii, frame_x=frame_x,
                        closed=(True, True), caps=(joint_cap, end_cap if free_end else joint_cap))


def fit_from_body(body) -> BodyFit:
    """The oracle BodyFit of a body with ground truth.

    Parameters
    ----------
    body : poses.Body
        With ``vertex_section`` and ``joints``.

    Returns
    -------
    fit : BodyFit
        All 11 sections, closed caps, the body's joints, residuals of the section vertices.
    """
    body.require_ground_truth("the oracle posture")
    joints = body.joint_dict()
    v = body.vertices
    sections, residuals = {}, {}
    for j, name in enumerate(SECTIONS):
        a, b, free = _AXES[name]
        verts = v[body.vertex_section == j]
        if len(verts) < 10:
            continue
        start, target = np.asarray(joints[a], dtype=float), np.asarray(joints[b], dtype=float)
        if name == "head":  # the head joint sits forward of the neck: use the head's own principal axis nearest to it
            c = verts - verts.mean(axis=0)
            vecs = np.linalg.eigh(c.T @ c)[1]
            along = vecs.T @ (target - start)
            axis = vecs[:, np.argmax(np.abs(along))] * np.sign(along[np.argmax(np.abs(along))])
            target = start + axis * np.linalg.norm(target - start)
        shape = section_from_vertices(name, start, target, verts, free, size_whole=name == "head")
        sections[name] = shape
        residuals[name] = float(np.sqrt(np.mean(shape.coords(verts)[0] ** 2)))
    unfitted = tuple(s for s in SECTIONS if s not in sections)
    return BodyFit(sections=sections, joints={k: np.asarray(x, dtype=float) for k, x in joints.items()},
                   residuals=residuals, unfitted=unfitted)
