"""Coarse matching of the body model to the volume data (paper 2.3(1), steps 2-4 of `recon.posture`).

The volume score (`Scorer`), the torso's 6-DOF search, the limb chains' direction searches, the
placement of a whole body at a size (`Pose`), and `coarse_match`: the ranked coarse poses that
`recon.posture.fit.estimate_posture` adjusts in turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bodymodel import LIMBS, STATURE_RANGE, StandardBody, kind_of, standard_body
from .joints import find_crotch
from ..geometry import cross, fibonacci_sphere, frames_from_dirs, perp, rotvec, tangent_dir, unit
from ..model import SectionShape
from ..params import FitParams
from .volume import Volume


#: Crown to crotch, as a fraction of stature: 0.52 (ANSUR II men, crotch height 0.48 of stature;
#: women 0.478). On the library's upright bodies, from their points: 0.51 (tall) to 0.545 (heavy).
CROWN_CROTCH = 0.52


class Scorer:
    """Looks up matching weights on the volume: mean weight of sample points inside model columns."""

    def __init__(self, vol: Volume, params: FitParams):
        from scipy import ndimage

        self.vol = vol
        self.empty = params.match_empty_weight
        self.claimed = params.match_claimed_weight
        w = vol.weights(params.contour_weight, params.match_empty_weight)
        self.w = ndimage.gaussian_filter(w, 0.7, mode="constant", cval=self.empty)
        self._ndimage = ndimage
        # for the shell score (a limb seen from one side only): contour voxels and their 26
        # neighbours, and voxels inside sections already placed
        self.near = ndimage.binary_dilation(vol.contour, structure=np.ones((3, 3, 3), bool))
        self.taken = np.zeros(vol.shape, bool)

    def flags(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(near contour, inside a placed section) at ``pts`` (..., 3) metres, nearest voxel."""
        shp = pts.shape[:-1]
        idx = np.rint(self.vol.index(pts.reshape(-1, 3))).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.array(self.vol.shape)), axis=1)
        flat = np.ravel_multi_index(idx.T, self.vol.shape, mode="clip")   # outside: any voxel, masked
        near = np.take(self.near, flat) & ok
        taken = np.take(self.taken, flat) & ok
        return near.reshape(shp), taken.reshape(shp)

    def lookup(self, pts: np.ndarray) -> np.ndarray:
        """Weights at ``pts`` (..., 3) metres, trilinear."""
        shp = pts.shape[:-1]
        idx = self.vol.index(pts.reshape(-1, 3)).T
        val = self._ndimage.map_coordinates(self.w, idx, order=1, mode="constant", cval=self.empty)
        return val.reshape(shp)

    def claim(self, shape: SectionShape, shrink: float = 1.0) -> None:
        """Make the voxels inside ``shape`` (a section already placed; its radii times ``shrink``)
        count against any later section: weight ``min(w, claimed)``."""
        v = self.vol
        shape = shape.replace(radii=shape.radii * shrink, caps=shape.caps * shrink)
        lo = np.minimum(shape.start, shape.end) - shape.radii.max() - shape.caps.max()
        hi = np.maximum(shape.start, shape.end) + shape.radii.max() + shape.caps.max()
        i0 = np.clip(np.floor(v.index(lo)).astype(int), 0, np.array(v.shape) - 1)
        i1 = np.clip(np.ceil(v.index(hi)).astype(int) + 1, 0, np.array(v.shape))
        if np.any(i1 <= i0):
            return
        g = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(i0, i1)], indexing="ij"), -1).reshape(-1, 3)
        g = g[shape.contains(g * v.size + v.origin)]
        self.w[g[:, 0], g[:, 1], g[:, 2]] = np.minimum(self.w[g[:, 0], g[:, 1], g[:, 2]], self.claimed)
        self.taken[g[:, 0], g[:, 1], g[:, 2]] = True


#: Sample template inside a unit column: rows (x/a, y/b, h/L) with h in [0, 1].
def _template(n_h: int = 7, rings=(0.0, 0.55, 0.9), n_t: int = 8, h0: float = 0.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n_t, endpoint=False)
    cross = [np.zeros((1, 2))] + [np.stack([r * np.cos(t), r * np.sin(t)], 1) for r in rings if r > 0]
    cross = np.concatenate(cross)
    h = np.linspace(h0, 1.0, n_h)
    return np.concatenate([np.column_stack([cross, np.full(len(cross), hh)]) for hh in h])


_TORSO_T = _template(9, (0.0, 0.45, 0.85), 10)
_LIMB_T = _template(6, (0.0, 0.6), 6, h0=0.15)


def _column_score(scorer: Scorer, start, frames, length, radii, template) -> np.ndarray:
    """Mean weight inside columns: ``start`` (m, 3) or (3,), ``frames`` (m, 3, 3) rows x, y, axis."""
    loc = template * np.array([radii[0], radii[1], length])
    pts = np.asarray(start)[..., None, :] + loc @ frames
    return scorer.lookup(pts).mean(axis=-1)


#: Shell score samples in a unit column, away from the joints at its ends (h in [0.15, 0.95]): its
#: surface, 12 around x 6 along, each at 0.7, 1 and 1.3 radii (a limb thinner or thicker than the
#: model's), and its axis.
_SHELL_RING = _template(6, (1.0,), 12, h0=0.15) * [1, 1, 0.95]
_SHELL_RING = _SHELL_RING[np.hypot(_SHELL_RING[:, 0], _SHELL_RING[:, 1]) > 0.5]       # (72, 3)
_SHELL_SURF = np.concatenate([_SHELL_RING * [f, f, 1.0] for f in (0.7, 1.0, 1.3)])  # (216, 3)
_SHELL_CORE = _template(6, (), 1, h0=0.15) * [1, 1, 0.95]                          # (6, 3)


