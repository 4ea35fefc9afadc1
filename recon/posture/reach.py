"""An arm the scan shows only sparsely, searched as a chain from its fitted shoulder (step 7 of
`recon.posture`).

An arm held towards a camera is seen nearly end-on: the scan holds its fist and the tops of the
upper arm and forearm, a few points spread along the limb, and the fine adjustment's arm covers
too little of its column to be trusted (`recon.posture.adjust.arm_doubtful`). The points still say where
the arm is: a chain (upper arm, then forearm within the elbow's bend) from the fitted shoulder
whose columns hold points no other section explains, whose HAND END holds points (the fist of an
arm held out is always seen: it is the part nearest the camera the arm points at), and whose
axis runs through empty space (no points inside its columns, not inside another section). A
scan without the arm (cut off, or hidden) has no such points at the hand end, and the arm stays
unfitted: a wrong arm is never invented.
"""

from __future__ import annotations

import numpy as np

from .adjust import _SEARCH_DIRS, _assign, axis_samples_inside, fit_section, limb_columns
from .bodymodel import LIMBS, StandardBody
from ..geometry import fibonacci_sphere, perp
from ..params import FitParams

__all__ = ["reach_arms"]


def reach_arms(points, secs: dict, resid: dict, counts: dict, listed, body: StandardBody,
               params: FitParams, back=None) -> tuple[dict, dict, dict, set]:
    """Arms listed unfitted, searched again as a chain from the fitted shoulder.

    For an arm with a section in ``listed``, the free points (within an arm's reach of the shoulder,
    farther than `fit_near_distance` from every other section: the trunk's own surface, which its
    columns fit to a few cm, is not taken for an arm) are searched for a chain from the upper
    arm's start (the shoulder, placed with the torso), with the model's lengths and radii:

    - upper arm: every direction of `recon.posture.adjust._SEARCH_DIRS` (800 over the sphere) whose column
      holds surface points (within 0.6 radii of its surface) in at least `reach_min_upper_bins` of
      its five fifths (an arm's seen surface runs along it, even sparsely: a direction grazing a
      patch of the trunk near the shoulder holds points only there), few in its core (at most
      `reach_max_core_fraction` of them nearer the axis than 0.4 radii: an arm does not cross seen
      surface), few around it (`reach_max_halo_fraction`, 1.6 to 3 radii out: a limb stands apart,
      a patch of trunk surface spreads around a column laid on it) and its axis half a radius clear
      of every other section; the `reach_candidates` with most surface points go on;
    - forearm: every direction of a 400-direction sphere within the elbow's bend
      (`match_max_bend`) whose hand end (the last `reach_hand_fraction` of the forearm and one
      radius beyond, within 1.6 radii of its axis) holds at least `reach_min_hand_points` free
      points, with the space beyond it (1 to 4 radii past the end) nearly empty (at most
      `reach_max_core_fraction` of the hand's count: a hand is a free end, the fist of an arm held
      out is what the camera it points at sees first), counting only points off the upper arm's
      column (a forearm folded back onto it), few core and halo points, its axis half a radius
      clear of other sections, its hand not behind the trunk near it or the thighs (``back``), and
      at least `fit_min_points` points on the chain.
    - a chain found is not taken when, with every found arm in place, more than
      `reach_max_shared_fraction` of the points either section is nearest to lie within
      `fit_coverage_distance` of another section's surface: a limb explains points no other
      section explains (arm_across turned 90 degrees without its
      left forearm: a "forearm" found on 44 points, 77 % of them on the other forearm, the upper arm
      and the chest, wrist 49 cm off; found arms of arms_forward: at most 12 %).

    The chain with most fifths of its two sections holding points (then most points) is refined,
    each section on the points it is nearest to (`recon.posture.adjust.fit_section`, model radii and
    lengths, the forearm from the refined elbow; kept when it fits those points better), and
    replaces the arm. A scan without the arm (cut off, hidden) has no hand end on free points
    within reach, and the arm stays listed.

    Parameters
    ----------
    points : (n, 3) float, metres
        The cloud.
    secs : dict of str -> SectionShape
        All sections as fitted (the listed arms too, placed where the fine adjustment left them).
    resid, counts : dict of str -> float, int
        Residual rms (m) and point count per section.
    listed : iterable of str
        Sections the checks list unfitted.
    body : StandardBody
        The model at the fitted stature (lengths, radii).
    params : FitParams
    back : (3,) float, optional
        Unit vector towards the body's back (front and back from the data, `recon.posture.joints.front_sign`):
        a chain whose hand would lie behind the trunk, within `reach_back_clearance` of its
        or the thighs' columns (before or after its refinement), is not taken (a hand resting on
        the back cannot be told from the back's own surface, which the fitted torso's column
        leaves out by several cm at the shoulder blades: the standing scan with its left forearm
        cut found a "hand" there; in another facing, one on the buttocks below the waist's column).

    Returns
    -------
    secs, resid, counts : dict
        With the found arms' two sections replaced (rms: of their surface points to the model's
        columns, m; count: points assigned to them).
    reached : set of str
        The names of the replaced sections (both of each found arm).
    """
    reached = set()
    listed = set(listed)
    secs0, resid0, counts0 = secs, resid, counts
    for prox, dist, root, *_ in LIMBS:
        if not root.startswith("shoulder") or not ({prox, dist} & listed) or prox not in secs or dist not in secs:
            continue
        found = _search_arm(points, secs, prox, dist, body, params, back)
        if found is None:
            continue
        up, fore = found
        trial = {**secs, prox: up, dist: fore}
        names, k = _assign(points, trial, params.fit_near_distance)
        r, c = {}, {}
        for n in (prox, dist):
            own = points[k == names.index(n)]
            r[n] = float(np.sqrt(np.mean(trial[n].distance(own) ** 2))) if len(own) else np.inf
            c[n] = int(len(own))
        secs, resid, counts = trial, {**resid, **r}, {**counts, **c}
        reached |= {prox, dist}
    if reached:
        # with every found arm in place: an arm whose points are another section's surface is not an arm
        # (sections still listed are not placed: they do not count)
        placed = {n: v for n, v in secs.items() if n in reached or n not in listed}
        names, k = _assign(points, placed, params.fit_near_distance)
        for prox, dist, *_ in LIMBS:
            if prox in reached and any(
                    _shared_fraction(points[k == names.index(n)], placed, n, params.fit_coverage_distance)
                    > params.reach_max_shared_fraction for n in (prox, dist)):
                secs = {**secs, prox: secs0[prox], dist: secs0[dist]}
                resid = {**resid, **{n: resid0[n] for n in (prox, dist) if n in resid0}}
                counts = {**counts, **{n: counts0[n] for n in (prox, dist) if n in counts0}}
                reached -= {prox, dist}
    return secs, resid, counts, reached


