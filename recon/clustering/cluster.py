"""Clustering of a cloud into the body sections of a fitted model (paper section 3, 3.1, 3.2).

The steps, each usable alone:

1. `section_coordinates`: (r, theta, h) of every point for every section.
2. `simple_clustering`: a point joins every section whose surface is nearer than T_d (the baseline).
3. `refine_by_distance`: per (theta, h) cell of a section, an Otsu threshold on r splits two peaks
   and keeps the smaller-r one, unless the cell is single-peaked (the T_n test).
4. `adopt_unlabeled`, `claim_across_joints`, `reduce_to_two`, `resolve_two_sections`,
   `resolve_joints`: settle the points left in no section, in one section across a joint, in
   three or more, and in two sections (paper section 3.2). Where the paper is silent (documented
   on `recon.params.ClusterParams`): a point claimed by one section only, inside the column of
   the adjacent one and on its side of their joint plane, goes to it; the three-or-more rule
   never drops the surface a point lies on; the joint rule's fronts are weighed with the model's
   joint plane
   (`joint_plane_score`: the mitre of the axes at the joint, the cross-section of the section
   the body follows where the joint lies inside the other, the arm's cross-section through the
   shoulder, the groin's crease at flexed hips).

``python -m bodyscan.benchmarks.recon_table`` shows, per shipped posture, which section pairs are confused
and which of these rules decided them.

`cluster_points` chains them for ``method="proposed"`` or ``"simple"``. Memberships are ``(n, 11)``
bool arrays in `recon.model.SECTIONS` order.
"""

from __future__ import annotations

import numpy as np

from ..geometry import unit
from ..model import ADJACENT, EXTREMITIES, SECTIONS, BodyFit, section_coords
from ..params import ClusterParams

NS = len(SECTIONS)


# -- 1. coordinates ------------------------------------------------------------------------------
def near_section(shape, points: np.ndarray, margin: float) -> np.ndarray:
    """(k,) indices of ``points`` (n, 3) inside the axis-aligned box around ``shape`` grown by
    ``margin`` metres (an open end is grown by ``shape.length`` more)."""
    reach = float(shape.radii.max()) + float(shape.caps.max()) + margin
    a, b = shape.start.copy(), shape.end.copy()
    if not shape.closed[0]:
        a = a - shape.axis * shape.length
    if not shape.closed[1]:
        b = b + shape.axis * shape.length
    lo, hi = np.minimum(a, b) - reach, np.maximum(a, b) + reach
    inside = np.ones(len(points), dtype=bool)
    for k in range(3):
        inside &= (points[:, k] >= lo[k]) & (points[:, k] <= hi[k])
    return np.flatnonzero(inside)


def section_coordinates(points: np.ndarray, fit: BodyFit, margin: float | None = None):
    """Section coordinates of every point for every section.

    Parameters
    ----------
    points : (n, 3) float, metres
    fit : BodyFit
    margin : float, optional
        Only points within ``margin`` (metres) of a section's bounding box get its coordinates;
        the others get ``r = inf`` (far outside) and NaN angle and height. Default: every point.

    Returns
    -------
    r, theta, h : (n, 11) float
        Signed distance from each section's model surface (metres, negative inside), angle around
        its axis (radians) and position along it (metres); NaN for sections absent from ``fit``.
    """
    if margin is None:
        return section_coords(fit.sections, points)
    n = len(points)
    r = np.full((n, NS), np.nan)
    theta = np.full((n, NS), np.nan)
    h = np.full((n, NS), np.nan)
    for j, name in enumerate(SECTIONS):
        if name not in fit.sections:
            continue
        shape = fit.sections[name]
        idx = near_section(shape, points, margin)
        r[:, j] = np.inf
        r[idx, j], theta[idx, j], h[idx, j] = shape.coords(points[idx])
    return r, theta, h


def section_widths(fit: BodyFit) -> np.ndarray:
    """(11,) float: each section's width (metres), NaN where the section is not fitted."""
    return np.array([fit.sections[s].width if s in fit.sections else np.nan for s in SECTIONS])


# -- 2. simple clustering ------------------------------------------------------------------------
def simple_clustering(r: np.ndarray, widths: np.ndarray, t_d: float = 0.30) -> np.ndarray:
    """The baseline: each point joins every section whose model surface is nearer than T_d.

    Parameters
    ----------
    r : (n, 11) float
        Signed distances from the section surfaces, metres (NaN: no such section).
    widths : (11,) float
        Section widths, metres.
    t_d : float
        T_d as a fraction of each section's width (paper: 0.30).

    Returns
    -------
    member : (n, 11) bool
    """
    with np.errstate(invalid="ignore"):
        return np.abs(r) < t_d * np.asarray(widths)[None, :]


# -- 3. refinement by the distance distribution ---------------------------------------------------
#: Peak bytes per cell and histogram bin of `otsu_cells` (its float64 histograms and cumulative sums).
BYTES_PER_CELL_BIN = 64


