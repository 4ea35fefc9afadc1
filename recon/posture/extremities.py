"""Hands and feet as sections of the body model (beyond the paper, whose 11 sections have none).

`place_extremities` runs after the paper's fit and leaves it as it is: past each fitted wrist and
ankle (the fit's seams, `recon.model.BodyFit.seams`) it takes the points that lie beyond the joint
along the forearm (lower leg) and nearer to that section's model than to any other, and places an
elliptic column through them along their principal axis (a hand: a flat column past the wrist; a
foot: a column from the ankle forward along the floor), open at the joint and capped at the
fingertips (toes); a small least-squares fit (`recon.posture.adjust.fit_section`) moves it onto the
points. The clustering gives the column its points (`recon.clustering.cluster.assign_extremities`)
and the surface stage meshes them on a chart of their own
(`recon.surface.complete.extremity_charts`); a hand is still scored as its forearm and a foot as its
lower leg. `--param extremities=False` gives the paper's 11 sections.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .bodymodel import LIMBS
from ..model import EXTREMITIES, BodyFit, SectionShape

#: How far past its joint a hand (foot) reaches, as a multiple of the forearm's (lower leg's)
#: length from elbow to wrist (knee to ankle): a hand is 0.74 forearm lengths long and a foot 0.61
#: lower-leg lengths (Winter 2009, 0.108 / 0.145 H and 0.152 / 0.246 H); with room for the fit's
#: joint errors.
REACH = {"forearm": 1.0, "lower_leg": 0.9}

#: Fewer points than this past a joint place no extremity (the part was not seen).
MIN_POINTS = 20


def _principal(q: np.ndarray):
    """Eigenvectors (columns, by decreasing spread) and standard deviations of ``q`` (k, 3)."""
    c = q.mean(axis=0)
    w, vec = np.linalg.eigh(np.cov((q - c).T))
    return c, vec[:, ::-1], np.sqrt(np.maximum(w[::-1], 0.0))


def extremity_shape(points: np.ndarray, joint: np.ndarray, name: str) -> SectionShape | None:
    """The column of one hand or foot through ``points`` (k, 3), open at ``joint`` (3,).

    The axis is the points' principal axis, turned away from the joint; it starts at the joint's
    projection (or at the points' nearest end, if that lies behind it: a heel) and ends at the
    farthest point less the cap. Cross-section radii from the spread across the axis (a uniform
    plate's half-width is 1.73 standard deviations), then twice a bounded least-squares fit of the
    axis (`fit_section`, radii kept) and one of the radii (`_radii`).
    """
    from .adjust import fit_section

    if len(points) < MIN_POINTS:
        return None
    c, vec, sd = _principal(points)
    d = vec[:, 0] if float((c - joint) @ vec[:, 0]) >= 0 else -vec[:, 0]
    t = (points - c) @ d
    lo = min(float((joint - c) @ d), float(t.min()))
    hi = float(t.max())
    radii = np.maximum(1.7 * sd[1:], 0.006)
    cap = min(float(radii.min()), 0.4 * (hi - lo))
    if hi - lo - cap < 0.02:
        return None
    shape = SectionShape(name=name, start=c + lo * d, end=c + (hi - cap) * d, radii=radii,
                         frame_x=vec[:, 1], closed=(False, True), caps=(cap, cap))
    for _ in range(2):
        shape, _ = fit_section(points, shape, iterations=1, free_end=False, fit_radii=False,
                               max_shift=0.5 * float(radii.max()), max_turn=0.3)
        shape = _radii(points, shape)
    return shape


def _radii(points: np.ndarray, shape: SectionShape) -> SectionShape:
    """``shape`` with the cross-section radii that fit the column's points best (least squares on
    their distance to the surface: a hand is a flat ellipse, beyond a first-order fit), and its
    end cap as high as the smaller one, its tip kept."""
    from scipy.optimize import least_squares

    q = shape.local(points)
    q = q[(q[:, 2] >= 0) & (q[:, 2] <= shape.length)]
    if len(q) < MIN_POINTS:
        return shape
    fit = least_squares(_open_distance, np.clip(shape.radii, 0.006, 0.3), jac=_open_distance_jac,
                        args=(q[:, 0] ** 2, q[:, 1] ** 2), loss="soft_l1", f_scale=0.005,
                        bounds=(0.006, 0.3), max_nfev=30)
    tip = shape.length + shape.caps[1]        # the fingertips (toes) stay where they are
    cap = min(float(fit.x.min()), 0.4 * tip)
    return shape.replace(end=shape.start + (tip - cap) * shape.axis, radii=fit.x, caps=np.array([cap, cap]))


def _open_distance(ab: np.ndarray, x2: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """(k,) signed distance from an open elliptic column of radii ``ab`` (2,) of the points whose
    squared local coordinates across it are ``x2``, ``y2`` (k,): `SectionShape.coords`' r."""
    s = np.sqrt(x2 / ab[0] ** 2 + y2 / ab[1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s > 0, np.sqrt(x2 + y2) * (1.0 - 1.0 / s), -ab.min())


def _open_distance_jac(ab: np.ndarray, x2: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """(k, 2) derivatives of `_open_distance` by the radii: ``-|xy| x^2 / (a^3 s^3)`` and likewise
    ``b`` (analytic: the numerical one cost `_radii` two thirds of its evaluations)."""
    s3 = (x2 / ab[0] ** 2 + y2 / ab[1] ** 2) ** 1.5
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(s3 > 0, -np.sqrt(x2 + y2) / s3, 0.0)
    return np.column_stack([f * x2 / ab[0] ** 3, f * y2 / ab[1] ** 3])


def extremity_points(points: np.ndarray, fit: BodyFit, parent: str, joint: str) -> np.ndarray:
    """(k,) indices of ``points`` (n, 3) that may be the hand (foot) past ``joint`` of section
    ``parent``: beyond the joint along the parent's axis, within `REACH` of it, and nearer to the
    parent's model than to any other fitted section's."""
    s = fit.sections[parent]
    j = np.asarray(fit.seams[joint], dtype=float)
    prox = next(middle for _, dist, _, middle, _ in LIMBS if dist == parent)   # elbow, knee
    length = float(np.linalg.norm(j - fit.seams[prox])) if prox in fit.seams else s.length
    rel = points - j
    near = np.flatnonzero((rel @ s.axis > 0) & (np.einsum("ij,ij->i", rel, rel)
                                                 < (REACH[parent[:-2]] * length) ** 2))
    if len(near) == 0:
        return near
    d = np.stack([o.distance(points[near]) for o in fit.sections.values()], axis=1)
    return near[d[:, list(fit.sections).index(parent)] <= d.min(axis=1)]


def place_extremities(points: np.ndarray, fit: BodyFit) -> BodyFit:
    """The fit with its hands and feet placed (`BodyFit.extremities`), the paper's 11 sections
    unchanged.

    Parameters
    ----------
    points : (n, 3) float, metres
        The cloud the fit was made on.
    fit : BodyFit

    Returns
    -------
    BodyFit
        ``extremities``: {``hand_l``...: SectionShape} for each wrist or ankle with a fitted forearm
        (lower leg) and enough points past it.
    """
    points = np.asarray(points, dtype=np.float64)
    out = {}
    for name, (parent, joint) in EXTREMITIES.items():
        if parent not in fit.sections or joint not in (fit.seams or {}):
            continue
        idx = extremity_points(points, fit, parent, joint)
        shape = extremity_shape(points[idx], np.asarray(fit.seams[joint], dtype=float), name)
        if shape is not None:
            out[name] = shape
    return replace(fit, extremities=out)
