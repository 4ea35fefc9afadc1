"""Fine adjustment on the points (paper 2.3(2), step 5 of `recon.posture`).

`fit_section` fits one section (axis, radii, free end) by least squares on the point-to-surface
distances; `fine_adjust` does it for every section of a coarse pose and rejoins them at their
joints; `anchor_on_head_top` slides the torso so that the head hangs from the detected crown.
"""

from __future__ import annotations

import numpy as np

from .bodymodel import LIMBS, StandardBody, kind_of
from ..geometry import cross, fibonacci_sphere, perp, turn_between, unit
from .joints import ELBOW_STRAIGHT_DEG as _ELBOW_STRAIGHT_DEG
from .joints import neck_sides
from .match import Pose
from ..model import SectionShape
from ..params import FitParams


def _assign(points, sections: dict, near: float):
    """Index of the nearest section surface per point (-1: none within ``near``), and distances."""
    names = list(sections)
    D = np.stack([sections[n].distance(points) for n in names], axis=1)
    k = np.argmin(D, axis=1)
    d = D[np.arange(len(points)), k]
    k[d > near] = -1
    return names, k


def fit_section(points: np.ndarray, shape: SectionShape, *, loss: str = "soft_l1",
                iterations: int = 3, end_threshold: float = 0.6, free_end: bool = True,
                fit_radii: bool = True, max_shift: float = np.inf,
                max_turn: float = np.inf) -> tuple[SectionShape, float]:
    """Fit one section's axis, radii and free end to points on its surface (paper 2.3(2)).

    Least squares on the point-to-surface distances over the axis position (2 offsets across the
    axis), direction (2 angles) and, for an elliptic column, roll (analytic Jacobian, `_PoseModel`); then radius = mean distance of the
    column's points from the axis (per principal direction for an elliptic column); repeated
    ``iterations`` times. When ``free_end``, the end cap is placed at the farthest point nearer the
    axis than ``end_threshold`` times the radius (the paper's rule); with no such point, on the
    points of the cap's flanks (within `FLANK` of the axis in units of the cross-section's ellipse,
    within the cap's height of the section's farthest point), on the model's own cap: a crown seen
    only from below, by perspective heads, shows no point near its axis; with neither the end is
    open and the length is kept.

    Parameters
    ----------
    points : (n, 3) float, metres
        Points of this section only.
    shape : SectionShape
        Starting shape (its ``start`` stays the reference point along the axis).
    loss : str
        `scipy.optimize.least_squares` loss.
    max_shift, max_turn : float
        Bounds on each iteration's move of the axis across itself (metres) and turn (radians).

    Returns
    -------
    shape : SectionShape
    rms : float
        RMS distance of the points to the fitted surface, metres.
    """
    from scipy.optimize import least_squares

    points = np.asarray(points, dtype=np.float64)
    cur = shape
    elliptic = not cur.is_cylinder
    scale = max(0.005, 0.1 * float(cur.radii.mean()))
    for _ in range(max(1, iterations)):
        base = cur
        model = _PoseModel(points, base, elliptic)
        x0 = np.zeros(5 if elliptic else 4)
        lim = np.array([max_shift, max_shift, max_turn, max_turn, max_turn])[:len(x0)]
        res = least_squares(model.resid, x0, jac=model.jac, loss=loss, f_scale=scale, x_scale=0.05,
                            max_nfev=40, bounds=(-lim, lim))
        cur = model.make(res.x)
        if fit_radii:
            cur = _refit_radii(points, cur)
    if free_end:
        cur = _find_end(points, cur, end_threshold)
    rms = float(np.sqrt(np.mean(cur.coords(points)[0] ** 2))) if len(points) else np.nan
    return cur, rms