def otsu_cells(cell: np.ndarray, values: np.ndarray, n_cells: int, *, bins: int = 16,
               near_band: float = 1.0, t_n_factor: float = 0.5, min_points: int = 12):
    """Per-cell Otsu threshold and single-peak test, vectorized over cells.

    Parameters
    ----------
    cell : (m,) int
        Cell index of each value, in ``[0, n_cells)``.
    values : (m,) float
        The values to split (r, metres).
    n_cells : int
    bins : int
        Histogram bins per cell, spanning that cell's value range.
    near_band : float
        Values within ``near_band`` bin widths of the threshold are "near" it.
    t_n_factor : float
        T_n = the cell histogram's maximum frequency times this factor; a cell with more than T_n
        values near its threshold is single-peaked.
    min_points : int
        Cells with fewer values are treated as single-peaked.

    Returns
    -------
    threshold : (n_cells,) float
        Otsu threshold of each cell (NaN for empty cells).
    split : (n_cells,) bool
        True where the cell holds two peaks (split at the threshold).
    """
    cell = np.asarray(cell, dtype=np.int64)
    v = np.asarray(values, dtype=np.float64)
    cnt = np.bincount(cell, minlength=n_cells)
    lo = np.full(n_cells, np.inf)
    hi = np.full(n_cells, -np.inf)
    np.minimum.at(lo, cell, v)
    np.maximum.at(hi, cell, v)
    span = hi - lo
    width = np.where(span > 0, span / bins, 1.0)
    b = np.clip(((v - lo[cell]) / width[cell]).astype(np.int64), 0, bins - 1)
    H = np.bincount(cell * bins + b, minlength=n_cells * bins).reshape(n_cells, bins).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = H / cnt[:, None]
        w0 = np.cumsum(p, axis=1)[:, :-1]                   # weight below a cut after bin k
        m = np.cumsum(p * np.arange(bins), axis=1)
        mk, mt = m[:, :-1], m[:, -1:]
        sb = (mt * w0 - mk) ** 2 / (w0 * (1.0 - w0))          # between-class variance
    sb = np.where(np.isfinite(sb), sb, -1.0)
    k = sb.argmax(axis=1)
    threshold = np.where(cnt > 0, lo + (k + 1) * width, np.nan)
    near = np.abs(v - threshold[cell]) <= near_band * width[cell]
    n_near = np.bincount(cell, weights=near.astype(np.float64), minlength=n_cells)
    single = (n_near > t_n_factor * H.max(axis=1)) | (cnt < min_points) | ~(span > 0)
    return threshold, ~single


def cell_index(theta: np.ndarray, h: np.ndarray, length: float, mesh_theta: int, mesh_h: int) -> np.ndarray:
    """(m,) int cell of the (theta, h) mesh on a section's side; caps fall in the end rows."""
    ti = np.clip((theta * (mesh_theta / (2 * np.pi))).astype(np.int64), 0, mesh_theta - 1)
    hi = np.clip(np.floor(h / length * mesh_h).astype(np.int64), 0, mesh_h - 1)
    return ti * mesh_h + hi


def refine_by_distance(member: np.ndarray, r: np.ndarray, theta: np.ndarray, h: np.ndarray,
                       fit: BodyFit, params: ClusterParams = ClusterParams()) -> np.ndarray:
    """Refine memberships by the local distribution of r (paper section 3.1).

    In each (theta, h) cell of each section, the r of the section's members is split by Otsu's
    threshold unless the cell is single-peaked (more than T_n points near the threshold). In a
    two-peak cell the larger-r peak "represents the surface of another body section": its points
    leave this section, but only those that are also members of another section, and not at the
    joint of that section with this one (paper silent: only sections that do not meet this one at any
    joint count; counting adjacent ones too split off the hips' overlap, the crotch seam, and on the
    library doubled the bridging). So a point never leaves its only section
    (the paper's proviso that two peaks may come from noise), and the overlap of adjacent sections
    at their joint, where the surfaces are continuous, is left to the joint rule (an arm against
    the chest below the shoulder is still split off).

    Parameters
    ----------
    member : (n, 11) bool
        Memberships from `simple_clustering`.
    r, theta, h : (n, 11) float
        From `section_coordinates`.
    fit : BodyFit
    params : ClusterParams

    Returns
    -------
    member : (n, 11) bool
        A refined copy.
    """
    from ..model import adjacency_matrix

    from bodyscan._resources import require_memory

    from .. import ReconError

    out = member.copy()
    n_cells = params.mesh_theta * params.mesh_h
    require_memory(n_cells * params.otsu_bins * BYTES_PER_CELL_BIN,
                   f"the T_n refinement's {params.mesh_theta} x {params.mesh_h} cells x {params.otsu_bins} bins",
                   "lower mesh_theta, mesh_h or otsu_bins", error=ReconError)
    apart = ~adjacency_matrix() & ~np.eye(NS, dtype=bool)   # sections that do not meet at a joint
    for j, name in enumerate(SECTIONS):
        if name not in fit.sections:
            continue
        idx = np.flatnonzero(member[:, j])
        if len(idx) == 0:
            continue
        cell = cell_index(theta[idx, j], h[idx, j], fit.sections[name].length,
                          params.mesh_theta, params.mesh_h)
        rr = r[idx, j]
        thr, split = otsu_cells(cell, rr, n_cells, bins=params.otsu_bins, near_band=params.near_band,
                                t_n_factor=params.t_n_factor, min_points=params.min_cell_points)
        elsewhere = (out[idx][:, apart[j]]).any(axis=1)
        drop = split[cell] & (rr >= thr[cell]) & elsewhere
        out[idx[drop], j] = False
    return out


# -- 4. points in no section, in three or more, in two ---------------------------------------------
def neighbor_radius(points: np.ndarray, params: ClusterParams, tree=None) -> float:
    """The neighbour radius, metres: ``params.neighbor_radius`` or the automatic one."""
    if params.neighbor_radius > 0:
        return float(params.neighbor_radius)
    from scipy.spatial import cKDTree

    tree = tree if tree is not None else cKDTree(points)
    rng = np.random.default_rng(0)
    sample = points[rng.choice(len(points), size=min(len(points), 5000), replace=False)]
    d, _ = tree.query(sample, k=2)
    spacing = float(np.median(d[:, 1]))
    return params.neighbor_spacing * max(spacing, 1e-6)


#: At most this many neighbours per point are used by the multi-section rules (the nearest ones
#: within the radius); about three times what a regular grid holds within the default radius.
MAX_NEIGHBORS = 32