def _shell_score(scorer: Scorer, start, frames, length, radii, avoid=None) -> np.ndarray:
    """Fraction of a column's surface samples near contour voxels not inside placed sections (at
    any of the three radii), minus the fraction of its axis samples near contour: (m,) for
    ``start`` (m, 3) or (3,), ``frames`` (m, 3, 3). A limb seen from one side only (a seated
    person's thighs, seen from above: no inside voxels) scores about 0.5 on its true axis; a column
    through a surface scores below 0. The axis of a limb may run inside a placed section (a seated
    person's thigh under the waist's claimed margin): that alone is no penalty. ``avoid`` = (root,
    d, length, radius): samples within that column (the proximal section of the chain) count as
    inside a placed section, and on the axis as a penalty (no folding back over the same limb)."""
    scale = np.array([radii[0], radii[1], length])
    out = []
    for tmpl in (_SHELL_SURF, _SHELL_CORE):
        pts = np.asarray(start)[..., None, :] + (tmpl * scale) @ frames
        near, taken = scorer.flags(pts)
        fold = np.zeros(near.shape, bool)
        if avoid is not None:
            root, d, L, r = avoid
            h = np.minimum(np.maximum((pts - root) @ d, 0.0), L)
            fold = np.linalg.norm(pts - root - h[..., None] * d, axis=-1) < r
        out.append(near & ~taken & ~fold if tmpl is _SHELL_SURF else near | fold)
    surf = out[0].reshape(out[0].shape[:-1] + (3, -1)).any(axis=-2)
    return surf.mean(axis=-1) - out[1].mean(axis=-1)


# -- coarse matching ----------------------------------------------------------------------------
@dataclass
class Pose:
    """The coarse model: torso frame and all sections."""

    centre: np.ndarray     # torso column centre
    R: np.ndarray          # (3, 3) columns: left, back, up (provisional until front is resolved)
    body: StandardBody
    sections: dict
    score: float = 0.0
    section_scores: dict = None   # mean volume weight of each limb section where it was placed
    shell_scores: dict = None     # shell score of each limb section placed by the shell search
    explained: float = 0.0        # fraction of the points near the model's surface


def _torso_frames(R: np.ndarray) -> np.ndarray:
    return R.T[None]  # rows x (left), y (back), axis (up)


def torso_len(body: StandardBody) -> float:
    return body.length("neck")


def _match_torso(scorer: Scorer, centroid: np.ndarray, body: StandardBody, params: FitParams,
                 starts=None, step: float = 1.0) -> list:
    """Candidate torso poses (centre, R) ranked by volume score, refined (Nelder-Mead, first steps
    ``step`` times 4 cm and 0.15 rad: given ``starts``, a smaller ``step`` keeps each near its own)."""
    from scipy.optimize import minimize

    L = torso_len(body)
    rad = np.array([body.radii("chest")[0] * 0.95, body.radii("waist")[1]])
    tmpl = _TORSO_T - np.array([0, 0, 0.5])

    # above the shoulders, beside the neck, the body is empty in any posture: samples there count
    # against the torso (this pins the torso's position along its axis)
    t = np.radians(np.r_[-40:41:20, 140:221:20])
    ring = np.column_stack([np.cos(t), np.sin(t), np.full(len(t), 0.5 + 0.06 * body.stature / L)])

    lam = params.match_upright_prior
    cos_up = np.cos(np.radians(params.match_upright_start))

    scale = np.array([rad[0], rad[1], L])
    loc_t, loc_r, n_t = tmpl * scale, ring * scale, len(tmpl)

    def score(c, R):
        # `_column_score` of both templates, their samples looked up in one call (the same numbers)
        w = scorer.lookup(np.concatenate([c + loc_t @ R.T, c + loc_r @ R.T]))
        return float(w[:n_t].mean() - w[n_t:].mean() - lam * (1.0 - abs(R[2, 2])))

    if starts is None:
        dirs = np.vstack([[0.0, 0.0, 1.0], fibonacci_sphere(params.match_torso_directions, hemisphere=True)])
        u = perp(dirs)
        w = cross(dirs, u)
        rolls = np.linspace(0, np.pi, 6, endpoint=False)
        X = (u[:, None] * np.cos(rolls)[None, :, None] + w[:, None] * np.sin(rolls)[None, :, None]).reshape(-1, 3)
        Z = np.repeat(dirs, len(rolls), axis=0)
        Y = cross(Z, X)
        frames = np.stack([X, Y, Z], axis=1)
        cands = []
        for off in (-0.05, 0.0, 0.05):
            c = centroid + off * body.stature * Z
            s = (_column_score(scorer, c, frames, L, rad, tmpl) - _column_score(scorer, c, frames, L, rad, ring)
                 - lam * (1.0 - np.abs(frames[:, 2, 2])))
            cands += [(s[i], c[i], frames[i].T) for i in range(len(s))]
        cands.sort(key=lambda t: -t[0])
        starts, seen = [], []
        for s, c, R in cands:
            if any(abs(R[:, 2] @ S[:, 2]) > np.cos(np.radians(20)) and abs(R[:, 0] @ S[:, 0]) > 0.8
                   and np.linalg.norm(c - cc) < 0.08 for cc, S in seen):
                continue
            seen.append((c, R))
            starts.append((c, R))
            if len(starts) == 3:
                break
        # and the best upright torso: on a coarse volume a torso tilted onto a hanging arm can
        # outscore it (its wide axis turned front-back, it covers torso and arm); the whole-body
        # match decides (the scanner's +z is up, and people are scanned mostly upright)
        if all(abs(R[2, 2]) < cos_up for _, R in starts):   # (refined, it stays upright)
            up = [(s, c, R) for s, c, R in cands if abs(R[2, 2]) >= cos_up]
            if up:
                starts.append(up[0][1:])
    out = []
    for c0, R0 in starts:
        upright = abs(R0[2, 2]) >= cos_up

        def f(x):
            R = rotvec(x[3:]) @ R0
            if upright and abs(R[2, 2]) < cos_up:
                return 10.0   # an upright start stays upright (another start may tilt)
            return -score(c0 + x[:3], R)
        simplex = np.vstack([np.zeros(6), step * np.diag([0.04, 0.04, 0.04, 0.15, 0.15, 0.15])])
        res = minimize(f, np.zeros(6), method="Nelder-Mead",
                       options=dict(initial_simplex=simplex, maxfev=150, xatol=1e-3, fatol=1e-4))
        out.append((-res.fun, c0 + res.x[:3], rotvec(res.x[3:]) @ R0))
    out.sort(key=lambda t: -t[0])
    return out


def _column(name, start, d, length, radii, frame_x, closed=(True, True)) -> SectionShape:
    return SectionShape(name=name, start=start, end=start + length * unit(d), radii=radii,
                        frame_x=frame_x, closed=closed)