class _PoseModel:
    """The point-to-surface distances of one section moved by ``x`` = (2 offsets across the axis
    along ``frame_x`` and ``frame_y``, 2 turn angles of the axis, roll about it for an elliptic
    column) from ``base``, and their analytic Jacobian (the numerical one cost `fit_section` about
    half its time). The distance is `SectionShape.coords`' r."""

    def __init__(self, points, base: SectionShape, elliptic: bool):
        self.points, self.base, self.elliptic = points, base, elliptic
        self.fr = base.frame
        self.u0 = perp(base.axis)
        self.w0 = cross(base.axis, self.u0)
        self.a, self.b = base.radii
        self.L = base.length
        self._x = None

    def _pose(self, x):
        """start, d, fx (3,) and their derivatives (k, 3) by x."""
        k = len(x)
        fr, ax = self.fr, self.base.axis
        t = float(np.hypot(x[2], x[3]))
        if t < 1e-4:
            g, q = 1.0 - t * t / 6, -1.0 / 3 + t * t / 30     # sin t / t, (t cos t - sin t) / t^3
        else:
            g, q = np.sin(t) / t, (t * np.cos(t) - np.sin(t)) / t ** 3
        v = self.u0 * x[2] + self.w0 * x[3]
        draw = ax * np.cos(t) + v * g
        nd = np.linalg.norm(draw)
        d = draw / nd
        dd = np.zeros((k, 3))
        dd[2] = -ax * g * x[2] + self.u0 * g + v * q * x[2]
        dd[3] = -ax * g * x[3] + self.w0 * g + v * q * x[3]
        dd = (dd - np.outer(dd @ d, d)) / nd
        start = self.base.start + x[0] * fr[0] + x[1] * fr[1]
        dstart = np.zeros((k, 3))
        dstart[0], dstart[1] = fr[0], fr[1]
        gx = fr[0] - d * (fr[0] @ d)
        ng = np.linalg.norm(gx)
        fx = gx / ng
        dg = -dd * (fr[0] @ d) - np.outer(dd @ fr[0], d)
        dfx = (dg - np.outer(dg @ fx, fx)) / ng
        if self.elliptic:
            c4, s4 = np.cos(x[4]), np.sin(x[4])
            side = cross(d, fx)
            dside = cross(dd, fx) + cross(d, dfx)
            dfx = dfx * c4 + dside * s4
            dfx[4] = -fx * s4 + side * c4
            fx = fx * c4 + side * s4
        return start, d, fx, dstart, dd, dfx

    def make(self, x) -> SectionShape:
        start, d, fx, *_ = self._pose(x)
        return self.base.replace(start=start, end=start + self.L * d, frame_x=fx)

    def _eval(self, x):
        if self._x is not None and np.array_equal(x, self._x):
            return self._cache
        start, d, fx, dstart, dd, dfx = self._pose(x)
        fy = cross(d, fx)
        dfy = cross(dd, fx) + cross(d, dfx)
        a, b, L = self.a, self.b, self.L
        cap0, cap1 = self.base.caps
        c0, c1 = self.base.closed
        rel = self.points - start
        X, Y, h = rel @ fx, rel @ fy, rel @ d
        below, above = (h < 0) & c0, (h > L) & c1
        e = np.where(below, h, np.where(above, h - L, 0.0))
        c = np.where(h < 0, cap0, cap1)
        q = np.sqrt((X / a) ** 2 + (Y / b) ** 2 + (e / c) ** 2)
        n = np.sqrt(X ** 2 + Y ** 2 + e ** 2)
        ok = q > 0
        qs, ns = np.maximum(q, 1e-12), np.maximum(n, 1e-12)
        r = np.where(ok, n * (1.0 - 1.0 / qs), -min(a, b))
        # dr/dX = X ((1 - 1/q) / n + n / (a^2 q^3)), likewise Y (b) and e (cap c); 0 on the axis
        f = np.where(ok, (1.0 - 1.0 / qs) / ns, 0.0)
        g = np.where(ok, n / qs ** 3, 0.0)
        rX, rY, re = X * (f + g / a ** 2), Y * (f + g / b ** 2), e * (f + g / c ** 2) * (below | above)
        J = (rX[:, None] * (rel @ dfx.T - dstart @ fx) + rY[:, None] * (rel @ dfy.T - dstart @ fy)
             + re[:, None] * (rel @ dd.T - dstart @ d))
        self._x, self._cache = np.array(x), (r, J)
        return r, J

    def resid(self, x):
        return self._eval(x)[0]

    def jac(self, x):
        return self._eval(x)[1]