def _neighbors(tree, points, rows, radius, k=MAX_NEIGHBORS):
    """Neighbour pairs of ``rows`` (excluding themselves), grouped by row in ``rows`` order.

    Returns (row position, neighbour index, distance in metres) arrays of the pairs.
    """
    k = min(k + 1, tree.n)
    d, nb = tree.query(points[rows], k=k, distance_upper_bound=radius, workers=-1)
    d, nb = d.reshape(len(rows), k), nb.reshape(len(rows), k)
    ok = np.isfinite(d) & (nb != rows[:, None])
    pos = np.broadcast_to(np.arange(len(rows))[:, None], ok.shape)[ok]
    return pos, nb[ok], d[ok]


def _edges_of(pos, m, sel, cnt=None):
    """Indices of the pairs (grouped by row, from `_neighbors`) whose row position is in ``sel``
    (``cnt``: ``np.bincount(pos, minlength=m)``, if already counted)."""
    cnt = np.bincount(pos, minlength=m) if cnt is None else cnt
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    c = cnt[sel]
    first = np.repeat(start[sel] - np.concatenate([[0], np.cumsum(c)[:-1]]), c)
    return first + np.arange(int(c.sum()))


def adopt_unlabeled(member: np.ndarray, points: np.ndarray, radius: float, max_rounds: int = 20,
                    tree=None, k: int = 12) -> np.ndarray:
    """Points in no section take the sections of their nearest labelled point within ``radius``.

    Repeated (up to ``max_rounds``), so that labels spread into a connected unlabelled region
    (fingers, toes, a nose further than T_d from the model); the nearest labelled point is looked
    for among the ``k`` nearest points. Returns a copy of ``member`` (n, 11); points with no
    labelled point within reach stay unlabelled.
    """
    from scipy.spatial import cKDTree

    out = member.copy()
    lone = np.flatnonzero(~out.any(axis=1))
    if len(lone) == 0 or len(lone) == len(points):
        return out
    tree = tree if tree is not None else cKDTree(points)
    k = min(k, len(points))
    d, nb = tree.query(points[lone], k=k, distance_upper_bound=radius)
    d, nb = d.reshape(len(lone), k), nb.reshape(len(lone), k)
    ok = np.isfinite(d)
    nb = np.where(ok, nb, 0)
    labelled = out.any(axis=1)
    for _ in range(max_rounds):
        has = ok & labelled[nb]
        take = has.any(axis=1) & ~labelled[lone]
        if not take.any():
            break
        first = nb[np.arange(len(lone)), has.argmax(axis=1)]
        out[lone[take]] = out[first[take]]
        labelled[lone[take]] = True
    return out


def _scaled_distance(r, widths):
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(r), np.inf, np.abs(r) / np.asarray(widths)[None, :])


def reduce_to_two(member: np.ndarray, points: np.ndarray, r: np.ndarray, widths: np.ndarray,
                  *, max_rounds: int = 20, k: int = 16, tree=None,
                  keep_nearest: float = 0.0) -> np.ndarray:
    """Three-or-more rule: copy the sections of the nearest point that has fewer (paper 3.2).

    Repeated until every point is in at most two sections; after ``max_rounds`` (or when a point has
    no such point among its ``k`` nearest) it keeps the two sections whose surfaces are nearest
    relative to their widths.

    With ``keep_nearest`` > 0 (paper silent), a point nearer than ``keep_nearest`` widths to the
    surface of its nearest section (relative to widths) copies only from a point also in that
    section: the copy drops the farther claims, never the surface the point lies on. Without
    it, an arm point against the chest below the shoulder (in chest, waist and upper arm)
    copies the labels of the nearest torso point (chest and waist) and leaves its own arm: it
    is then meshed with the chest, across the armpit.

    Returns a copy of ``member`` (n, 11).
    """
    from scipy.spatial import cKDTree

    out = member.copy()
    count = out.sum(axis=1)
    many0 = np.flatnonzero(count >= 3)
    if len(many0) == 0:
        return out
    tree = tree if tree is not None else cKDTree(points)
    k = min(k, len(points))
    _, nb0 = tree.query(points[many0], k=k, workers=-1)   # counts only fall: one query will do
    nb0 = nb0.reshape(len(many0), k)
    if keep_nearest:
        sd0 = np.where(out[many0], _scaled_distance(r[many0], widths), np.inf)
        nearest = np.argmin(sd0, axis=1)
        on = sd0[np.arange(len(many0)), nearest] <= float(keep_nearest)
    for _ in range(max_rounds):
        still = count[many0] >= 3
        if not still.any():
            return out
        many, nb = many0[still], nb0[still]
        fewer = (count[nb] < count[many][:, None]) & (nb != many[:, None])
        if keep_nearest:
            fewer &= out[nb, nearest[still][:, None]] | ~on[still][:, None]
        has = fewer.any(axis=1)
        if not has.any():
            break
        first = nb[np.arange(len(many)), fewer.argmax(axis=1)][has]
        new = out[first]                      # all copies from the labels before this round
        # a copy that leaves the point in no section is no help: keep its own labels then
        ok = new.any(axis=1)
        tgt, new = many[has][ok], new[ok]
        changed = (out[tgt] != new).any(axis=1)
        if not changed.any():
            break
        out[tgt] = new
        count[tgt] = new.sum(axis=1)
    many = np.flatnonzero(count >= 3)
    if len(many):
        sd = np.where(out[many], _scaled_distance(r[many], widths), np.inf)
        best = np.argsort(sd, axis=1)[:, :2]
        out[many] = False
        out[many[:, None], best] = True
    return out


def _pairs(member, rows):
    """(m,) first and second section index of rows that are in exactly two sections."""
    order = np.argsort(~member[rows], axis=1, kind="stable")
    return order[:, 0], order[:, 1]