def _search_chain(scorer, root, body, prox, dist, params, dirs, outward, R=None, shell=False):
    """Best (d1, d2, score) of a limb chain from ``root`` on the volume (``shell``: by the shell
    score, for a limb seen from one side only).

    With the torso frame ``R`` (columns left, back, up), a thigh may rise above the horizontal of
    the torso only by flexing (forward or backward: which is the front is not known yet) more than
    it rises: a thigh does not reach up beside the torso (on a coarse volume, a leg chain could
    otherwise follow the arm hanging next to it), and a shin never rises above its thigh (knees bend
    backwards only)."""
    from scipy.optimize import minimize

    L1, L2 = body.section_length(prox), body.section_length(dist)
    r1, r2 = body.radii(kind_of(prox)), body.radii(kind_of(dist))
    F = frames_from_dirs(dirs)
    s1 = _shell_score(scorer, root, F, L1, r1) if shell else _column_score(scorer, root, F, L1, r1, _LIMB_T)
    s1[dirs @ outward < -params.match_max_adduction] = -np.inf

    def raised(d):
        if R is None or not prox.startswith("thigh"):
            return np.zeros(d.shape[:-1], bool)
        up = d @ R[:, 2]
        return (up > params.match_thigh_max_rise) & (np.abs(d @ R[:, 1]) < up)

    s1[raised(dirs)] = -np.inf

    def shin_up(d1, d2):
        # a knee bends backwards only: the shin never rises above its thigh
        if R is None or not prox.startswith("thigh"):
            return np.zeros(np.broadcast_shapes(np.shape(d1)[:-1], np.shape(d2)[:-1]), bool)
        return d2 @ R[:, 2] > np.maximum(d1 @ R[:, 2], 0.0) + params.match_thigh_max_rise

    loc2 = _LIMB_T * np.array([r2[0], r2[1], L2])
    # the distal samples about the origin in every direction's frame, for the beam below (the same
    # products as ``loc2 @ F[ok]``, made once)
    locF = None if shell else loc2 @ F

    def folded_back(pts, w, d1):
        # distal samples inside the proximal column weigh as claimed: no folding back over the same limb
        rel = pts - root
        h = np.minimum(np.maximum(rel @ d1, 0.0), L1)   # np.clip, without its overhead
        off = rel - h[..., None] * d1
        off *= off   # the squared distance from the axis summed as np.linalg.norm does: ((x + y) + z)
        inside = np.sqrt(off[..., 0] + off[..., 1] + off[..., 2]) < r1[0] + r2[0]
        return np.where(inside, np.minimum(w, scorer.claimed), w).mean(axis=-1)

    def distal(elbow, d1, ok):
        if shell:
            return _shell_score(scorer, elbow, F[ok], L2, r2, avoid=(root, d1, L1, r1[0]))
        pts = elbow + locF[ok]
        return folded_back(pts, scorer.lookup(pts), d1)

    order = np.argsort(-s1)
    cos_max = np.cos(np.radians(params.match_max_bend if prox.startswith("thigh") else params.match_max_elbow_bend))
    best = (-np.inf, None, None)
    kept = []
    for i in order:
        if any(dirs[i] @ dirs[k] > np.cos(np.radians(12)) for k in kept):
            continue
        kept.append(i)
        elbow = root + L1 * dirs[i]
        ok = ~((dirs @ dirs[i] < cos_max) | shin_up(dirs[i], dirs)
               | ((L1 * dirs[i] + L2 * dirs) @ outward < -params.match_max_adduction * (L1 + L2)))
        tot = np.full(len(dirs), -np.inf)
        tot[ok] = s1[i] * L1 + distal(elbow, dirs[i], ok) * L2   # only the bends a chain can take
        j = int(np.argmax(tot))
        if tot[j] > best[0]:
            best = (tot[j], dirs[i], dirs[j])
        if len(kept) >= params.match_beam:
            break
    _, d1, d2 = best

    # the polish below evaluates one chain at a time: the tangent bases of d1 and d2 are fixed, and
    # both sections' samples are looked up in one call (the same numbers as `distal`)
    basis1, basis2 = (perp(d1), cross(d1, perp(d1))), (perp(d2), cross(d2, perp(d2)))
    loc1 = _LIMB_T * np.array([r1[0], r1[1], L1])
    n1 = len(_LIMB_T)

    def total(x):
        a = tangent_dir(d1, x[0], x[1], basis1)
        b = tangent_dir(d2, x[2], x[3], basis2)
        if a @ b < cos_max or a @ outward < -params.match_max_adduction or raised(a) or shin_up(a, b) or \
                (L1 * a + L2 * b) @ outward < -params.match_max_adduction * (L1 + L2):
            return 10.0
        e = root + L1 * a
        fa = frames_from_dirs(a[None])
        if shell:
            s1 = _shell_score(scorer, root, fa, L1, r1)
            return -(s1[0] * L1 + _shell_score(scorer, e, frames_from_dirs(b[None]), L2, r2,
                                               avoid=(root, a, L1, r1[0]))[0] * L2)
        p2 = e + loc2 @ frames_from_dirs(b[None])
        w = scorer.lookup(np.concatenate([root + loc1 @ fa, p2], axis=-2))
        return -(w[:, :n1].mean(axis=-1)[0] * L1 + folded_back(p2, w[:, n1:], a)[0] * L2)

    simplex = np.vstack([np.zeros(4), np.eye(4) * 0.12])
    res = minimize(total, np.zeros(4), method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, maxfev=60, xatol=1e-3, fatol=1e-4))
    return tangent_dir(d1, *res.x[:2]), tangent_dir(d2, *res.x[2:]), -res.fun


def _search_cone(scorer, start, axis, length, radii, frame_x, max_angle, n=120, max_side=90.0):
    """Best direction within ``max_angle`` degrees of ``axis`` for a column from ``start``, and
    leaning at most ``max_side`` degrees from ``axis`` towards ``frame_x`` (sideways)."""
    dirs = fibonacci_sphere(n * 4)
    side = unit(frame_x - axis * (frame_x @ axis))
    dirs = dirs[(dirs @ axis >= np.cos(np.radians(max_angle))) & (np.abs(dirs @ side) <= np.sin(np.radians(max_side)))]
    dirs = np.vstack([axis, dirs])
    fx = frame_x - dirs * (dirs @ frame_x)[:, None]
    fx = unit(fx)
    F = np.stack([fx, cross(dirs, fx), dirs], axis=1)
    s = _column_score(scorer, start, F, length, radii, _LIMB_T)
    i = int(np.argmax(s))
    return dirs[i], float(s[i])