def _refit_radii(points, s: SectionShape) -> SectionShape:
    q = s.local(points)
    col = (q[:, 2] >= 0) & (q[:, 2] <= s.length)
    if col.sum() < 8:
        return s
    rho = np.hypot(q[col, 0], q[col, 1])
    if s.is_cylinder:
        r = float(rho.mean())
        return s.replace(radii=np.array([r, r]), caps=s.caps * 0 + r)
    c2 = (q[col, 0] / np.maximum(rho, 1e-9)) ** 2
    A = np.column_stack([c2, 1 - c2])   # rho ~ a cos^2 + b sin^2 (first-order ellipse)
    try:
        (a, b), *_ = np.linalg.lstsq(A, rho, rcond=None)
    except np.linalg.LinAlgError:
        return s
    if not (a > 0.01 and b > 0.01) or max(a, b) > 3 * min(a, b):
        r = float(rho.mean())
        a = b = r
    return s.replace(radii=np.array([a, b]), caps=np.array([s.caps[0], min(a, b)]))


#: `_find_end`'s flank points lie within this of the axis in units of the cross-section's ellipse
#: (a column's own side lies at 1).
FLANK = 0.8


def _find_end(points, s: SectionShape, threshold: float) -> SectionShape:
    q = s.local(points)
    rho = np.hypot(q[:, 0], q[:, 1])
    upper = q[:, 2] > 0.5 * s.length
    near_axis = (rho < threshold * s.radii.mean()) & upper
    cap = float(s.radii.min())
    closed = list(s.closed)
    if near_axis.any():
        tip = float(q[near_axis, 2].max())
    else:
        # a cap seen only on its flanks (cameras below a crown): each flank point within the cap's
        # height of the section's highest point puts the tip where the model's cap (half an
        # ellipsoid, the column's semi-axes across, the cap's height along) reaches above it
        e = np.hypot(q[:, 0] / s.radii[0], q[:, 1] / s.radii[1])
        flank = (e < FLANK) & upper & (q[:, 2] > q[:, 2].max(initial=-np.inf) - cap)
        if not flank.any():
            closed[1] = False
            return s.replace(closed=tuple(closed))
        tip = float((q[flank, 2] + cap * (1.0 - np.sqrt(1.0 - e[flank] ** 2))).max())
    L = max(tip - cap, 0.3 * s.length)
    closed[1] = True
    return s.replace(end=s.start + L * s.axis, closed=tuple(closed), caps=np.array([s.caps[0], cap]))


def _closest_on_axes(a: SectionShape, b: SectionShape):
    """Midpoint of the shortest segment between the axis lines of a and b, and the sine of their angle."""
    d1, d2 = a.axis, b.axis
    w = a.start - b.start
    A, B, C = d1 @ d1, d1 @ d2, d2 @ d2
    D, E = d1 @ w, d2 @ w
    den = A * C - B * B
    sin = float(np.linalg.norm(cross(d1, d2)))
    if den < 1e-9:
        return None, sin
    t = (B * E - C * D) / den
    u = (A * E - B * D) / den
    return 0.5 * (a.start + t * d1 + b.start + u * d2), sin