def at_joint_mask(points: np.ndarray, A: np.ndarray, B: np.ndarray, h: np.ndarray, fit: BodyFit,
                  joint_reach: float) -> np.ndarray:
    """(m,) bool: whether each two-section point (sections A, B) lies at the joint between them.

    Only adjacent sections meet at a joint; a point is at it when its position along the distal
    section's axis is less than ``joint_reach`` times that section's width (the distal section
    starts at the joint).
    """
    at = np.zeros(len(points), dtype=bool)
    for (p, d) in ADJACENT:
        ip, idd = SECTIONS.index(p), SECTIONS.index(d)
        if d not in fit.sections:
            continue
        sel = ((A == ip) & (B == idd)) | ((A == idd) & (B == ip))
        if sel.any():
            at[sel] = h[sel, idd] < joint_reach * fit.sections[d].width
    return at


def resolve_two_sections(member, points, r, rows, A, B, radius, tree, *, max_rounds=20):
    """Two-section rule for points not at a joint (paper 3.2), in place on ``member``.

    A point in sections A and B goes to the one with the smaller ``|d_A - mean_A|`` vs
    ``|d_B - mean_B|``, where d are its signed distances to the section surfaces and the means are
    over its neighbours clustered only into A (only into B). Where a point has no such neighbour
    for a section, that section's mean is the median r of all points clustered only into it (paper
    silent). Decisions are taken in rounds, the points with neighbours of both kinds first, so that
    the others see settled neighbours.
    """
    pos, nb, _ = _neighbors(tree, points, rows, radius)
    count = member.sum(axis=1)
    fallback = np.zeros(NS)
    for j in range(NS):
        only = member[:, j] & (count == 1)
        if only.any():
            fallback[j] = np.median(r[only, j])
    m = len(rows)
    ra, rb = r[nb, A[pos]], r[nb, B[pos]]
    r_a, r_b = r[rows, A], r[rows, B]
    todo = np.ones(m, dtype=bool)
    for round_ in range(max_rounds + 1):
        live = todo[pos]                  # only the pairs of undecided points matter
        pos, nb, ra, rb = pos[live], nb[live], ra[live], rb[live]
        only_a = member[nb, A[pos]] & (count[nb] == 1)
        only_b = member[nb, B[pos]] & (count[nb] == 1)
        na = np.bincount(pos, weights=only_a, minlength=m)
        nbb = np.bincount(pos, weights=only_b, minlength=m)
        sa = np.bincount(pos, weights=np.where(only_a, ra, 0.0), minlength=m)
        sb = np.bincount(pos, weights=np.where(only_b, rb, 0.0), minlength=m)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_a = np.where(na > 0, sa / na, fallback[A])
            mean_b = np.where(nbb > 0, sb / nbb, fallback[B])
        ea = np.abs(r_a - mean_a)
        eb = np.abs(r_b - mean_b)
        last = round_ == max_rounds
        decided = todo & (((na > 0) & (nbb > 0)) | last)
        if not decided.any():  # nobody has both kinds: let those with one kind go
            decided = todo & ((na > 0) | (nbb > 0))
            if not decided.any():
                decided = todo
        to_a = decided & (ea <= eb)
        to_b = decided & (ea > eb)
        member[rows[to_a], B[to_a]] = False
        member[rows[to_b], A[to_b]] = False
        count[rows[decided]] = 1
        todo &= ~decided
        if not todo.any():
            return


#: A joint further than this many mean radii of the proximal section from its axis is a side joint.
SIDE_JOINT = 0.7


#: The joints at the far ends of the bones that meet at an end joint: {joint: (the proximal
#: section's other joint, the distal section's other joint)}.
BONE_ENDS = {"chest": ("pelvis", "neck"), "neck": ("chest", "head"),
             "elbow_l": ("shoulder_l", "wrist_l"), "elbow_r": ("shoulder_r", "wrist_r"),
             "knee_l": ("hip_l", "ankle_l"), "knee_r": ("hip_r", "ankle_r")}

#: A bone further than this from its section's axis (degrees) is not used (a misplaced joint).
BONE_MAX_ANGLE = 45.0


def _bone(fit: BodyFit, a: str, b: str, axis: np.ndarray) -> np.ndarray:
    """(3,) unit direction from joint ``a`` to joint ``b`` of ``fit``, or ``axis`` (unit, pointing
    the same way) when a joint is missing or the bone lies more than `BONE_MAX_ANGLE` from it."""
    if not fit.seams or a not in fit.seams or b not in fit.seams:
        return axis
    v = np.asarray(fit.seams[b], dtype=float) - np.asarray(fit.seams[a], dtype=float)
    n = np.linalg.norm(v)
    if n < 1e-6 or (v / n) @ axis < np.cos(np.radians(BONE_MAX_ANGLE)):
        return axis
    return v / n


#: The joint toward the body's midline from each side joint (the other side's; the second if the
#: first is missing).
_MIDLINE = {"shoulder_l": ("shoulder_r", "neck"), "shoulder_r": ("shoulder_l", "neck"),
            "hip_l": ("hip_r", "pelvis"), "hip_r": ("hip_l", "pelvis")}


def _tilt_to_midline(fit: BodyFit, joint: str, j: np.ndarray, away: np.ndarray,
                     tilt: float) -> np.ndarray:
    """(3,) unit normal ``away - tilt * inward``: ``away`` (unit, the limb's axis) tilted toward
    the body's midline, ``inward`` the unit direction from the joint ``j`` to the midline joint
    (`_MIDLINE`) across ``away``. ``away`` unchanged where no midline joint is known or the limb
    points along the line to it (less than 0.3 of that line across the limb: a T-pose's arm)."""
    names = [n for n in _MIDLINE.get(joint, ()) if fit.seams and n in fit.seams]
    if not names:
        return away
    to_mid = np.asarray(fit.seams[names[0]], dtype=float) - j
    inward = to_mid - (to_mid @ away) * away
    if np.linalg.norm(inward) < 0.3 * np.linalg.norm(to_mid):
        return away
    normal = away - tilt * inward / np.linalg.norm(inward)
    return normal / np.linalg.norm(normal)