def _shared_fraction(own, secs: dict, name: str, near: float) -> float:
    """The fraction of the points ``own`` (k, 3) of section ``name`` lying within ``near`` metres of
    another section's surface in ``secs`` (0 without points): a limb explains points no other
    section explains."""
    if not len(own):
        return 0.0
    d = np.min(np.stack([v.distance(own) for n, v in secs.items() if n != name], 1), 1)
    return float(np.mean(d < near))


def _search_arm(points, secs: dict, prox: str, dist: str, body: StandardBody, params: FitParams, back=None):
    """The best chain (upper arm, forearm) of `reach_arms` for one arm, or None."""
    s = secs[prox].start
    Lu, Lf = body.section_length(prox), body.section_length(dist)
    ru, rf = float(body.radii("upper_arm").mean()), float(body.radii("forearm").mean())
    others = [v for k, v in secs.items() if k not in (prox, dist)]
    X = points[np.linalg.norm(points - s, axis=1) < Lu + Lf + rf]
    if len(X) < params.fit_min_points:
        return None
    free = np.min(np.stack([o.distance(X) for o in others], 1), 1) > params.fit_near_distance
    X = X[free]
    if len(X) < params.fit_min_points:
        return None

    cos_bend = np.cos(np.radians(params.match_max_bend))
    # the upper arm's best directions over the sphere, each with the forearm's over a coarser sphere
    trunk = [secs[n] for n in ("chest", "waist") if n in secs]
    # the back of the trunk, the buttocks and the backs of the thighs: the body's own surface
    rear = trunk + [secs[n] for n in ("thigh_l", "thigh_r") if n in secs]

    def behind_body(hand):
        """(k,) bool: the hands (k, 3) behind the trunk, within the clearance of its rear."""
        behind = (hand - trunk[0].start) @ np.asarray(back, dtype=float) > 0
        return behind & (np.min(np.stack([t.coords(hand)[0] for t in rear], 1), 1) < params.reach_back_clearance)

    def forearms(d1):
        d2s = _COARSE_DIRS[_COARSE_DIRS @ d1 >= cos_bend]
        if back is None or not trunk:
            return d2s
        return d2s[~behind_body(s + Lu * d1 + Lf * d2s)]

    best = _best_chain(X, s, _SEARCH_DIRS, forearms, (Lu, Lf, ru, rf), others, params, params.reach_candidates)
    if best is None:
        return None
    _, d1, d2 = best
    e = s + Lu * d1
    up = secs[prox].replace(start=s, end=e, radii=body.radii("upper_arm"), frame_x=perp(d1))
    fore = secs[dist].replace(start=e, end=e + Lf * d2, radii=body.radii("forearm"), frame_x=perp(d2))
    # refined on the points each section is nearest to (least squares, model radii and lengths), the
    # forearm from the refined elbow; a refinement that fits those points worse is not taken
    chain = {**secs, prox: up, dist: fore}
    for n in (prox, dist):
        names, k = _assign(points, chain, params.fit_near_distance)
        own = points[k == names.index(n)]
        if len(own) < params.reach_min_hand_points:
            continue
        shp, rms = fit_section(own, chain[n], loss=params.fit_loss, iterations=2, free_end=False, fit_radii=False,
                             max_shift=params.fit_max_shift, max_turn=np.radians(params.fit_max_turn))
        if rms <= np.sqrt(np.mean(chain[n].distance(own) ** 2)):
            chain[n] = shp
        if n == prox:
            f = chain[dist]
            chain[dist] = f.replace(start=chain[prox].end, end=chain[prox].end + Lf * f.axis)
    if back is not None and trunk and behind_body(chain[dist].end[None])[0]:
        return None   # refined onto the body's rear
    return chain[prox], chain[dist]