def fine_adjust(points, pose: Pose, params: FitParams):
    """Fine adjustment of every section on the points; returns sections, residuals, free-end flags."""
    secs = dict(pose.sections)
    body = pose.body
    resid = {}
    counts = {}
    rng = np.random.default_rng(params.fit_seed)
    for it in range(max(1, params.fit_iterations)):
        names, k = _assign(points, secs, params.fit_near_distance)
        new = {}
        for j, name in enumerate(names):
            pts = points[k == j]
            counts[name] = len(pts)
            if len(pts) < params.fit_min_points:
                new[name] = secs[name]
                resid[name] = np.nan
                continue
            free = name in ("head", "forearm_l", "forearm_r", "lower_leg_l", "lower_leg_r")
            if len(pts) > params.fit_section_points:
                pts = pts[rng.choice(len(pts), params.fit_section_points, replace=False)]
            shp, rms = fit_section(pts, secs[name], loss=params.fit_loss, iterations=1,
                                   end_threshold=params.fit_end_threshold,
                                   free_end=free and it == params.fit_iterations - 1,
                                   max_shift=params.fit_max_shift,
                                   max_turn=np.radians(params.fit_max_turn) * (0.3 if name == "chest" else 1.0))
            new[name] = shp
            resid[name] = rms
        secs = _rejoin(new, secs, pose, body, points)
    return secs, resid, counts


def _rejoin(new: dict, old: dict, pose: Pose, body: StandardBody, points=None) -> dict:
    """Reconnect the independently adjusted sections at their joints; ``points`` (n, 3), when
    given, centre the neck between its sides (`_neck_shift`)."""
    out = {}
    w = new["waist"]
    # pelvis: keep it where the coarse match put it along the (adjusted) waist axis
    pelvis = w.start + w.axis * ((old["waist"].start - w.start) @ w.axis)
    Lw = old["waist"].length
    waist = w.replace(start=pelvis, end=pelvis + Lw * w.axis)
    out["waist"] = waist
    c = new["chest"]
    chest = c.replace(start=waist.end, end=waist.end + c.length * unit(c.end - waist.end + 1e-12 * c.axis))
    chest = _keep_dir(chest, c.axis, waist.end, old["chest"].length)
    # the chest's top end hangs under the head, which the points place well (the chest's own
    # direction is poorly fixed: the arms beside it); within 25 degrees of the waist's axis
    h = new["head"]
    target = h.start + h.axis * ((chest.end - h.start) @ h.axis)   # nearest point of the head's axis
    d = unit(target - waist.end)
    if d @ waist.axis > np.cos(np.radians(25)):
        chest = _keep_dir(chest, d, waist.end, old["chest"].length)
    head_dir = new["head"].axis
    shift = _neck_shift(points, chest, waist.axis, body) if points is not None else None
    if shift is not None:
        # the neck is left-right symmetric: its top end lies midway between the neck's sides
        d = unit(chest.end + shift - waist.end)
        if d @ waist.axis > np.cos(np.radians(25)):
            chest = _keep_dir(chest, d, waist.end, old["chest"].length)
            # the head keeps its top (the crown is measured) and hangs from the moved neck
            hd = unit(new["head"].end - chest.end)
            if hd @ head_dir > np.cos(np.radians(30)):
                head_dir = hd
    out["chest"] = chest
    out["head"] = _keep_dir(new["head"], head_dir, chest.end, new["head"].length)
    # the shoulders ride with the chest: the coarse shoulder joints turn with it from its coarse
    # direction to its final one (a coarse chest tilted sideways raises one shoulder and lowers
    # the other), then each is taken onto its adjusted upper arm's axis; likewise the hips ride with
    # the waist (the pelvis): moved and turned with it, then taken onto the thighs' axes (a squat
    # matched upright, 10 cm forward, kept its hips 10 cm forward on the level thighs while the
    # waist moved back onto its points: knee 11.3 -> 7.2 cm)
    turn = turn_between(old["chest"].axis, chest.axis)
    turn_w = turn_between(old["waist"].axis, waist.axis)
    roots = {}
    for prox, *_ in LIMBS:
        r0 = old[prox].start
        if prox.startswith("upper_arm"):
            r0 = chest.start + turn @ (r0 - old["chest"].start)
        else:
            r0 = waist.start + turn_w @ (r0 - old["waist"].start)
        roots[prox] = new[prox].start + new[prox].axis * ((r0 - new[prox].start) @ new[prox].axis)
    for prox, dist, root_name, _, _ in LIMBS:
        p, q = new[prox], new[dist]
        root = roots[prox]
        mid, sin = _closest_on_axes(p, q)
        if mid is None or sin < np.sin(np.radians(_ELBOW_STRAIGHT_DEG if root_name.startswith("shoulder") else 25)):
            # straight joint: keep the proximal length along the adjusted axis
            mid_len = old[prox].length
        else:
            mid_len = float(np.clip((mid - root) @ p.axis, 0.6 * old[prox].length, 1.4 * old[prox].length))
        joint = root + mid_len * p.axis
        out[prox] = p.replace(start=root, end=joint)
        out[dist] = _keep_dir(q, q.axis, joint, q.length)
    return out