#: The side joints where a thigh leaves the waist.
_HIPS = ("hip_l", "hip_r")


def flexed_hip_plane(points: np.ndarray, fit: BodyFit, params: ClusterParams) -> tuple | None:
    """(tilt, offset) of the hips' planes (``params.hip_plane_tilt``, ``params.hip_plane_offset``)
    when the hips are flexed, else None (without ``params.hip_planes`` too).

    The hips count as flexed when no crotch is found along the thighs (`recon.posture.joints.find_crotch`:
    a thigh more than 45 degrees from the waist's downward axis, or no points between the legs).
    With the legs down, the crotch was found and the reported thighs start from it
    (`recon.posture.joints.split_hips`); the joint rule's fronts then place the seam, and a plane would
    have to be anchored on the crotch seen in the points, which steeper lasers see less (found
    -3.0 to +1.8 cm from the body file's at k = 1, -0.4 to +3.0 at k = 2, +2.6 to +5.4 cm at
    k = 3; through it, the upright postures lost up to 0.6 % at k = 3) or on the fitted hip
    joint, which scatters 2.3 cm along the plane's normal (child_arms_raised 0.961 -> 0.953).
    """
    if not params.hip_planes:
        return None
    from ..posture.joints import find_crotch

    if find_crotch(points, fit.sections) is not None:
        return None
    return (params.hip_plane_tilt, params.hip_plane_offset)


def joint_plane_score(points: np.ndarray, prox: np.ndarray, dist: np.ndarray, fit: BodyFit,
                      reach: float, mitre_band: float = np.inf, side_planes: bool = False,
                      overlap_middle: bool = True, bones: bool = False,
                      side_tilt: float = 0.0, hip_plane: tuple | None = None) -> np.ndarray:
    """(m,) float in [-1, 1]: which side of its joint's plane each point lies on, from the model.

    The plane of the joint between a proximal section P and a distal one D passes through the
    end of D at the joint (where the two columns overlap, P's end lying past D's end along P's
    axis, through the middle of that overlap: both columns claim it), with the bisector of the
    two axes as normal (P's axis toward the joint plus D's axis away from it: the plane across
    a straight limb, the mitre of a bent one). The score is the signed distance to it
    (positive on D's side) over ``reach`` times D's width, clipped to [-1, 1].

    Where the joint lies more than ``mitre_band`` widths of D past D's end (measured along P's
    axis), the body between that end and the joint still follows P: the boundary is P's cross
    section, and the normal is P's axis alone (the spine bends at the chest joint, well above
    the chest section's lower end). Where D's end lies more than ``mitre_band`` widths past the
    joint, the normal is D's axis alone.

    At a side joint, where D leaves P through its side rather than its end (the joint is further
    than `SIDE_JOINT` mean radii from P's axis: shoulders, hips), there is no plane across P's
    axis. With ``side_planes``, where the joint lies beside P's column (within its length: the
    shoulders), the plane is D's cross-section through the joint, the limb's centre of rotation
    (a hanging arm: its inner side below the joint is arm, the chest beside the joint is
    chest); where it lies beyond P's end the score is 0. At the hips, with ``hip_plane`` =
    (tilt, offset), the plane is the groin's crease (paper silent): the mitre of the waist's axis
    toward the hip and the thigh's axis, tilted out by ``tilt`` (`_tilt_to_midline`: it rises
    from the crotch to the hip's side), ``offset`` thigh widths past the hip joint along its
    normal (`flexed_hip_plane` gives it only with the hips flexed). Measured on the labels with
    the oracle posture (a plane
    fitted to the waist and thigh labels within 16 cm of each hip, 42 hips of the 21 shipped
    bodies): its normal 0.82-0.91 along the mitre with 0.40-0.56 outward (tan 29 degrees), upright
    and flexed 90 degrees alike; 2.5 cm (sd 0.4) past the rig's joint, 0.6 cm (sd 1.0) past the
    crotch. Before, a flexed hip whose joint lay within the waist's length got the shoulders'
    plane, the thigh's cross-section through the joint, which gave the lower belly above a
    squatting thigh to the thigh.

    Parameters
    ----------
    points : (m, 3) float, metres
    prox, dist : (m,) int
        Proximal and distal section of each point's joint (indices into `recon.model.SECTIONS`).
    fit : BodyFit
    reach : float
        Fraction of the distal section's width at which the score saturates.
    mitre_band : float
        Widths of D: the mitre only where the joint is within this of D's end (default: always).
    side_planes : bool
        Planes at the side joints beside P's column (default: none at side joints).
    hip_plane : (2,) float, optional
        (tilt, offset in thigh widths) of the hips' planes (default: as the other side joints).
    overlap_middle : bool
        Where the columns overlap, the plane through the middle of the overlap (else D's end).
    bones : bool
        At the end joints (`BONE_ENDS`: chest, neck, elbows, knees), the directions of the bones
        from the fit's seams (`BodyFit.seams`) instead of the columns' axes: P's from its other
        joint to the joint, D's from the joint to its other joint (each only within
        `BONE_MAX_ANGLE` of the axis).
        The body file's sections are where the skinning weights change bones, and the bones run
        between the joints; a column's axis runs through the middle of the flesh, which can lean
        away from the bone (the spine lies at the back of the torso and the waist's column,
        fitted to the belly and the buttocks, stands more upright than the lumbar spine).
    side_tilt : float
        At the side joints beside P's column (``side_planes``: the shoulders, and an estimated hip
        level with the waist's lower end), the plane's normal is tilted toward the body's midline
        by this (the tangent of the tilt; `_tilt_to_midline`): the body file's upper arm
        includes the deltoid, which caps the joint from outside, while the chest reaches below
        the joint on the armpit's side; the boundary is high outside and low inside.
    """
    out = np.zeros(len(points))
    for (p, d), joint in ADJACENT.items():
        ip, idd = SECTIONS.index(p), SECTIONS.index(d)
        sel = np.flatnonzero((prox == ip) & (dist == idd))
        if len(sel) == 0 or p not in fit.sections or d not in fit.sections:
            continue
        P, D = fit.sections[p], fit.sections[d]
        j = fit.seams.get(joint, D.start) if fit.seams else D.start
        along = (j - P.start) @ P.axis
        at_start = np.linalg.norm(D.start - j) <= np.linalg.norm(D.end - j)
        away = D.axis if at_start else -D.axis
        if np.linalg.norm(j - P.start - along * P.axis) > SIDE_JOINT * float(P.radii.mean()):
            if hip_plane is not None and joint in _HIPS:
                # the groin's crease: the mitre of the waist's axis and the thigh's, tilted out
                toward = P.axis if along > P.length / 2 else -P.axis
                normal = _tilt_to_midline(fit, joint, j, unit(toward + away), hip_plane[0])
                origin = j + hip_plane[1] * D.width * normal
                out[sel] = np.clip((points[sel] - origin) @ normal / (reach * D.width), -1.0, 1.0)
                continue
            if not (side_planes and 0.0 <= along <= P.length):
                continue  # a side joint beyond P's end (hips): no plane
            # beside P's column (shoulders): D's cross-section through the joint, tilted
            normal = _tilt_to_midline(fit, joint, j, away, side_tilt) if side_tilt > 0 else away
            score = np.clip((points[sel] - j) @ normal / (reach * D.width), -1.0, 1.0)
            # only along D's column: beyond its end (its cap, a capsule's dome) the plane says nothing
            h = (points[sel] - (D.start if at_start else D.end)) @ away
            out[sel] = np.where(h >= 0, score, 0.0)
            continue
        toward = P.axis if along > P.length / 2 else -P.axis
        origin = D.start if at_start else D.end
        overlap = ((P.end if along > P.length / 2 else P.start) - origin) @ toward
        if bones and joint in BONE_ENDS:  # the body file's bones, from the joints
            toward = _bone(fit, BONE_ENDS[joint][0], joint, toward)
            away = _bone(fit, joint, BONE_ENDS[joint][1], away)
        normal = toward + away
        n = np.linalg.norm(normal)
        normal = normal / n if n > 1e-3 else away
        beyond = (j - origin) @ toward / D.width   # the joint lies this far past D's end, widths
        if beyond > mitre_band:
            normal = toward
        elif beyond < -mitre_band:
            normal = away
        if overlap > 0 and overlap_middle:  # the columns overlap along P's axis: its middle
            origin = origin + 0.5 * overlap * toward
        out[sel] = np.clip((points[sel] - origin) @ normal / (reach * D.width), -1.0, 1.0)
    return out