def _best_chain(X, s, d1s, d2_of, dims, others, params: FitParams, keep: int):
    """The best chain from the shoulder ``s`` (3,) on the free points ``X`` (m, 3): upper-arm directions
    ``d1s`` (k, 3) (the ``keep`` with most surface points among those holding points along 4 fifths of
    the upper arm, few in its core, not into another section), forearm directions ``d2_of(d1)`` (j, 3);
    ``dims`` (upper-arm length, forearm length, their radii), m. Returns (score, d1, d2) or None."""
    Lu, Lf, ru, rf = dims
    surf_u, core_u, own_u = (np.zeros((len(d1s), len(X)), bool) for _ in range(3))
    bins_u, halo = np.zeros(len(d1s), np.int64), np.zeros(len(d1s), np.int64)
    for rows, surf, core, t, rho in limb_columns(X, s, d1s, Lu, ru):
        surf_u[rows], core_u[rows] = surf, core
        bins_u[rows] = _bins_seen(surf, t / Lu)
        own_u[rows] = (t > -ru) & (t < Lu + ru) & (rho < 1.6 * ru)
        halo[rows] = ((t > 0.15 * Lu) & (t < Lu) & (rho > 1.6 * ru) & (rho < 3 * ru)).sum(1)
    n_u = surf_u.sum(1)
    seen = (bins_u >= params.reach_min_upper_bins) & (core_u.sum(1) <= params.reach_max_core_fraction * n_u) \
        & (halo <= params.reach_max_halo_fraction * n_u)
    seen[seen] = axis_samples_inside(others, s, d1s[seen], Lu, 0.5 * ru, 7) == 0
    order = np.argsort(-np.where(seen, n_u, -1), kind="stable")[:keep]
    order = order[seen[order]]
    best = None
    for i in order:
        d1 = d1s[i]
        e = s + Lu * d1
        d2s = d2_of(d1)
        if not len(d2s):
            continue
        # per forearm direction: points at the hand end, beyond it, on its surface or the upper
        # arm's, in either core, in its halo; and the fifths of its length holding points. The
        # forearm's own points are not on or in the upper arm's column (a forearm folded back onto it)
        mine = ~own_u[i]
        n_hand, beyond, n_surf, n_core, halo_f, bins_f = (np.zeros(len(d2s), np.int64) for _ in range(6))
        for rows, surf, core, t, rho in limb_columns(X, e, d2s, Lf, rf):
            hand = (t > (1 - params.reach_hand_fraction) * Lf) & (t < Lf + rf) & (rho < 1.6 * rf) & mine
            on = (surf & mine) | hand
            n_hand[rows] = hand.sum(1)
            beyond[rows] = ((t >= Lf + rf) & (t < Lf + 4 * rf) & (rho < 1.6 * rf)).sum(1)
            n_surf[rows] = (on | surf_u[i]).sum(1)
            n_core[rows] = ((core & mine) | core_u[i]).sum(1)
            halo_f[rows] = ((t > 0.15 * Lf) & (t < Lf + rf) & (rho > 1.6 * rf) & (rho < 3 * rf) & mine).sum(1)
            bins_f[rows] = _bins_seen(on, t / Lf)
        ok = (n_hand >= params.reach_min_hand_points) & (halo_f + halo[i] <= params.reach_max_halo_fraction * n_surf) & (beyond <= params.reach_max_core_fraction * n_hand) \
            & (n_surf >= params.fit_min_points) & (n_core <= params.reach_max_core_fraction * n_surf)
        if not ok.any():
            continue
        ok[ok] = axis_samples_inside(others, e, d2s[ok], Lf, 0.5 * rf, 7) == 0
        # an arm's seen points run along its whole length: the most fifths holding points first
        score = np.where(ok, (bins_u[i] + bins_f) * (len(X) + 1) + n_surf, -1)
        j = int(np.argmax(score))
        if score[j] >= 0 and (best is None or score[j] > best[0]):
            best = (int(score[j]), d1, d2s[j])
    return best


def _bins_seen(on: np.ndarray, f: np.ndarray, n: int = 5) -> np.ndarray:
    """(k,) how many of ``n`` equal lengths of a section hold points: ``on`` (k, m) bool, the points on
    its surface per direction; ``f`` (k, m) their position along it as a fraction of its length."""
    b = np.clip((f * n).astype(int), 0, n - 1)
    return sum((on & (b == i)).any(1) for i in range(n))


#: Forearm directions searched (about 10 degrees apart).
_COARSE_DIRS = fibonacci_sphere(400)