def _neck_shift(points, chest: SectionShape, up: np.ndarray, body: StandardBody) -> np.ndarray | None:
    """(3,) move across the body that centres the chest's top end (the neck) between the sides of
    the neck, or None (fewer than 10 points there).

    The neck is left-right symmetric in any posture: its sides, in a slab 0.02-0.06 H above the
    chest's top end (above the trapezius, below the jaw and ears) within 0.08 H of it (clear of
    arms raised beside the head), lie at the same distance either side of it; their midpoint is
    taken between the 10th and 90th percentiles across the body (the sides are silhouettes, seen by
    front and back sensors alike). The chest's own sideways tilt is poorly fixed by its points
    (arms hang beside it): measured on `paper` scans of the library (k = 1, 3, turned), the neck's
    left-right error went 2.1 -> 0.6 cm mean (6.2 -> 2.5 cm largest). ``up`` is the waist's axis,
    across is the chest's wide axis (``frame_x``).
    """
    H = body.stature
    lat = unit(chest.frame_x - up * (chest.frame_x @ up))
    sides = neck_sides(points, chest.end, up, lat, (0.02 * H, 0.06 * H), 0.08 * H)
    return None if sides is None else 0.5 * (sides[0] + sides[1]) * lat


def anchor_on_head_top(secs: dict, body: StandardBody, params: FitParams) -> dict:
    """Slide the torso, head and legs along the torso axis (at most `fit_max_shift`) so that the
    neck lies the standard head length below the detected top of the head (the crown is the
    best-measured landmark along the spine); the neck (the chest's top end) and the head follow the
    crown up to `fit_anchor_max_shift` further up, the chest stretching; the arms stay on
    their points and only their shoulders follow (`_move_shoulders`); a leg section turned more than
    45 degrees from the torso axis slides along its own axis only."""
    h, w = secs["head"], secs["waist"]
    move, rest = np.zeros(3), np.zeros(3)
    # children's heads are relatively larger: the adult head length does not hold
    if h.closed[1] and body.stature >= params.fit_anchor_min_stature:
        top = h.end + h.caps[1] * h.axis
        neck = top - body.section_length("head") * h.axis
        want = float((neck - h.start) @ w.axis)
        shift = float(np.clip(want, -params.fit_max_shift, params.fit_max_shift))
        move = shift * w.axis
        # further only upwards: a crown found from points can fall short of the head's top (a sparse
        # or half-seen head), never beyond it
        rest = float(np.clip(want - shift, 0.0, params.fit_anchor_max_shift)) * w.axis
    out = {k: v.replace(start=v.start + move, end=v.end + move) for k, v in secs.items()
           if k not in _ARM_SECTIONS}
    for k in ("thigh_l", "thigh_r", "lower_leg_l", "lower_leg_r"):
        # the legs were placed on their points: one turned more than 45 degrees from the torso axis
        # slides along its own axis only (a thigh held level, seated or raised, moved across
        # itself, would leave its points)
        if k in secs and abs(secs[k].axis @ w.axis) < np.cos(np.radians(45.0)):
            v = secs[k]
            m = v.axis * (move @ v.axis)
            out[k] = v.replace(start=v.start + m, end=v.end + m)
    if np.any(rest):
        out["chest"] = out["chest"].replace(end=out["chest"].end + rest)
        out["head"] = out["head"].replace(start=out["head"].start + rest, end=out["head"].end + rest)
    return _move_shoulders(out, secs, body, move)