def _robust_radii(points, s: SectionShape) -> np.ndarray:
    """(2,) radii of a torso column from the points around it: median distance from the axis of the
    points across (a) and front-back (b), within 1.5x the standard radii; the standard where unseen."""
    q = s.local(points)
    rho = np.hypot(q[:, 0], q[:, 1])
    sel = (q[:, 2] >= 0) & (q[:, 2] <= s.length) & (rho < 1.5 * s.radii.max()) & (rho > 0.3 * s.radii.min())
    out = s.radii.copy()
    for i in (0, 1):
        band = sel & (np.abs(q[:, i]) > 0.9 * rho)
        if band.sum() >= 10:
            out[i] = np.clip(np.median(rho[band]), 0.6 * s.radii[i], 1.5 * s.radii[i])
    return out


def _place_body(points, scorer_base: Scorer, centre, R, body: StandardBody, params, dirs,
                anchor: bool = True, min_shift: float | None = None) -> Pose:
    """Place all sections for a torso pose (R columns: left, back, up) and score the whole match;
    the torso slides to hang from the crown when the crown is off by more than ``min_shift`` (m;
    default `match_min_anchor_shift`). Legs before arms (the paper places the arms first)."""
    import copy

    scorer = copy.copy(scorer_base)
    scorer.w = scorer_base.w.copy()
    scorer.taken = scorer_base.taken.copy()
    ex, ez = R[:, 0], R[:, 2]
    L = torso_len(body)
    pelvis = centre - 0.5 * L * ez
    secs = {}
    fit_scores = {}
    shell_scores = {}
    total = 0.0
    Lw = body.section_length("waist")
    waist = _column("waist", pelvis, ez, Lw, body.radii("waist"), ex)
    cj = waist.end
    Lc = body.section_length("chest")
    dc, sc = _search_cone(scorer, cj, ez, Lc, body.radii("chest"), ex, 20)
    chest = _column("chest", cj, dc, Lc, body.radii("chest"), ex)
    # the torso's own width from the points (the standard radii may be far off), then claimed
    waist = waist.replace(radii=_robust_radii(points, waist))
    chest = chest.replace(radii=_robust_radii(points, chest))
    secs["waist"], secs["chest"] = waist, chest
    total += sc * Lc
    for s in (waist, chest):
        scorer.claim(s.replace(radii=s.radii + params.match_claim_margin))
    Lh = body.section_length("head")
    dh, sh = _search_cone(scorer, chest.end, chest.axis, Lh, body.radii("head"), ex, 70,
                          max_side=params.match_head_max_side)
    secs["head"] = _column("head", chest.end, dh, Lh, body.radii("head"), ex)
    if anchor:
        # the volume pins the torso poorly along its axis: the crown does (adult head length)
        shift = _crown_shift(points, secs["head"])
        on_trunk = False
        if shift is None and params.match_crown_on_trunk:
            # no crown on the head's axis: the head leans into the air above a torso matched too
            # high; the crown on the trunk's axis may only bring it down (at any size: a child's
            # larger head only leaves the torso a little high)
            shift = _crown_on_trunk(points, chest, Lh, float(body.radii("head").min()))
            shift, on_trunk = (shift, True) if shift is not None and shift < 0 else (None, False)
        elif body.stature < params.fit_anchor_min_stature:
            shift = None   # a child's head is relatively larger: the adult head length does not hold
        if shift is not None and abs(shift) > (params.match_min_anchor_shift if min_shift is None else min_shift):
            move = float(np.clip(shift, -params.match_max_anchor_shift, params.match_max_anchor_shift))
            moved = _place_body(points, scorer_base, centre + move * (chest.end - pelvis) / np.linalg.norm(chest.end - pelvis),
                                R, body, params, dirs, anchor=False)
            if not on_trunk:
                return moved
            # the trunk's axis may miss a head held off it (a body leaning sideways) and find the
            # shoulders: the points decide between the torso slid down and where it was, unless
            # the head where it was leans forward or back beyond the neck's flexion (onto the face
            # or the back of the skull: the torso sits too high, a body seen from its side)
            stay = _place_body(points, scorer_base, centre, R, body, params, dirs, anchor=False)
            sample = points[::max(1, len(points) // params.match_explain_points)]
            return max((stay, moved), key=lambda p: (head_in_range(p.sections, params.match_head_max_lean),
                                                     explained_fraction(sample, p.sections, params.match_explain_distance)))
    total += sh * Lh
    scorer.claim(secs["head"])
    # limb roots in the chest (arms) and waist (legs) frames; legs first: hanging hands reach
    # down beside the thighs, and a leg's volume is larger and unambiguous
    for prox, dist, root_name, _, _ in LIMBS[2:] + LIMBS[:2]:
        off = body.root_offset(root_name)
        if root_name.startswith("shoulder"):
            base = chest.frame.T  # columns x, y, axis of the chest
            root = cj + base @ (off - np.array([0, 0, body.length("chest")]))
        else:
            root = pelvis + R @ off
        outward = ex if root_name.endswith("_l") else -ex
        d1, d2, s = _search_chain(scorer, root, body, prox, dist, params, dirs, outward, R)
        p, q, sc_pq = _chain_columns(scorer, root, d1, d2, prox, dist, body)
        if sc_pq[0] < params.match_min_section_score and scorer.vol.size <= params.match_shell_voxel:
            # the limb's root section in empty voxels: a limb seen from one side only (a seated
            # person's thighs, seen from above) holds no inside voxels; search the chain again on
            # its seen surface (a distal section alone in empty voxels is listed, as before)
            e1, e2, _ = _search_chain(scorer, root, body, prox, dist, params, dirs, outward, R, shell=True)
            p2, q2, sc2 = _chain_columns(scorer, root, e1, e2, prox, dist, body)
            new, old = _chain_shell(scorer, root, p2, q2), _chain_shell(scorer, root, p, q)
            # kept only when it places the sections the volume could not (a weak shell placement
            # would change the whole match for nothing: those sections are listed anyway);
            # otherwise the volume's placement is judged on its seen surface too
            shell_scores[prox], shell_scores[dist] = old
            if sum(new) > sum(old) and all(b >= params.match_min_shell_score for a, b in zip(sc_pq, new)
                                           if a < params.match_min_section_score):
                p, q, sc_pq = p2, q2, sc2
                shell_scores[prox], shell_scores[dist] = new
        secs[prox], secs[dist] = p, q
        fit_scores[prox], fit_scores[dist] = sc_pq
        m = params.match_leg_claim_margin if kind_of(prox) == "thigh" else 0.0
        scorer.claim(p.replace(radii=p.radii + m))
        scorer.claim(q.replace(radii=q.radii + m))
        total += s
    return Pose(centre=centre, R=R, body=body, sections=secs, score=total, section_scores=fit_scores,
                shell_scores=shell_scores)


def _chain_columns(scorer, root, d1, d2, prox, dist, body):
    """The two columns of a limb chain from ``root`` along ``d1``, ``d2`` and how well each sits
    in the volume (mean weight, before claiming them)."""
    p = _column(prox, root, d1, body.section_length(prox), body.radii(kind_of(prox)), perp(d1))
    q = _column(dist, p.end, d2, body.section_length(dist), body.radii(kind_of(dist)), perp(d2))
    return p, q, tuple(float(_column_score(scorer, c.start, c.frame[None], c.length, c.radii, _LIMB_T)[0])
                       for c in (p, q))


def _chain_shell(scorer, root, p: SectionShape, q: SectionShape) -> tuple:
    """Shell scores (`_shell_score`) of a chain's two columns: (proximal, distal)."""
    a = _shell_score(scorer, p.start, p.frame[None], p.length, p.radii)[0]
    b = _shell_score(scorer, q.start, q.frame[None], q.length, q.radii,
                     avoid=(root, p.axis, p.length, p.radii[0]))[0]
    return float(a), float(b)


def explained_fraction(points, sections: dict, near: float) -> float:
    """Fraction of ``points`` (n, 3) within ``near`` metres of the surface of any of ``sections``."""
    D = np.min([s.distance(points) for s in sections.values()], axis=0)
    return float(np.mean(D < near))


def head_in_range(secs: dict, max_lean: float) -> bool:
    """Whether the head of the placed sections ``secs`` leans at most ``max_lean`` degrees from its
    chest's axis towards the chest's front or back (flexion or extension of the neck; sideways the
    head's search has its own limit, `match_head_max_side`).

    The volume pins the torso poorly along its own axis; a torso matched too high leaves its head
    column to lean onto the face or the back of the skull, which it explains as well as an upright
    one (bodies seen from their sides): silent nonsense fits."""
    _, front, axis = secs["chest"].frame
    d = secs["head"].axis
    return bool(np.degrees(np.arctan2(abs(d @ front), d @ axis)) <= max_lean)


def _crown_shift(points, head: SectionShape) -> float | None:
    """How far the detected crown lies beyond the head section's end along its axis, metres (None:
    too few points on the head's axis)."""
    rel = points - head.start
    h = rel @ head.axis
    rho = np.linalg.norm(rel - np.outer(h, head.axis), axis=1)
    near = (rho < 0.6 * head.radii.min()) & (h > 0.5 * head.length) & (h < 1.8 * head.length)
    if near.sum() < 10:
        return None
    return float(np.quantile(h[near], 0.995) - head.length)


def _crown_on_trunk(points, chest: SectionShape, head_len: float, head_radius: float) -> float | None:
    """How far the crown, sought on the trunk's axis (the chest's, continued above the neck), lies
    beyond a head length above the neck, metres (None: fewer than 10 points there).

    The head sits on the trunk: when the head's column, searched from a neck placed too high, finds
    no points on its own axis (it leans into the air or onto a raised arm), the top of the points
    within one head radius of the trunk's axis, from half a head length below the neck to 1.8
    above, is the crown (a seated body's upright torso matched 19 cm high, a child's with raised
    arms 10 cm high: their heads leaned 50 degrees onto nothing). One head radius, not the 0.6 of
    `_crown_shift`: a head is carried a little forward of the trunk's axis (the seated body's
    nearest points lay 4.3 cm off it). `_place_body` slides the torso only down to it (a torso matched too low keeps
    its head in the head's points, whose axis finds the crown) and keeps the slid placement only
    when it explains more points: beside a head held off the trunk's axis (a body leaning
    sideways, 20 mm scan) the axis finds the shoulders."""
    rel = points - chest.end
    h = rel @ chest.axis
    rho2 = np.einsum("ij,ij->i", rel, rel) - h * h
    near = (rho2 < head_radius ** 2) & (h > -0.5 * head_len) & (h < 1.8 * head_len)
    if near.sum() < 10:
        return None
    return float(np.quantile(h[near], 0.995) - head_len)


def _chain_extent(points, pose: Pose, dist: str) -> float | None:
    """Measured root-to-free-end length of the limb chain ending in ``dist``, or None."""
    q = pose.sections[dist]
    p = pose.sections[{s[1]: s[0] for s in LIMBS}[dist]]
    rel = points - q.start
    h = rel @ q.axis
    rho = np.linalg.norm(rel - np.outer(h, q.axis), axis=1)
    near = (rho < 1.5 * q.radii.max() + 0.02) & (h > 0) & (h < 2.0 * q.length)
    if near.sum() < 10:
        return None
    tip = np.quantile(h[near], 0.995)
    return p.length + tip


def _crotch_to_sole(pose: Pose, dist: str, ratio: float, crotch: np.ndarray) -> float:
    """A leg chain's length from the crotch seen in the points (not from the matched hip) to its
    free end, over the model's crotch height ``(1 - CROWN_CROTCH)`` statures; ``ratio`` is the
    chain's `_chain_extent` over the model's. Measured from the crotch like the trunk (crown to
    crotch), it compares with it whatever the model's size: from the hips of a model too tall
    (a child matched at 1.5 m), which sit too low, a whole leg measures short."""
    body = pose.body
    p = pose.sections[{s[1]: s[0] for s in LIMBS}[dist]]
    length = ratio * body.limb_lengths(dist) + float((p.start - crotch) @ p.axis)
    return length / ((1.0 - CROWN_CROTCH) * body.stature)


def _roll_from_legs(points, centre, R, body: StandardBody) -> np.ndarray:
    """Turn the torso frame about its axis so that its x axis runs from one thigh to the other.

    Just below the torso (either end: up is not known yet) the cloud splits into two legs; their
    2-means centres give the left-right direction. Unchanged when no end shows two separate blobs.
    """
    ez = R[:, 2]
    rel = points - centre
    h = rel @ ez
    lat = rel - np.outer(h, ez)
    half = 0.5 * torso_len(body)
    best = None
    for sgn in (-1.0, 1.0):
        hh = sgn * h - half
        sel = (hh > 0.02 * body.scale) & (hh < 0.12 * body.scale) & (np.linalg.norm(lat, axis=1) < 0.3)
        q = lat[sel]
        if len(q) < 40:
            continue
        # 2-means in the plane, started along the current x axis and its perpendicular
        seps = []
        for init in (R[:, 0], R[:, 1]):
            lab = q @ init > np.median(q @ init)
            for _ in range(8):
                if lab.all() or not lab.any():
                    break
                a, b = q[lab].mean(0), q[~lab].mean(0)
                lab = np.linalg.norm(q - a, axis=1) < np.linalg.norm(q - b, axis=1)
            if lab.all() or not lab.any():
                continue
            a, b = q[lab].mean(0), q[~lab].mean(0)
            spread = np.sqrt(np.mean(np.minimum(np.linalg.norm(q - a, axis=1), np.linalg.norm(q - b, axis=1)) ** 2))
            seps.append((np.linalg.norm(a - b) / max(spread, 1e-3), a - b))
        if seps:
            ratio, d = max(seps, key=lambda t: t[0])
            if ratio > 1.5 and (best is None or ratio > best[0]):
                best = (ratio, d)
    if best is None:
        return R
    x = best[1] - ez * (best[1] @ ez)
    x = x / np.linalg.norm(x)
    if x @ R[:, 0] < 0:
        x = -x
    return np.column_stack([x, cross(ez, x), ez])


def _thick_core(vol: Volume) -> np.ndarray:
    """Centre (3,) of the thickest part of the volume (voxels deepest inside it): the torso."""
    from scipy import ndimage

    solid = vol.contour | vol.inside
    depth = ndimage.distance_transform_edt(solid)
    core = depth >= 0.6 * depth.max()
    return vol.centres(core).mean(axis=0)


def _torso_choice(cands: list, params: FitParams) -> list:
    """The best `match_torso_candidates` torso poses, and the best upright one (within
    `match_upright_start` degrees of +z) if they hold none."""
    out = list(cands[:params.match_torso_candidates])
    cos_up = np.cos(np.radians(params.match_upright_start))
    if all(abs(R[2, 2]) < cos_up for _, _, R in out):
        out += [t for t in cands if abs(t[2][2, 2]) >= cos_up][:1]
    return out


def waist_wider_than_deep(waist: SectionShape) -> bool:
    """Whether the ``waist``, its radii measured on the points, is wider (frame x) than deep (y): a
    waist is (ANSUR II: 0.31 x 0.22 m; the library's fits 1.3-1.7 x). A torso roll taken from the
    legs that makes it deeper than wide took legs split front-back (a walker's stride) for legs apart
    sideways."""
    r = waist.radii
    return bool(r[0] >= r[1])


def upright_restart(pose: Pose, placed: list, upright_deg: float):
    """The match to start again from, beside ``pose``, when the body is resized: the best (most points
    explained) of ``placed`` whose torso is within ``upright_deg`` of +z, when ``pose``'s torso is
    tilted beyond it (None otherwise). The size was measured along the tilted torso's axis (short:
    the body leaves that axis), and at that wrong size the upright torso lost; people are scanned
    mostly upright, so the upright one is matched again at the new size too and the points decide."""
    cos_up = np.cos(np.radians(upright_deg))
    up = [p for p in placed if abs(p.R[2, 2]) >= cos_up]
    if abs(pose.R[2, 2]) >= cos_up or not up:
        return None
    return max(up, key=lambda p: p.explained)


def coarse_match(points, scorer, params: FitParams, feet: bool = False) -> list:
    """Volume matching (paper 2.3(1)-(2)), with the body size re-estimated between rounds.

    Of the torso candidates, each placed with all its sections, the one whose model explains most
    points (`match_explain_distance`) wins; when the legs size the body but crown to sole says
    another size, it is matched at both and the same count decides (`match_size_both`). Returns the
    best pose; for a child sized by its legs while crown to sole differs by more than
    `match_size_disagree`, its match at the crown-to-sole size (before the best pose when it explains
    more points by `match_crown_first_margin`: a short adult's legs); then up to `match_alternatives`
    poses of other torso candidates (turned by more than `match_alt_min_turn` degrees or moved),
    best first.

    ``feet``: the scan shows feet (`recon.posture.fit.feet_forward`: soles reaching in front of
    their ankles), so its legs are whole, however short their chains measure against the trunk
    (`size_ratios`' ``min_leg`` is not applied): a body matched at a wrong first size (a short heavy
    body, 1.27 m, at 1.5 m) can measure its whole legs as short of its trunk as legs cut from a scan."""
    centroid = _thick_core(scorer.vol)
    stature = params.fit_stature if params.fit_stature > 0 else None
    body = standard_body(stature or 1.75)
    dirs = fibonacci_sphere(params.match_directions)
    starts = None
    hang = None
    regained = False   # the best upright torso was brought back after a tilted one set the size
    cos_up = np.cos(np.radians(params.match_upright_start))
    pose = None
    alternatives = []
    rng = np.random.default_rng(params.fit_seed)
    sample = points if len(points) <= params.match_explain_points else \
        points[rng.choice(len(points), params.match_explain_points, replace=False)]

    def match_at(body, cands, hang):
        # every torso candidate placed whole at this size; the one explaining most points wins
        trials = []
        placed = []
        eligible = []
        for sc, c, R in _torso_choice(cands, params):
            trials.append((sc, c, R, False))
            R2 = _roll_from_legs(points, c, R, body)
            if abs(R2[:, 0] @ R[:, 0]) < np.cos(np.radians(20)):
                trials.append((sc, c, R2, True))   # the legs suggest another roll: let the match decide
        for sc, c, R, legs in trials:
            # the scanner's +z is up: trust it unless the torso lies nearly horizontal
            flips = (False,) if R[2, 2] > 0.5 else (True,) if R[2, 2] < -0.5 else (False, True)
            for flip in flips:
                RR = R @ np.diag([1.0, -1.0, -1.0]) if flip else R
                p = _place_body(points, scorer, c, RR, body, params, dirs, min_shift=hang)
                p.score += sc * torso_len(body)
                p.explained = explained_fraction(sample, p.sections, params.match_explain_distance)
                placed.append(p)
                if regained and abs(p.R[2, 2]) >= cos_up and _crown_shift(points, p.sections["head"]) is None:
                    continue   # an upright torso brought back must hang from a crown the points show
                if legs and params.match_legs_roll_wide and not waist_wider_than_deep(p.sections["waist"]):
                    continue   # the legs' roll gave a waist deeper than wide: they were split front-back
                eligible.append(p)
        best = max(eligible or placed, key=lambda p: p.explained)
        return best, [p for p in (eligible or placed) if p is not best], placed

    extra = []   # (body, hang): further sizes to match in the next round
    backup = None   # a size matched in the next round as the first alternative (a child's crown to sole)
    second = None   # its match
    cut = set()  # lower legs whose chain measured far shorter than the trunk (`size_ratios`)
    last = max(1, params.match_rounds) - 1   # the last round
    for rnd in range(max(1, params.match_rounds) + 1):
        cands = _match_torso(scorer, centroid, body, params, starts)
        if rnd == 0 and stature is None:
            # first size estimate: the body's extent along the torso axis near that axis
            c, R = cands[0][1], cands[0][2]
            rel = points - c
            h = rel @ R[:, 2]
            near = np.linalg.norm(rel - np.outer(h, R[:, 2]), axis=1) < 0.3
            if near.sum() > 50:
                ext = float(np.quantile(h[near], 0.999) - np.quantile(h[near], 0.001))
                if abs(R[2, 2]) > 0.8:
                    # too short for its torso: seated, squatting or kneeling; the limbs tell later.
                    # Every candidate is matched again at this size: on a coarse volume (sparse
                    # scan, 40 mm voxels) the torso's own score hardly tells an upright torso from
                    # one tilted onto an arm; the whole-body match below does
                    body = standard_body(float(np.clip(ext, params.match_min_first_stature, STATURE_RANGE[1])))
                    cands = _match_torso(scorer, centroid, body, params,
                                         [(cc, RR) for _, cc, RR in _torso_choice(cands, params)], step=0.4)
        best, others, placed = match_at(body, cands, hang)
        for other, other_hang in extra:
            # the other size (legs and crown to sole disagreed): the points decide; its torso searched
            # afresh (the previous match's torso, whose hips gave the legs' length, is the one in doubt)
            b2, o2, p2 = match_at(other, _match_torso(scorer, centroid, other, params), other_hang)
            if b2.explained > best.explained:
                best, b2, others, o2, placed = b2, best, o2, others, p2
            alternatives += [b2] + o2
        if backup is not None:
            # from the same starts, hung from the crown as a body sized from it is
            second = match_at(backup, _match_torso(scorer, centroid, backup, params, starts),
                              params.match_resized_anchor_shift)[0]
            backup = None
        alternatives += others
        if pose is not None and best.body.stature > pose.body.stature and best.explained < pose.explained:
            # matched again larger, the model explains fewer points (a larger model explains more
            # when it is right): the size came from a wrong pose; keep the first
            alternatives.append(best)
            break
        if pose is not None:
            alternatives.append(pose)
        pose = best
        if stature is not None or rnd >= last:
            break
        ratios = size_ratios(points, pose, 0.0 if feet else params.match_leg_trunk_min)
        cut |= set(ratios.get("cut", ()))
        if len(cut) == 2 and "trunk" in ratios:
            # legs judged cut stay cut: matched again, a lower leg may reach across to the other
            # leg's points and measure whole (walking without lower legs: 1.01 and 0.65 of the trunk)
            ratios = {"trunk": ratios["trunk"], "cut": sorted(cut)}
        # whole body first (crown to sole: where the torso sits along its axis cancels out), then
        # the legs, then any limb (a hand resting on a thigh makes an arm look far too long)
        crown = ratios.get("body") or []
        # adult proportions: crown to sole; a child's large head and short legs: the legs
        legs = [v for k, v in ratios.items() if k.startswith("lower_leg")]
        adult = bool(crown) and body.stature * np.median(crown) >= params.fit_anchor_min_stature
        use = crown if adult and (params.match_size_from_crown or (
            legs and abs(np.median(legs) - np.median(crown)) > params.match_size_disagree)) else []
        use = use or legs
        if not use and ratios.get("cut"):
            # both legs cut short (`size_ratios`): the trunk sizes the body, and is measured again on
            # the next match (one round more): crown and crotch come from the head and thighs the
            # match placed, which a first-guess size places less well (t_pose without lower legs:
            # 1.50 m -> 1.60 m -> 1.77 m, true 1.76)
            use = [ratios["trunk"]]
            last = max(last, min(rnd + 2, max(1, params.match_rounds)))
        elif not use or (len(use) < 2 and "body" not in ratios):
            use = [v for k, v in ratios.items() if k not in ("body", "trunk", "cut")]
        s = float(np.median(use))
        if abs(s - 1.0) < params.match_resize_tolerance:
            break
        body = standard_body(float(np.clip(body.stature * s, *STATURE_RANGE)))
        second = None
        if not adult and use is legs and crown and \
                abs(np.median(legs) - np.median(crown)) > params.match_size_disagree:
            # a child's legs are short for its stature, and measured from the hips of a model matched
            # at the wrong size (the first, 1.5 m) they can size it far too small: its trunk and head
            # then do not fit. Crown to sole, which depends on neither, is matched too and is the
            # next pose tried when the legs' size fails the checks (before the first size's)
            backup = standard_body(float(np.clip(pose.body.stature * np.median(crown), *STATURE_RANGE)))
        starts = [(pose.centre, pose.R)]
        u = upright_restart(pose, placed, params.match_upright_start) if params.match_resize_upright else None
        if u is not None:
            starts.append((u.centre, u.R))
            regained = True
        # sized from the crown because the legs, measured from the matched hips, disagreed: the torso
        # was misplaced along its axis; the next match hangs it from the crown wherever it is
        hang = params.match_resized_anchor_shift if use is crown and not params.match_size_from_crown else None
        # sized from the legs while crown to sole says another size (by more than the resize
        # tolerance, less than `match_size_disagree`): the hips may sit off along the torso's axis (a
        # tall walker's matched 8 cm high: legs 2.18 m, crown to sole 2.02, true 1.97); the body is
        # matched at both sizes and the one whose model explains more points is kept
        # (`match_size_both`). Both sizes adult: a child's large head and short legs make the two
        # disagree by nature, and the larger model then explains more points (a child at 20 mm:
        # legs 1.41 m, crown to sole 1.53 m won, a lower leg listed though seen)
        extra = []
        if params.match_size_both and adult and use is legs and \
                abs(np.median(legs) - np.median(crown)) > params.match_resize_tolerance and \
                pose.body.stature * np.median(legs) >= params.fit_anchor_min_stature:
            other = standard_body(float(np.clip(pose.body.stature * np.median(crown), *STATURE_RANGE)))
            extra = [(other, params.match_resized_anchor_shift)]
    # other torso poses, best first, for when the best one's fine fit fails its checks
    alts, seen = [], [pose]
    for p in sorted(alternatives, key=lambda p: -p.explained):
        if all(p.R[:, 2] @ q.R[:, 2] < np.cos(np.radians(params.match_alt_min_turn))
               or np.linalg.norm(p.centre - q.centre) > 0.5 * params.match_min_anchor_shift for q in seen):
            seen.append(p)
            alts.append(p)
    sizes = [pose] + ([second] if second is not None else [])
    if second is not None and params.match_size_both and \
            second.explained > pose.explained + params.match_crown_first_margin:
        # the points decide between the two sizes, as for adults (`match_size_both`), by a margin (a
        # child's larger model explains more by nature): a short adult's legs are short for its
        # trunk and size it far too small (1.29 m sized 1.10 m from its legs explained 0.60 of the
        # points, crown to sole 0.89)
        sizes = sizes[::-1]
    out = sizes + alts[:max(0, params.match_alternatives)]
    for p in out:
        # a leg chain far shorter than its trunk ends where the scan does: its lower leg is not in
        # it, and wherever the match put one (across to the other leg's stump) it lies on other
        # points; it is listed unfitted unless its fitted surface is seen (the checks of
        # `recon.posture`: volume score below `match_min_section_score`)
        p.section_scores = {k: (min(v, -1.0) if k in cut else v) for k, v in (p.section_scores or {}).items()}
    return out


def size_ratios(points, pose: Pose, min_leg: float = 0.0) -> dict:
    """Measured / model lengths: per limb chain (root to free end), and ``body``: the list of crown
    to sole ratios over both legs (hip to crown along the head, plus the leg), which do not depend
    on where the coarse match put the torso along its axis.

    Crown to sole is measured over the model's chain: the crown along the head's axis from the
    model's neck, the sole along the shin's axis from the model's knee. On a straight chain the
    model's own lengths cancel out; where the chain bends by an angle a, the segment before the
    bend (length l: the thigh before the knee, the trunk before the head) places the next one, and
    l (1 - cos a) of it is not measured (moving the knee by d along a thigh moves the sole along the
    shin by d cos a). That part U is taken out of both the measured length T and the model's S:
    ratio = (T - U) / (S - U) (a seated body, knees at 90 degrees: 1.67 -> 1.76 m from a 1.50 m
    match, true 1.77 m). Points nearer a placed forearm than the head are not the crown (a hand
    held over the head).

    Parameters
    ----------
    points : (n, 3) float, metres
    pose : Pose
        The coarse match.

    Returns
    -------
    ratios : dict
        ``lower_leg_l`` ... ``forearm_r``: float, measured / model chain length; ``body``: list of
        float, crown to sole / model stature, one per measured leg.
    """
    body = pose.body
    ratios = {}
    for prox, dist, *_ in LIMBS:
        e = _chain_extent(points, pose, dist)
        if e is not None:
            ratios[dist] = e / body.limb_lengths(dist)
    head = pose.sections["head"]
    rel = points - head.start
    h = rel @ head.axis
    rho = np.linalg.norm(rel - np.outer(h, head.axis), axis=1)
    near = (rho < 1.5 * head.radii.max() + 0.02) & (h > 0) & (h < 2.0 * head.length)
    hands = [pose.sections[k] for k in ("forearm_l", "forearm_r") if k in pose.sections]
    if hands and near.any():
        # a hand held over the head is not the crown: points nearer a forearm than the head
        idx = np.flatnonzero(near)
        d_hand = np.min([s.distance(points[idx]) for s in hands], axis=0)
        near[idx[d_hand < head.distance(points[idx])]] = False
    if near.sum() >= 10:
        crotch = find_crotch(points, pose.sections)
        if crotch is not None:
            crown = head.start + head.axis * float(np.quantile(h[near], 0.995))
            ratios["trunk"] = float(np.linalg.norm(crown - crotch)) / (CROWN_CROTCH * body.stature)
            # leg chains far shorter than their trunk, both of them, are not whole legs: the scan
            # ends above the feet (legs cut from it, or out of the scanner's view); neither they nor
            # crown to sole through them size the body. One short chain alone is more often a leg
            # the match placed badly (a child's at 20 mm, k = 2: 0.78 of its trunk, the other 0.84)
            legs = [d for d in ("lower_leg_l", "lower_leg_r") if d in ratios]
            # measured from the matched hips and from the crotch, a cut leg is short either way; a
            # whole leg is long at least one way (a child matched too tall: its hips sit low; a
            # stride: the crotch found low on a thigh)
            short = [d for d in legs if max(ratios[d], _crotch_to_sole(pose, d, ratios[d], crotch))
                     < min_leg * ratios["trunk"]]
            cut = short if len(short) == 2 else []
            for d in cut:
                del ratios[d]
            if cut:
                ratios["cut"] = cut
        hips = pose.centre - 0.5 * torso_len(body) * pose.R[:, 2] + pose.R @ np.array([0, 0, body.length("hip_z")])
        up = np.linalg.norm(head.start - hips) + np.quantile(h[near], 0.995)
        up_model = body.length("neck") + body.section_length("head") - body.length("hip_z")
        tor = head.start - hips
        u_head = np.linalg.norm(tor) * (1.0 - max(0.0, float(head.axis @ unit(tor))))
        out = []
        for prox, dist in (("thigh_l", "lower_leg_l"), ("thigh_r", "lower_leg_r")):
            if dist not in ratios:
                continue
            p, q = pose.sections[prox], pose.sections[dist]
            T = up + ratios[dist] * body.limb_lengths(dist)
            S = up_model + body.limb_lengths(dist)
            U = u_head + p.length * (1.0 - max(0.0, float(p.axis @ q.axis)))
            out.append((T - U) / (S - U))
        if out:
            ratios["body"] = out
    return ratios