def resolve_joints(member, points, r, rows, A, B, radius, tree, widths, seam_width=None,
                   fit=None, plane_weight=0.0, plane_reach=0.3, mitre_band=np.inf,
                   side_planes=False, overlap_middle=True, bones=False, side_tilt=0.0,
                   hip_plane=None):
    """Joint rule for points in two adjacent sections A, B at their joint (paper 3.2), in place.

    The paper settles such a point from its neighbours: only in A, or in A and in both -> A
    (likewise B); neighbours in A, in B and in both -> it stays in both when the "both" ones are
    few, otherwise it waits while the others are settled, and the rule is applied again. Applied
    round after round, this erodes the overlap from the A-only and the B-only sides until the two
    fronts meet. That fixed point is computed here directly, with distances along the neighbour
    graph (Dijkstra from the single-section points of each section).

    Where the fronts meet: the overlap reaches T_d * width_A into B and T_d * width_B into A, so
    the fronts meet at the true junction when a point goes to A if ``d_A * width_A < d_B *
    width_B`` (``d`` its graph distance from each front); plain round-by-round erosion would move
    the seam toward the narrower section. The points of the proximal section that have a point
    of the distal one within ``seam_width`` (default: the neighbour radius) stay in both: a
    one-point-wide seam that stitches the surfaces.
    Points that no front reaches go to the section whose surface is nearer (relative to width).

    With ``plane_weight`` > 0 (and ``fit``), the model's joint plane also votes (paper silent):
    a point goes to the distal section D, rather than the proximal P, when
    ``(f_P - f_D) / (f_P + f_D) + plane_weight * s > 0``, with ``f`` the width-scaled front
    distances above and ``s`` the `joint_plane_score` (reach ``plane_reach``). The fronts alone
    put the seam where the overlap's geometry says; the plane corrects them where a section's
    overlap reaches far across a narrow neck or knee.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    pos, nb, w = _neighbors(tree, points, rows, radius)
    n, m = len(points), len(rows)
    count = member.sum(axis=1)
    w = w + 1e-9
    dist = np.full((m, 2), np.inf)
    local = np.full(n, -1, dtype=np.int64)
    cnt = np.bincount(pos, minlength=m)
    for j in np.unique(np.concatenate([A, B])):
        # the front of section j runs through the points that may belong to j
        sel = np.flatnonzero((A == j) | (B == j))
        e = _edges_of(pos, m, sel, cnt)
        nbe = nb[e]
        src = nbe[(count[nbe] == 1) & member[nbe, j]]
        if len(src) == 0:
            continue
        # a compact graph: the points of sel first (their pairs are grouped in sel's order), then
        # the other neighbours
        flag = np.zeros(n, dtype=bool)
        flag[nbe] = True
        flag[rows[sel]] = False
        extra = np.flatnonzero(flag)
        local[rows[sel]] = np.arange(len(sel))
        local[extra] = len(sel) + np.arange(len(extra))
        size = len(sel) + len(extra)
        indptr = np.concatenate([[0], np.cumsum(cnt[sel]),
                                 np.full(len(extra), len(e))])
        graph = csr_matrix((w[e], local[nbe], indptr), shape=(size, size))
        d = dijkstra(graph, directed=False, indices=np.unique(local[src]), min_only=True)[:len(sel)]
        d = d * widths[j]
        local[rows[sel]] = -1
        local[extra] = -1
        dist[sel, 0] = np.where(A[sel] == j, d, dist[sel, 0])
        dist[sel, 1] = np.where(B[sel] == j, d, dist[sel, 1])
    reached = np.isfinite(dist).any(axis=1)
    sd = _scaled_distance(r[rows], widths)
    closer_a = sd[np.arange(m), A] <= sd[np.arange(m), B]
    choice = np.where(reached, np.where(dist[:, 0] <= dist[:, 1], A, B), np.where(closer_a, A, B))
    if plane_weight > 0 and fit is not None:
        prox = _PROXIMAL[A, B]
        distal = np.where(prox == A, B, A)
        f_p = np.where(prox == A, dist[:, 0], dist[:, 1])
        f_d = np.where(prox == A, dist[:, 1], dist[:, 0])
        with np.errstate(invalid="ignore"):
            front = np.where(np.isinf(f_p) & np.isinf(f_d), 0.0,
                             np.where(np.isinf(f_p), 1.0, np.where(np.isinf(f_d), -1.0,
                                                                     (f_p - f_d) / (f_p + f_d + 1e-12))))
        vote = front + plane_weight * joint_plane_score(points[rows], prox, distal, fit, plane_reach,
                                                           mitre_band, side_planes, overlap_middle,
                                                           bones, side_tilt, hip_plane)
        choice = np.where(reached, np.where(vote > 0, distal, prox), choice)
    assigned = np.where(count == 1, member.argmax(axis=1), -1)
    assigned[rows] = choice
    other = np.where(choice == A, B, A)
    seam_width = radius if seam_width is None else seam_width
    close = (assigned[nb] == other[pos]) & (w <= seam_width)
    touches = np.bincount(pos, weights=close, minlength=m) > 0
    seam = touches & (choice == _PROXIMAL[A, B])
    keep = ~seam
    member[rows[keep], other[keep]] = False


_PROXIMAL = np.full((NS, NS), -1, dtype=np.int64)
for (_p, _d) in ADJACENT:
    _i, _j = SECTIONS.index(_p), SECTIONS.index(_d)
    _PROXIMAL[_i, _j] = _PROXIMAL[_j, _i] = _i


def claim_across_joints(member: np.ndarray, points: np.ndarray, r: np.ndarray, h: np.ndarray,
                        fit: BodyFit, reach: float = 0.5,
                        params: ClusterParams = ClusterParams(),
                        hip_plane: tuple | None = None) -> np.ndarray:
    """Points claimed by one section alone but lying in the adjacent one go to it (paper silent).

    The T_d shell of a section claims only points near its model surface, ``|r| < T_d * width``.
    Where the body narrows or slopes inside a section's column near a joint, its surface lies
    deeper inside that column than T_d: the base of the neck and the slope of the trapezius inside
    the chest's column (the body file's chest reaches the neck joint; only the head's start cap,
    around the neck joint, claims them), the back of the knee inside the lower leg's column. Such
    a point is claimed by the adjacent section only, on the wrong side of their joint. A point
    claimed by one section S alone, lying inside the column of a section T adjacent to S
    (``r_T < 0``, within T's axial extent) and on T's side of their joint plane
    (`joint_plane_score`, within ``reach`` widths of the distal section) goes to T instead. Side
    joints without a plane (the hips without ``params.hip_planes``) and points beyond the distal
    column's end at the shoulders (score 0) are left alone.

    Parameters
    ----------
    member : (n, 11) bool
    points : (n, 3) float, metres
    r, h : (n, 11) float
        From `section_coordinates`.
    fit : BodyFit
    reach : float
        Widths of the distal section: how far from the joint plane a point may lie.
    params : ClusterParams
        For the joint plane's settings (``mitre_band``, ``side_joint_planes``,
        ``joint_plane_overlap_middle``, ``joint_plane_bones``, ``side_plane_tilt``, ``hip_planes``).
    hip_plane : (2,) float, optional
        The hips' planes (`joint_plane_score`; from `flexed_hip_plane`).

    Returns
    -------
    member : (n, 11) bool
        A copy; the moved points are in T only.
    """
    out = member.copy()
    single = member.sum(axis=1) == 1
    for (p, d) in ADJACENT:
        if p not in fit.sections or d not in fit.sections:
            continue
        ip, idd = SECTIONS.index(p), SECTIONS.index(d)
        for src, dst, sign in ((idd, ip, -1.0), (ip, idd, 1.0)):
            T = fit.sections[SECTIONS[dst]]
            with np.errstate(invalid="ignore"):
                cand = np.flatnonzero(single & member[:, src] & (r[:, dst] < 0) & (h[:, dst] >= 0)
                                      & (h[:, dst] <= T.length))
            if len(cand) == 0:
                continue
            s = sign * joint_plane_score(points[cand], np.full(len(cand), ip),
                                         np.full(len(cand), idd), fit, reach, params.mitre_band,
                                         params.side_joint_planes,
                                         params.joint_plane_overlap_middle,
                                         params.joint_plane_bones, params.side_plane_tilt,
                                         hip_plane)
            go = cand[(s > 0) & (s < 1)]
            out[go, src] = False
            out[go, dst] = True
    return out


def settle_multi(member: np.ndarray, points: np.ndarray, r: np.ndarray, h: np.ndarray, fit: BodyFit,
                 params: ClusterParams = ClusterParams(), tree=None, radius: float | None = None) -> np.ndarray:
    """Settle the points in several sections (paper 3.2): three-or-more, two-section, joint rules.

    First (paper silent), points claimed by one section alone across a joint go to the adjacent
    section they lie in (`claim_across_joints`, with ``params.claim_across_joints`` > 0). With the
    hips flexed, both rules weigh the hips' planes (`flexed_hip_plane`, ``params.hip_planes``).

    Parameters
    ----------
    member : (n, 11) bool
    points : (n, 3) float, metres
    r, h : (n, 11) float
        From `section_coordinates`.
    fit : BodyFit
    params : ClusterParams
    tree : scipy.spatial.cKDTree of ``points``, optional
    radius : float, optional
        Neighbour radius, metres (default: `neighbor_radius`).

    Returns
    -------
    member : (n, 11) bool
        Every point in at most two sections; two only at the joints of adjacent sections.
    """
    from scipy.spatial import cKDTree

    tree = tree if tree is not None else cKDTree(points)
    radius = radius if radius is not None else neighbor_radius(points, params, tree)
    widths = section_widths(fit)
    hip_plane = flexed_hip_plane(points, fit, params)
    if params.claim_across_joints > 0:
        member = claim_across_joints(member, points, r, h, fit, params.claim_across_joints, params,
                                     hip_plane)
    out = reduce_to_two(member, points, r, widths, max_rounds=params.max_rounds, tree=tree,
                        keep_nearest=params.three_keep_nearest)
    rows = np.flatnonzero(out.sum(axis=1) == 2)
    if len(rows) == 0:
        return out
    A, B = _pairs(out, rows)
    at = at_joint_mask(points[rows], A, B, h[rows], fit, params.joint_reach)
    if (~at).any():
        resolve_two_sections(out, points, r, rows[~at], A[~at], B[~at], radius, tree,
                             max_rounds=params.max_rounds)
    if at.any():
        resolve_joints(out, points, r, rows[at], A[at], B[at], radius, tree, widths,
                       seam_width=radius * params.seam_width / params.neighbor_spacing
                       if params.neighbor_radius == 0 else params.seam_width * radius / 3.0,
                       fit=fit, plane_weight=params.joint_plane_weight, plane_reach=params.t_d,
                       mitre_band=params.mitre_band, side_planes=params.side_joint_planes,
                       overlap_middle=params.joint_plane_overlap_middle,
                       bones=params.joint_plane_bones, side_tilt=params.side_plane_tilt,
                       hip_plane=hip_plane)
    return out


def primary_section(member: np.ndarray, r: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """(n,) int8: the one section of each point (nearest surface among its sections), -1 for none."""
    sd = np.where(member, _scaled_distance(r, widths), np.inf)
    out = sd.argmin(axis=1).astype(np.int8)
    out[~member.any(axis=1)] = -1
    return out


def cluster_points(points: np.ndarray, fit: BodyFit, method: str = "proposed",
                   params: ClusterParams = ClusterParams(), coords=None, tree=None) -> np.ndarray:
    """Cluster ``points`` (n, 3) into the fitted sections.

    Parameters
    ----------
    points : (n, 3) float, metres
    fit : BodyFit
    method : {"proposed", "simple"}
        ``simple`` stops after the T_d threshold (the paper's baseline); ``proposed`` refines
        by the distance distribution and settles the points in several sections.
    params : ClusterParams
    coords : tuple of three (n, 11) arrays, optional
        Precomputed `section_coordinates`.
    tree : scipy.spatial.cKDTree of ``points``, optional

    Returns
    -------
    member : (n, 11) bool
    """
    r, theta, h = coords if coords is not None else section_coordinates(points, fit)
    widths = section_widths(fit)
    member = simple_clustering(r, widths, params.t_d)
    if method == "simple":
        return member
    from scipy.spatial import cKDTree

    tree = tree if tree is not None else cKDTree(points)
    radius = neighbor_radius(points, params, tree)
    member = refine_by_distance(member, r, theta, h, fit, params)
    if params.adopt_unlabeled:
        member = adopt_unlabeled(member, points, radius, params.max_rounds, tree)
    return settle_multi(member, points, r, h, fit, params, tree=tree, radius=radius)


def assign_extremities(points: np.ndarray, member: np.ndarray, fit: BodyFit, t_d: float = 0.30) -> np.ndarray:
    """Which hand or foot of ``fit.extremities`` each point is on (beyond the paper).

    A point past a wrist (ankle), along the forearm's (lower leg's) axis, that is the forearm's
    or in no section, goes to the hand (foot) when its model surface is nearer than T_d times
    the hand's width (the simple clustering's test).

    Parameters
    ----------
    points : (n, 3) float, metres
    member : (n, 11) bool
        Memberships (`cluster_points`).
    fit : BodyFit
        With ``extremities`` (`recon.posture.extremities.place_extremities`).
    t_d : float

    Returns
    -------
    (n,) int8
        Index into `recon.model.EXTREMITIES` (its order), -1 for none.
    """
    out = np.full(len(points), -1, dtype=np.int8)
    free = ~member.any(axis=1)
    for k, (name, (parent, joint)) in enumerate(EXTREMITIES.items()):
        shape = fit.extremities.get(name)
        if shape is None or parent not in fit.sections or joint not in fit.seams:
            continue
        s = fit.sections[parent]
        cand = np.flatnonzero((member[:, SECTIONS.index(parent)] | free) & (out < 0)
                              & ((points - np.asarray(fit.seams[joint], dtype=float)) @ s.axis > 0))
        out[cand[shape.distance(points[cand]) <= t_d * shape.width]] = k
    return out