#: The arm chains' sections.
_ARM_SECTIONS = frozenset(n for prox, dist, root, *_ in LIMBS if root.startswith("shoulder") for n in (prox, dist))


#: The shoulder joint rises with the arm raised above the horizontal (the clavicle elevates with
#: the scapula, scapulohumeral rhythm): by this fraction of stature times the upper arm's cosine
#: with the chest's axis. The rig's shoulder joints lie 0.025 H higher with the arms raised 157-161
#: degrees from hanging (arms_raised, child_arms_raised) than hanging or held out level (t_pose).
_SHOULDER_RISE = 0.027


def _move_shoulders(out: dict, secs: dict, body: StandardBody, move: np.ndarray) -> dict:
    """Add the arm sections of ``secs`` to ``out`` (the torso already moved by ``move`` (3,)) with
    their shoulders following the torso and rising with a raised arm (`_SHOULDER_RISE`).

    The arms were fitted on their own points: they stay there, and each shoulder moves along its
    upper arm's axis only; a bent elbow stays where the two axes meet; a straight elbow keeps the
    upper arm's length from the shoulder, and the forearm keeps its far end (the fingertips).
    """
    up = out["chest"].axis if "chest" in out else secs["waist"].axis
    for prox, dist, root, *_ in LIMBS:
        if not root.startswith("shoulder"):
            continue
        if prox not in secs or dist not in secs:   # an incomplete chain stays where it is
            out.update({n: secs[n] for n in (prox, dist) if n in secs})
            continue
        p, q = secs[prox], secs[dist]
        rise = _SHOULDER_RISE * body.stature * max(0.0, float(p.axis @ up))
        s = float((move + rise * up) @ p.axis)
        if np.linalg.norm(cross(p.axis, q.axis)) < np.sin(np.radians(_ELBOW_STRAIGHT_DEG)):
            out[prox] = p.replace(start=p.start + s * p.axis, end=p.end + s * p.axis)
            out[dist] = q.replace(start=out[prox].end) if s * (p.axis @ q.axis) < q.length - 0.05 else q
        else:
            out[prox] = p.replace(start=p.start + s * p.axis)
            out[dist] = q
    return out


def _keep_dir(s: SectionShape, d, start, length) -> SectionShape:
    return s.replace(start=start, end=start + length * unit(d))


def section_cover(points, secs: dict, near: float, n_theta: int = 12, n_h: int = 6) -> dict:
    """Per section, the fraction of its column's (theta, h) cells holding points near its surface
    (within ``near`` metres), counting only points for which this section's surface is the nearest."""
    names = list(secs)
    D = np.stack([secs[n].distance(points) for n in names], axis=1)
    k = np.argmin(D, axis=1)
    out = {}
    for j, n in enumerate(names):
        sel = (k == j) & (D[:, j] < near)
        r, th, h = secs[n].coords(points[sel])
        col = (h >= 0) & (h <= secs[n].length)
        ti = np.minimum((th[col] / (2 * np.pi) * n_theta).astype(int), n_theta - 1)
        hi = np.minimum((h[col] / secs[n].length * n_h).astype(int), n_h - 1)
        out[n] = len(np.unique(ti * n_h + hi)) / (n_theta * n_h)
    return out


def arm_doubtful(cover: float, rms: float, params: FitParams) -> bool:
    """The arm check of `recon.posture` (step 7): an arm section too little covered (`section_cover`),
    or little covered and fitted badly (rms, metres)."""
    return cover < params.fit_doubt_min_cover or (cover < params.fit_doubt_cover and rms > params.fit_doubt_rms)


def research_distal(points, secs: dict, resid: dict, counts: dict, body: StandardBody,
                    params: FitParams) -> tuple[dict, dict, dict, set]:
    """A forearm or lower leg the checks doubt, searched again on the points from its elbow or knee.

    On a coarse volume a limb can be sent where its points are not. A forearm resting against the
    body (across the chest, beside wide hips) merges with the trunk, and the volume search can send
    it into flesh the torso's column does not hold (the hips, the belly). Legs seen from their sides
    (a body turned to the cameras) show each its outer side only: the space between them lies in
    both cameras' shadow, the volume holds them as one slab, and a lower leg can be matched across
    to the other ankle. Either way the fit leaves its own points. The points tell the limb apart
    (`_search_distal`), from two joints: where the fine adjustment left it, and the model's
    proximal length along the fitted proximal section (the doubted section may have dragged the
    joint along). A forearm is doubted by the arm check (`arm_doubtful`), a lower leg when it holds
    fewer than `fit_min_points` points or covers less than `fit_min_section_cover` of its surface.
    The result no longer doubted, whose axis does not run inside another section
    (`_inside_others`), and that covers more of its surface, replaces the doubted section.

    Parameters
    ----------
    points : (n, 3) float
    secs, resid, counts : dict
        The fine adjustment's sections, residuals (m) and point counts by name.

    Returns
    -------
    secs, resid, counts : dict
        With the re-searched sections replaced.
    replaced : set of str
        Their names: the coarse volume score no longer speaks for them.
    """
    covers = section_cover(points, secs, params.fit_coverage_distance)
    replaced = set()
    for prox, dist, *_ in LIMBS:
        if dist not in secs or prox not in secs:
            continue
        if not _doubted(dist, covers.get(dist, 0.0), resid.get(dist, np.inf), counts.get(dist, 0), params):
            continue
        p = secs[prox]
        best = None
        for upper in (p, p.replace(end=p.start + body.section_length(prox) * p.axis)):
            trial = {**secs, prox: upper}
            found = _search_distal(points, trial, prox, dist, body, params)
            if found is None:
                continue
            shp, rms, n = found
            if _inside_others(shp, trial, dist):
                continue   # a limb does not run inside another part of the body
            cov = section_cover(points, {**trial, dist: shp}, params.fit_coverage_distance).get(dist, 0.0)
            if not _doubted(dist, cov, rms, n, params) and (best is None or cov > best[0]):
                best = (cov, {**trial, dist: shp}, rms, n)
        if best is not None:
            secs, resid, counts = best[1], {**resid, dist: best[2]}, {**counts, dist: best[3]}
            replaced.add(dist)
    return secs, resid, counts, replaced


def too_few(n: int, cover: float, params: FitParams) -> bool:
    """The fit's first test of a section (`recon.posture.fit`'s unfitted check): fewer than
    `fit_min_points` points, or less than `fit_min_section_cover` of its surface covered (``cover``,
    `section_cover`)."""
    return n < params.fit_min_points or cover < params.fit_min_section_cover


def _doubted(name: str, cover: float, rms: float, n: int, params: FitParams) -> bool:
    """Whether `research_distal` searches the distal section ``name`` again: a forearm the arm
    check doubts (`arm_doubtful`; ``rms`` metres), a lower leg that fails `too_few`."""
    if kind_of(name) == "forearm":
        return arm_doubtful(cover, rms, params)
    return too_few(n, cover, params)


def _inside_others(shape: SectionShape, secs: dict, name: str) -> bool:
    """Whether more than one of four samples on ``shape``'s axis (at 0.25, 0.5, 0.75 and 1 of its
    length) lies inside another section of ``secs`` than ``name``. A forearm fitted on the points
    after the re-search lies beside the trunk or the head, never in it (a hand held against the
    body or on the head keeps its axis a forearm radius outside): one fitted through the head was a
    forearm pointed at the cameras, unseen, that took the neck's points (arms_forward at k = 1
    turned 60 degrees: wrist 50 cm off, a silent nonsense fit)."""
    samples = shape.start + np.linspace(0.25, 1.0, 4)[:, None] * (shape.end - shape.start)
    inside = np.zeros(len(samples), bool)
    for k, v in secs.items():
        if k != name:
            inside |= v.coords(samples)[0] < 0
    return int(inside.sum()) > 1


def _search_distal(points, secs: dict, prox: str, dist: str, body: StandardBody, params: FitParams):
    """The distal section ``dist`` (a forearm or lower leg) searched on the points from the end of
    ``secs[prox]``: (shape, rms, points) or None.

    Every direction within the joint's bend (`match_max_bend` from the proximal section) is scored
    by the points on the limb's surface around it (within 0.6 radii of it, between 0.15 and 1
    section length) that no other section explains (farther than half `fit_near_distance` from
    their surfaces), less a quarter of the best score per axis sample inside another section (a
    limb is not inside the trunk); the best is fitted by `fit_section` on the points it is nearest
    to.
    """
    p, q = secs[prox], secs[dist]
    e, L, r = p.end, body.section_length(dist), float(q.radii.mean())
    others = [v for k, v in secs.items() if k != dist]
    X = points[np.linalg.norm(points - e, axis=1) < L + 0.05]
    if not len(X):
        return None
    free = X[np.min(np.stack([o.distance(X) for o in others], 1), 1) > 0.5 * params.fit_near_distance]
    dirs = _SEARCH_DIRS[_SEARCH_DIRS @ p.axis >= np.cos(np.radians(params.match_max_bend))]
    score = np.zeros(len(dirs))
    for rows, surf, *_ in limb_columns(free, e, dirs, L, r):
        score[rows] = surf.sum(1)
    score = score - 0.25 * score.max() * axis_samples_inside(others, e, dirs, L, 0.0, 4)
    start = q.replace(start=e, end=e + L * dirs[int(np.argmax(score))])
    names, k = _assign(points, {**secs, dist: start}, params.fit_near_distance)
    own = points[k == names.index(dist)]
    if len(own) < params.fit_min_points:
        return None
    shp, rms = fit_section(own, start, loss=params.fit_loss, iterations=2,
                           end_threshold=params.fit_end_threshold, max_shift=params.fit_max_shift)
    return shp.replace(start=e), rms, len(own)


def limb_columns(X, e, dirs, L, r):
    """Limb columns from ``e`` (3,) along ``dirs`` (k, 3), ``L`` long, radius ``r``, against the
    points ``X`` (m, 3), a block of directions at a time: yields ``(rows, surf, core, t, rho)``,
    ``rows`` a slice of ``dirs`` and, for those b directions, (b, m) whether each point is on the
    surface (within 0.6 r of it, between 0.15 L and L), (b, m) whether it is in the core (nearer
    the axis than 0.4 r there), and (b, m) its position along and distance from the axis. In
    blocks because the whole (k, m) arrays (800 directions by thousands of points) cost far more
    in memory traffic than in arithmetic (the same numbers: one product ``dirs @ rel.T``). Used by
    the re-search of doubted limbs (`research_distal`) and by `recon.posture.reach`."""
    rel = X - e
    t_all = dirs @ rel.T
    r2 = (rel ** 2).sum(1)[None, :]
    step = max(1, 2 ** 16 // max(1, len(X)))
    for i in range(0, len(dirs), step):
        rows = slice(i, i + step)
        t = t_all[rows]
        rho = np.sqrt(np.maximum(r2 - t ** 2, 0.0))
        along = (t > 0.15 * L) & (t < L)
        yield rows, along & (np.abs(rho - r) < 0.6 * r), along & (rho < 0.4 * r), t, rho


def axis_samples_inside(others, e, dirs, L: float, depth: float, n: int) -> np.ndarray:
    """(k,) int: over the sections ``others``, how many of ``n`` samples of each axis from ``e``
    (3,) along ``dirs`` (k, 3), at 0.25 to 1 of the length ``L``, lie nearer than ``depth`` to a
    section's surface or inside it (a limb's axis does not run into the trunk)."""
    samples = (e + (np.linspace(0.25, 1.0, n) * L)[None, :, None] * dirs[:, None, :]).reshape(-1, 3)
    return sum((o.coords(samples)[0] < depth).reshape(len(dirs), n).sum(1) for o in others)


#: Directions searched for a doubted forearm or lower leg (`research_distal`).
_SEARCH_DIRS = fibonacci_sphere(800)
