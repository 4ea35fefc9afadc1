"""Posture estimation (paper section 2): match the body model to the volume data, then adjust it on the points.

The steps, as the paper gives them, with the choices it leaves open (each one a `FitParams` field):

1. Volume data (`recon.volume`): voxel size from the sparsest part's density, clamped to
   [`voxel_min`, `voxel_max`].
2. Torso (one elliptic column covering chest and waist), 6 degrees of freedom: the paper aligns the
   model's centre of gravity with the cloud's and fits the torso to the volume, contour voxels
   weighted n. To work for any posture we start from the centre of the thickest part of the volume
   (deepest voxels; the cloud's centre of gravity leaves the body when the limbs are spread) and
   search the torso's axis over a hemisphere of directions and its roll about the axis
   (`match_torso_directions` x 6 rolls x 3 offsets along the axis), score each on the volume (mean
   voxel weight inside the column: n on contour, 1 inside, `match_empty_weight` outside; minus the
   mean weight of samples beside the neck, where a body is empty; minus `match_upright_prior` x
   (1 - cos tilt): scanned people are mostly upright and a scanner knows its +z), refine the best
   few by Nelder-Mead over translation and rotation. The best `match_torso_candidates`, and the
   best upright one (within `match_upright_start` of +z, kept so while refined), each also with
   its roll taken from the two legs below it, are matched whole (step 3), and the match whose
   model explains most points (within `match_explain_distance`) wins: on a coarse volume (a sparse
   scan, 40 mm voxels, where a hanging arm merges with the torso) the volume score ties an upright
   torso with one tilted onto an arm, its wide axis turned front-back; the points tell them apart.
   The torso's radii are then measured on the points.
3. Sections from the chest outwards: chest (about the chest joint, within 20 degrees of the torso),
   head (about the neck), then thighs and lower legs, then upper arms and forearms (the paper does
   the arms before the legs; we place the legs first because hanging hands reach down beside the
   thighs). Where the paper does not say how a limb's direction is searched, each limb chain is
   searched on a sphere of `match_directions` directions for its proximal section, the best
   `match_beam` of them are extended by the same search for the distal section (elbow or knee bend
   at most `match_max_bend` degrees, the limb pointing at most `match_max_adduction` across the
   body; a thigh rising above the torso's horizontal by more than `match_thigh_max_rise` only by
   flexing front or back, a shin never above its thigh), and the best chain is refined by
   Nelder-Mead. Voxels inside sections already placed weigh
   `match_claimed_weight`, so a limb is not fitted into the torso or folded back over itself. A limb
   seen from one side only holds no inside voxels (a seated person's thighs under the 2 mm scanner,
   seen from above: a thigh on its bone scores -0.8 on the volume): when a chain's root section
   lands in empty voxels (below `match_min_section_score`) of a fine volume (voxels at most
   `match_shell_voxel`), the chain is searched again by a shell
   score (surface samples near contour voxels, at 0.7-1.3 radii, minus axis samples near them) and
   that placement kept when its sections reach `match_min_shell_score`. The
   model's up/down along the torso axis: when the torso is within 60 degrees of the vertical its
   upper end is the one towards +z (clouds are in a +z up frame); otherwise both are matched and
   the better total score wins. The volume pins the torso poorly along its own axis (an arm held
   out at the shoulder, a half-seen side): when the crown, found on the head's axis, lies more
   than `match_min_anchor_shift` from the model's, the torso slides (at most
   `match_max_anchor_shift`) so that the head hangs from it, and the sections are placed again.
4. Body size: the paper uses the average adult male. The first match uses the extent of the cloud
   along the torso axis (at least `match_min_first_stature`; every torso candidate is matched
   again, locally, at that size); then each leg chain's length (hip to
   the farthest point along its lower leg) is measured and, when the legs' median ratio to the
   standard is off by more than `match_resize_tolerance`, the model is rescaled and matched again.
   The legs are measured from the matched hips, so a torso matched too high or too low along its
   axis makes them too long or too short; crown to sole (through each leg) does not depend on
   where the torso sits. When the two disagree by more than `match_size_disagree` (adult sizes),
   the hips were misplaced and the size comes from crown to sole, and the next match hangs the
   torso from the crown (`match_resized_anchor_shift`). Crown to sole is measured over
   the coarse model: where a joint bends (a knee, the head on the trunk) the model's segment before
   it, not the points, sets where the next one hangs, so that segment's unseen part (its length x
   (1 - cos bend)) is taken out of the measured and the model lengths (`_size_ratios`).
   (`match_size_from_crown` = 1 always sizes adult bodies from crown to sole; off by default: on
   the shipped library it fixes some k = 3 sizes but misplaces a seated and a squatting body.)
5. Fine adjustment on the points (paper 2.3(2)): each point within `fit_near_distance` of a section's
   surface is given to the nearest section; each section's axis (position, direction, roll) is
   adjusted by bounded least squares on the point-to-surface distances, its radius set to the mean
   distance of its points from the axis, and its free end (head top, fingertips, sole) found from
   the points nearer the axis than `fit_end_threshold` times the radius (none: the end is open and
   the length kept). Joints are then placed where adjacent axes meet (bent joints) or along the
   axis at the model's proportions (straight joints, and a joint whose distal section is
   unfitted; an elbow bent less than 35 degrees counts as straight); a knee whose ankle was found
   from the sole closes the triangle hip-knee-ankle with the model's thigh : shank ratio and the
   bend of the fitted axes (`_knee_between`: where two nearly straight axes meet is ill-defined);
   the chest's top end is aimed at the fitted head (within 25 degrees of the waist's axis; the arms
   beside it fix the chest's own direction poorly), then centred between the sides of the neck
   (`_neck_shift`), and the shoulders turn with it. The torso, head and legs slide along the torso
   axis (at most `fit_max_shift`) so that the neck lies a standard head length below the detected
   crown (a leg section turned more than 45 degrees from that axis, a thigh held level, slides
   along its own axis only: it stays on its points), and the neck and head follow the crown up to
   `fit_anchor_max_shift` further up; the arms stay on their points and only the shoulders follow,
   along the upper arms, rising with an arm raised above the horizontal (`_move_shoulders`). A
   wrist lies a hand length before the fingertips; a hand resting on the thigh or hip, whose
   points went to those sections, is followed along the forearm's axis (`_fingertip`).
6. Front and back, hence left and right, come from the data, never from the scanner: feet point
   forward from the shins, knees bend backward, hips bend forward. The foot is the lowest part of
   the leg chain (against the scanner's +z), not the fitted shin's end, which in a sparse scan
   falls short of the sole onto the calf (a calf bulges backwards: left and right came out swapped
   at 20-30 mm). A scan rotated about the vertical gives the same fit.
7. Checks: a limb section whose volume score is below `match_min_section_score` or whose surface
   cells hold too few points (`fit_min_section_cover`) is unfitted (and so is what hangs from it);
   so is an arm section both poorly covered (`fit_doubt_cover`) and poorly fitted
   (`fit_doubt_rms`), or very poorly covered (`fit_doubt_min_cover`): an arm matched onto the torso's side or a half-seen arm is listed, with a
   warning, rather than placed wrongly. A section in empty voxels whose seen surface fits it (shell
   score at least `match_min_shell_score`) is kept, and so is a leg section whose fitted surface the
   points cover (`fit_leg_seen_cover`, `fit_leg_seen_rms`: a thigh raised level, seen from the
   front and above, encloses no inside voxels). An upper arm raising its elbow behind the
   shoulder (pointing up, and more backwards than sideways or upwards: not anatomy) was fitted onto
   the shoulder of a misplaced torso and is listed, and so is a thigh pointing up within 60 degrees
   of the torso's axis (a hip flexed past its active range). A fit whose sections (all placed ones) explain fewer than
   `fit_min_coverage` of the points within `fit_coverage_distance`, or with more than
   `fit_max_unfitted` sections unfitted, failed: the fit is made again from the next torso
   candidate (up to `match_alternatives`, turned by at least `match_alt_min_turn` or moved), and
   when none passes the cloud is refused (`ReconError`): a wrong coarse pose is never returned
   silently as a fit.
8. The joints are the rig's (the body file format's); the sections reported in the `BodyFit` meet
   where the body file's section labels change, which is not always at a joint: the torso splits
   into waist and chest at `recon.bodymodel.TORSO_SPLIT` of the way from the pelvis to the chest
   joint, the lower legs start `KNEE_SPLIT` statures below the knees, and sections meeting at a
   joint have flat caps (`JOINT_CAP`). The clustering separates the sections there.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, fields

import numpy as np

from . import ReconError
from .bodymodel import (HIP_OFFSET, JOINT_CAP, KNEE_SPLIT, LIMBS, SPINE_BACK, TORSO_SPLIT, StandardBody,
                        kind_of, standard_body)
from .cloud import check_points
from .model import SECTIONS, BodyFit, SectionShape
from .volume import Volume, voxel_size, voxelize


@dataclass(frozen=True)
class FitParams:
    """Parameters of posture estimation; paper values as defaults, paper section in each comment."""

    voxel_min: float = 0.010               # 2.2: lower limit of the voxel edge, m (value not given; chosen)
    voxel_max: float = 0.040               # 2.2, 4.2: upper limit of the voxel edge, 40 mm
    voxel_density_k: int = 6               # 2.2: density = distance to the k-th nearest neighbour (chosen)
    voxel_density_quantile: float = 0.95   # 2.2: "the sparsest part": this quantile of it (chosen)
    voxel_spacing_factor: float = 1.0      # 2.2: voxel edge / sparsest spacing (chosen)
    voxel_reach: float = 0.3               # 2.2: inside test: enclosing contours within this, m (chosen)
    contour_weight: float = 2.0            # 2.3(1), 4.2: weight n of contour voxels, n = 2
    match_empty_weight: float = -1.0       # 2.3(1): weight of empty voxels in the match (chosen)
    match_claimed_weight: float = -0.5     # 2.3(2): weight of voxels inside sections already placed (chosen)
    match_max_adduction: float = 0.25      # 2.3(2): limb may point at most this far (cosine) across the body (chosen)
    match_claim_margin: float = 0.02       # 2.3(2): torso claimed this far beyond its surface, m (chosen)
    match_upright_prior: float = 0.5       # 2.3(1): score penalty x (1 - cos tilt) of the torso from +z (chosen)
    match_torso_candidates: int = 2        # 2.3(1): best torso poses whose whole-body match is compared,
                                           # each also with its roll from the legs (chosen)
    match_min_section_score: float = 0.0   # 2.3(2): a limb section whose volume weight is below: unfitted (chosen)
    match_min_shell_score: float = 0.3     # 2.3(2): ... unless placed on its seen surface, by a shell score at
                                           # least this (a limb seen from one side only; chosen)
    match_shell_voxel: float = 0.025       # 2.3(2): the shell score only on volumes of voxels this fine, m: the 2 mm
                                           # scans (15 mm voxels). Measured: at 0.035 (10 mm scans, 25-30 mm voxels)
                                           # squat k=3 went 8 -> 17 cm; on 40 mm voxels (20 mm scans) a rescued arm
                                           # let a misplaced child's fit through (chosen)
    match_thigh_max_rise: float = 0.2      # 2.3(2): a thigh rising more than this (cosine) towards the torso's top
                                           # must flex front or back more than it rises (anatomy; chosen)
    match_upright_start: float = 5.0       # 2.3(1): the best torso within this of +z (degrees) is always among
                                           # those matched whole, and stays so when refined (chosen: 5 measured
                                           # better than 12 on heavy_a_pose, standing at 10 and 20 mm)
    match_torso_directions: int = 200      # 2.3(1): torso axis candidates on a hemisphere (chosen)
    match_directions: int = 300            # 2.3(2): limb direction candidates on a sphere (chosen)
    match_beam: int = 6                    # 2.3(2): proximal directions kept per limb chain (chosen)
    match_max_bend: float = 150.0          # 2.3(2): largest knee bend searched, degrees (chosen)
    match_max_elbow_bend: float = 140.0    # 2.3(2): largest elbow bend searched, degrees (anatomy: about 145;
                                           # a forearm folded back down a raised arm was matched at 150; chosen)
    match_rounds: int = 2                  # 2.1: matches with the size re-estimated in between (chosen; 3
                                           # measured worse on child_standing, t_pose and seated)
    match_resize_tolerance: float = 0.06   # 2.1: re-match only when the limbs measure off by more (chosen)
    match_min_anchor_shift: float = 0.08   # 2.3(1): slide the torso to hang from the crown when it is off
    match_max_anchor_shift: float = 0.15   #   by more than this, and at most this far, m (chosen)
    match_size_from_crown: int = 0         # 2.1: 1 = size from crown-to-sole lengths, 0 = from the legs (chosen)
    match_min_first_stature: float = 1.5   # 2.1: stature of the first match at least this, m (chosen)
    match_size_disagree: float = 0.1       # 2.1: the legs' length (from the matched hips) and crown to sole (which does
                                           # not depend on where the torso sits along its axis) differ by more than this
                                           # ratio: the hips were misplaced, size from crown to sole (adult sizes; a
                                           # walker 1.97 m tall, hips matched 11 cm high: legs 2.2 m, crown to sole
                                           # 2.0 m; on the library's other adult-size matches they agree within
                                           # 0.09; a child's disagree by 0.11, but children stay sized by the legs;
                                           # chosen)
    match_resized_anchor_shift: float = 0.0  # 2.3(1): after sizing from the crown (`match_size_disagree`: the torso was
                                           # misplaced along its axis), the next match slides the torso to hang from the
                                           # crown when it is off by more than this, m (0: always; the walker's resized
                                           # match sat 7 cm low, under `match_min_anchor_shift`; chosen)
    match_alternatives: int = 2            # 2.3(1): other torso poses tried, best first, when the fit of the best
                                           # fails its checks (a sparse scan's coarse volume often ties an upright
                                           # torso with one tilted onto an arm; chosen)
    match_explain_distance: float = 0.03   # 2.3(1)-(2): of the whole-body matches of the torso candidates, the one
                                           # explaining most points within this (m) wins: on a coarse volume the
                                           # volume score ties right and wrong torsos, the points do not (chosen)
    match_explain_points: int = 4000       # 2.3(1): points sampled (fit_seed) for that count (chosen)
    match_alt_min_turn: float = 10.0       # 2.3(1): an alternative's torso axis turned at least this, degrees (chosen)
    fit_near_distance: float = 0.05        # 2.3(2): points this near a section surface adjust it, m
    fit_end_threshold: float = 0.6         # 2.3(2): end points: nearer the axis than this x radius
    fit_iterations: int = 2                # 2.3(2): rounds of point assignment and adjustment (chosen)
    fit_section_points: int = 500          # 2.3(2): points per section per round, subsampled (chosen)
    fit_max_shift: float = 0.04            # 2.3(2): largest axis move per round, m (chosen)
    fit_max_turn: float = 12.0             # 2.3(2): largest axis turn per round, degrees (chosen)
    fit_max_points: int = 30000            # 2.3(2): points used by the fine fit, subsampled (chosen)
    fit_loss: str = "soft_l1"              # 2.3(2): least-squares loss (paper: squares; robust chosen)
    fit_min_points: int = 30               # 2.3(2): fewer points: the section is unfitted (chosen)
    fit_coverage_distance: float = 0.02    # 2.3(2): a point is explained within this of a surface, m (chosen)
    fit_min_section_cover: float = 0.2     # 2.3(2): fewer of a section's cells with points: unfitted (chosen)
    fit_doubt_cover: float = 0.55          # 2.3(2): an arm section both this little covered and
    fit_doubt_rms: float = 0.015           #   fitted worse than this rms (m) is not trusted: unfitted,
    fit_doubt_min_cover: float = 0.35      #   and so is one covered less than this (chosen; 0.5 while the
                                           #   head anchor moved the arms off their points, 4 cm on most
                                           #   scans: arm covers on the library rose 0.69 -> 0.77 mean
                                           #   when they stayed, the doubt cover by the same ratio)
    fit_leg_seen_cover: float = 0.4        # 2.3(2): a leg section in empty voxels (a thigh raised level, seen from
    fit_leg_seen_rms: float = 0.012        #   the front and above: no inside voxels) is kept when its fitted surface's
                                           #   cells hold points at least this much and it fits them within this rms
                                           #   (m): the points show the limb the volume missed. Measured: the raised
                                           #   thighs of knee_raised 0.42-0.57 / 9-11 mm; a squat's thigh matched
                                           #   into a gap 0.35-0.40 / 14-17 mm (chosen)
    fit_max_unfitted: int = 4              # 2.3(2): more sections unfitted (two arms' worth): the posture was not
                                           # found (on the library, fits with 5 or more were wrong; chosen)
    fit_min_coverage: float = 0.6          # 2.3(2): fewer points explained: not a body (chosen)
    fit_anchor_min_stature: float = 1.5    # 2.3(2): anchor on the crown only for bodies this tall, m (chosen)
    fit_anchor_max_shift: float = 0.04     # 2.3(2): the neck and head follow the crown this much further than the
                                           # torso (fit_max_shift), the chest stretching, m. Measured on the library
                                           # (paper, k = 1, 3): neck error 2.9 -> 2.3 cm mean, head 3.2 -> 2.5, the
                                           # rest unchanged; 0.08 for the whole torso moved the knees (chosen)
    fit_stature: float = 0.0               # 2.1: body stature, m; 0 = estimate it from the cloud
    fit_seed: int = 0                      # random subsampling seed

    @classmethod
    def from_strings(cls, pairs) -> "FitParams":
        """Build from ``["name=value", ...]`` (the CLI's ``--param``); raise `ReconError` on a bad one."""
        types = {f.name: f.type for f in fields(cls)}
        kw = {}
        for pair in pairs or ():
            name, sep, value = pair.partition("=")
            name = name.strip()
            if not sep or name not in types:
                raise ReconError(f"--param {pair!r}: expected name=value with name one of "
                                 f"{', '.join(types)}")
            conv = {"float": float, "int": int, "str": str}[types[name]]
            try:
                kw[name] = conv(value)
            except ValueError:
                raise ReconError(f"--param {pair!r}: {value!r} is not a {types[name]}") from None
        return cls(**kw)


# -- geometry helpers ---------------------------------------------------------------------------
def fibonacci_sphere(n: int, hemisphere: bool = False) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (or the upper hemisphere, z >= 0)."""
    i = np.arange(n) + 0.5
    z = 1 - i / n if hemisphere else 1 - 2 * i / n
    phi = i * np.pi * (3 - np.sqrt(5))
    r = np.sqrt(1 - z ** 2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _cross(a, b) -> np.ndarray:
    """Cross product of (..., 3) arrays (np.cross is slow on small arrays)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def _perp(d: np.ndarray) -> np.ndarray:
    """(..., 3) a unit vector perpendicular to each unit vector ``d`` (..., 3)."""
    ref = np.where(np.abs(d[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    u = _cross(d, ref)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def _rotvec(v: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of rotation vector ``v`` (Rodrigues)."""
    th = float(np.linalg.norm(v))
    if th < 1e-12:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tangent_dir(d0: np.ndarray, a: float, b: float) -> np.ndarray:
    """Unit direction near ``d0`` moved by angles (a, b) radians in its tangent plane."""
    u = _perp(d0)
    w = _cross(d0, u)
    return _unit(d0 * np.cos(np.hypot(a, b)) + (u * a + w * b) * np.sinc(np.hypot(a, b) / np.pi))


# -- the volume score ---------------------------------------------------------------------------
class _Scorer:
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
        idx = np.where(ok[:, None], idx, 0)
        near = self.near[idx[:, 0], idx[:, 1], idx[:, 2]] & ok
        taken = self.taken[idx[:, 0], idx[:, 1], idx[:, 2]] & ok
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
        r, _, _ = shape.coords(g * v.size + v.origin)
        g = g[r < 0]
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


def _column_score(scorer: _Scorer, start, frames, length, radii, template) -> np.ndarray:
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


def _shell_score(scorer: _Scorer, start, frames, length, radii, avoid=None) -> np.ndarray:
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
            h = np.clip((pts - root) @ d, 0.0, L)
            fold = np.linalg.norm(pts - root - h[..., None] * d, axis=-1) < r
        out.append(near & ~taken & ~fold if tmpl is _SHELL_SURF else near | fold)
    surf = out[0].reshape(out[0].shape[:-1] + (3, -1)).any(axis=-2)
    return surf.mean(axis=-1) - out[1].mean(axis=-1)


def _frames_from_dirs(d: np.ndarray) -> np.ndarray:
    """(m, 3, 3) frames (rows x, y, axis) for unit directions ``d`` (m, 3)."""
    u = _perp(d)
    return np.stack([u, _cross(d, u), d], axis=1)


# -- coarse matching ----------------------------------------------------------------------------
@dataclass
class _Pose:
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


def _torso_len(body: StandardBody) -> float:
    return body.length("neck")


def _match_torso(scorer: _Scorer, centroid: np.ndarray, body: StandardBody, params: FitParams,
                 starts=None, step: float = 1.0) -> list:
    """Candidate torso poses (centre, R) ranked by volume score, refined (Nelder-Mead, first steps
    ``step`` times 4 cm and 0.15 rad: given ``starts``, a smaller ``step`` keeps each near its own)."""
    from scipy.optimize import minimize

    L = _torso_len(body)
    rad = np.array([body.radii("chest")[0] * 0.95, body.radii("waist")[1]])
    tmpl = _TORSO_T - np.array([0, 0, 0.5])

    # above the shoulders, beside the neck, the body is empty in any posture: samples there count
    # against the torso (this pins the torso's position along its axis)
    t = np.radians(np.r_[-40:41:20, 140:221:20])
    ring = np.column_stack([np.cos(t), np.sin(t), np.full(len(t), 0.5 + 0.06 * body.stature / L)])

    lam = params.match_upright_prior
    cos_up = np.cos(np.radians(params.match_upright_start))

    def score(c, R):
        return float(_column_score(scorer, c, R.T[None], L, rad, tmpl)[0]
                     - _column_score(scorer, c, R.T[None], L, rad, ring)[0]
                     - lam * (1.0 - abs(R[2, 2])))

    if starts is None:
        dirs = np.vstack([[0.0, 0.0, 1.0], fibonacci_sphere(params.match_torso_directions, hemisphere=True)])
        u = _perp(dirs)
        w = _cross(dirs, u)
        rolls = np.linspace(0, np.pi, 6, endpoint=False)
        X = (u[:, None] * np.cos(rolls)[None, :, None] + w[:, None] * np.sin(rolls)[None, :, None]).reshape(-1, 3)
        Z = np.repeat(dirs, len(rolls), axis=0)
        Y = _cross(Z, X)
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
            R = _rotvec(x[3:]) @ R0
            if upright and abs(R[2, 2]) < cos_up:
                return 10.0   # an upright start stays upright (another start may tilt)
            return -score(c0 + x[:3], R)
        simplex = np.vstack([np.zeros(6), step * np.diag([0.04, 0.04, 0.04, 0.15, 0.15, 0.15])])
        res = minimize(f, np.zeros(6), method="Nelder-Mead",
                       options=dict(initial_simplex=simplex, maxfev=150, xatol=1e-3, fatol=1e-4))
        out.append((-res.fun, c0 + res.x[:3], _rotvec(res.x[3:]) @ R0))
    out.sort(key=lambda t: -t[0])
    return out


def _column(name, start, d, length, radii, frame_x, closed=(True, True)) -> SectionShape:
    return SectionShape(name=name, start=start, end=start + length * _unit(d), radii=radii,
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
    F = _frames_from_dirs(dirs)
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

    def distal(elbow, d1, frames):
        # distal samples inside the proximal column weigh 0: no folding back over the same limb
        if shell:
            return _shell_score(scorer, elbow, frames, L2, r2, avoid=(root, d1, L1, r1[0]))
        loc = _LIMB_T * np.array([r2[0], r2[1], L2])
        pts = elbow + loc @ frames
        w = scorer.lookup(pts)
        h = np.clip((pts - root) @ d1, 0.0, L1)
        inside = np.linalg.norm(pts - root - h[..., None] * d1, axis=-1) < r1[0] + r2[0]
        return np.where(inside, np.minimum(w, scorer.claimed), w).mean(axis=-1)

    order = np.argsort(-s1)
    cos_max = np.cos(np.radians(params.match_max_bend if prox.startswith("thigh") else params.match_max_elbow_bend))
    best = (-np.inf, None, None)
    kept = []
    for i in order:
        if any(dirs[i] @ dirs[k] > np.cos(np.radians(12)) for k in kept):
            continue
        kept.append(i)
        elbow = root + L1 * dirs[i]
        s2 = distal(elbow, dirs[i], F)
        tot = s1[i] * L1 + s2 * L2
        tot[dirs @ dirs[i] < cos_max] = -np.inf
        tot[shin_up(dirs[i], dirs)] = -np.inf
        tot[(L1 * dirs[i] + L2 * dirs) @ outward < -params.match_max_adduction * (L1 + L2)] = -np.inf
        j = int(np.argmax(tot))
        if tot[j] > best[0]:
            best = (tot[j], dirs[i], dirs[j])
        if len(kept) >= params.match_beam:
            break
    _, d1, d2 = best

    def total(x):
        a = _tangent_dir(d1, x[0], x[1])
        b = _tangent_dir(d2, x[2], x[3])
        if a @ b < cos_max or a @ outward < -params.match_max_adduction or raised(a) or shin_up(a, b) or \
                (L1 * a + L2 * b) @ outward < -params.match_max_adduction * (L1 + L2):
            return 10.0
        e = root + L1 * a
        fa = _frames_from_dirs(a[None])
        s1 = _shell_score(scorer, root, fa, L1, r1) if shell else _column_score(scorer, root, fa, L1, r1, _LIMB_T)
        return -(s1[0] * L1 + distal(e, a, _frames_from_dirs(b[None]))[0] * L2)

    simplex = np.vstack([np.zeros(4), np.eye(4) * 0.12])
    res = minimize(total, np.zeros(4), method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, maxfev=60, xatol=1e-3, fatol=1e-4))
    return _tangent_dir(d1, *res.x[:2]), _tangent_dir(d2, *res.x[2:]), -res.fun


def _search_cone(scorer, start, axis, length, radii, frame_x, max_angle, n=120):
    """Best direction within ``max_angle`` degrees of ``axis`` for a column from ``start``."""
    dirs = fibonacci_sphere(n * 4)
    dirs = dirs[dirs @ axis >= np.cos(np.radians(max_angle))]
    dirs = np.vstack([axis, dirs])
    fx = frame_x - dirs * (dirs @ frame_x)[:, None]
    fx = _unit(fx)
    F = np.stack([fx, _cross(dirs, fx), dirs], axis=1)
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


def _place_body(points, scorer_base: _Scorer, centre, R, body: StandardBody, params, dirs,
                anchor: bool = True, min_shift: float | None = None) -> _Pose:
    """Place all sections for a torso pose (R columns: left, back, up) and score the whole match;
    the torso slides to hang from the crown when the crown is off by more than ``min_shift`` (m;
    default `match_min_anchor_shift`)."""
    import copy

    scorer = copy.copy(scorer_base)
    scorer.w = scorer_base.w.copy()
    scorer.taken = scorer_base.taken.copy()
    ex, ez = R[:, 0], R[:, 2]
    L = _torso_len(body)
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
    dh, sh = _search_cone(scorer, chest.end, chest.axis, Lh, body.radii("head"), ex, 70)
    secs["head"] = _column("head", chest.end, dh, Lh, body.radii("head"), ex)
    if anchor and body.stature >= params.fit_anchor_min_stature:
        # the volume pins the torso poorly along its axis: the crown does (adult head length)
        shift = _crown_shift(points, secs["head"])
        if shift is not None and abs(shift) > (params.match_min_anchor_shift if min_shift is None else min_shift):
            move = float(np.clip(shift, -params.match_max_anchor_shift, params.match_max_anchor_shift))
            return _place_body(points, scorer_base, centre + move * (chest.end - pelvis) / np.linalg.norm(chest.end - pelvis),
                               R, body, params, dirs, anchor=False)
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
        scorer.claim(p)
        scorer.claim(q)
        total += s
    return _Pose(centre=centre, R=R, body=body, sections=secs, score=total, section_scores=fit_scores,
                 shell_scores=shell_scores)


def _chain_columns(scorer, root, d1, d2, prox, dist, body):
    """The two columns of a limb chain from ``root`` along ``d1``, ``d2`` and how well each sits
    in the volume (mean weight, before claiming them)."""
    p = _column(prox, root, d1, body.section_length(prox), body.radii(kind_of(prox)), _perp(d1))
    q = _column(dist, p.end, d2, body.section_length(dist), body.radii(kind_of(dist)), _perp(d2))
    return p, q, tuple(float(_column_score(scorer, c.start, c.frame[None], c.length, c.radii, _LIMB_T)[0])
                       for c in (p, q))


def _chain_shell(scorer, root, p: SectionShape, q: SectionShape) -> tuple:
    """Shell scores (`_shell_score`) of a chain's two columns: (proximal, distal)."""
    a = _shell_score(scorer, p.start, p.frame[None], p.length, p.radii)[0]
    b = _shell_score(scorer, q.start, q.frame[None], q.length, q.radii,
                     avoid=(root, p.axis, p.length, p.radii[0]))[0]
    return float(a), float(b)


def _explained(points, sections: dict, near: float) -> float:
    """Fraction of ``points`` (n, 3) within ``near`` metres of the surface of any of ``sections``."""
    D = np.min([s.distance(points) for s in sections.values()], axis=0)
    return float(np.mean(D < near))


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


def _chain_extent(points, pose: _Pose, dist: str) -> float | None:
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


def _roll_from_legs(points, centre, R, body: StandardBody) -> np.ndarray:
    """Turn the torso frame about its axis so that its x axis runs from one thigh to the other.

    Just below the torso (either end: up is not known yet) the cloud splits into two legs; their
    2-means centres give the left-right direction. Unchanged when no end shows two separate blobs.
    """
    ez = R[:, 2]
    rel = points - centre
    h = rel @ ez
    lat = rel - np.outer(h, ez)
    half = 0.5 * _torso_len(body)
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
    return np.column_stack([x, _cross(ez, x), ez])


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


def _coarse_match(points, scorer, params: FitParams) -> list:
    """Volume matching (paper 2.3(1)-(2)), with the body size re-estimated between rounds.

    Of the torso candidates, each placed with all its sections, the one whose model explains most
    points (`match_explain_distance`) wins. Returns the best pose, then up to `match_alternatives`
    poses of other torso candidates (turned by more than `match_alt_min_turn` degrees or moved),
    best first."""
    centroid = _thick_core(scorer.vol)
    stature = params.fit_stature if params.fit_stature > 0 else None
    body = standard_body(stature or 1.75)
    dirs = fibonacci_sphere(params.match_directions)
    starts = None
    hang = None
    pose = None
    alternatives = []
    rng = np.random.default_rng(params.fit_seed)
    sample = points if len(points) <= params.match_explain_points else \
        points[rng.choice(len(points), params.match_explain_points, replace=False)]
    for rnd in range(max(1, params.match_rounds)):
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
                    body = standard_body(float(np.clip(ext, params.match_min_first_stature, 2.2)))
                    cands = _match_torso(scorer, centroid, body, params,
                                         [(cc, RR) for _, cc, RR in _torso_choice(cands, params)], step=0.4)
        best = None
        trials = []
        placed = []
        for sc, c, R in _torso_choice(cands, params):
            trials.append((sc, c, R))
            R2 = _roll_from_legs(points, c, R, body)
            if abs(R2[:, 0] @ R[:, 0]) < np.cos(np.radians(20)):
                trials.append((sc, c, R2))   # the legs suggest another roll: let the match decide
        for sc, c, R in trials:
            # the scanner's +z is up: trust it unless the torso lies nearly horizontal
            flips = (False,) if R[2, 2] > 0.5 else (True,) if R[2, 2] < -0.5 else (False, True)
            for flip in flips:
                RR = R @ np.diag([1.0, -1.0, -1.0]) if flip else R
                p = _place_body(points, scorer, c, RR, body, params, dirs, min_shift=hang)
                p.score += sc * _torso_len(body)
                p.explained = _explained(sample, p.sections, params.match_explain_distance)
                placed.append(p)
                if best is None or p.explained > best.explained:
                    best = p
        alternatives += [p for p in placed if p is not best]
        if pose is not None and best.body.stature > pose.body.stature and best.explained < pose.explained:
            # matched again larger, the model explains fewer points (a larger model explains more
            # when it is right): the size came from a wrong pose; keep the first
            alternatives.append(best)
            break
        if pose is not None:
            alternatives.append(pose)
        pose = best
        if stature is not None or rnd == params.match_rounds - 1:
            break
        ratios = _size_ratios(points, pose)
        # whole body first (crown to sole: where the torso sits along its axis cancels out), then
        # the legs, then any limb (a hand resting on a thigh makes an arm look far too long)
        crown = ratios.get("body") or []
        # adult proportions: crown to sole; a child's large head and short legs: the legs
        legs = [v for k, v in ratios.items() if k.startswith("lower_leg")]
        adult = bool(crown) and body.stature * np.median(crown) >= params.fit_anchor_min_stature
        use = crown if adult and (params.match_size_from_crown or (
            legs and abs(np.median(legs) - np.median(crown)) > params.match_size_disagree)) else []
        use = use or legs
        if not use or (len(use) < 2 and "body" not in ratios):
            use = [v for k, v in ratios.items() if k != "body"]
        s = float(np.median(use))
        if abs(s - 1.0) < params.match_resize_tolerance:
            break
        body = standard_body(float(np.clip(body.stature * s, 0.8, 2.2)))
        starts = [(pose.centre, pose.R)]
        # sized from the crown because the legs, measured from the matched hips, disagreed: the torso
        # was misplaced along its axis; the next match hangs it from the crown wherever it is
        hang = params.match_resized_anchor_shift if use is crown and not params.match_size_from_crown else None
    # other torso poses, best first, for when the best one's fine fit fails its checks
    alts, seen = [], [pose]
    for p in sorted(alternatives, key=lambda p: -p.explained):
        if all(p.R[:, 2] @ q.R[:, 2] < np.cos(np.radians(params.match_alt_min_turn))
               or np.linalg.norm(p.centre - q.centre) > 0.5 * params.match_min_anchor_shift for q in seen):
            seen.append(p)
            alts.append(p)
    return [pose] + alts[:max(0, params.match_alternatives)]


def _size_ratios(points, pose: _Pose) -> dict:
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
    pose : _Pose
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
        hips = pose.centre - 0.5 * _torso_len(body) * pose.R[:, 2] + pose.R @ np.array([0, 0, body.length("hip_z")])
        up = np.linalg.norm(head.start - hips) + np.quantile(h[near], 0.995)
        up_model = body.length("neck") + body.section_length("head") - body.length("hip_z")
        tor = head.start - hips
        u_head = np.linalg.norm(tor) * (1.0 - max(0.0, float(head.axis @ _unit(tor))))
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


# -- fine adjustment ----------------------------------------------------------------------------
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
    axis), direction (2 angles) and, for an elliptic column, roll; then radius = mean distance of the
    column's points from the axis (per principal direction for an elliptic column); repeated
    ``iterations`` times. When ``free_end``, the end cap is placed at the farthest point nearer the
    axis than ``end_threshold`` times the radius; with no such point the end is open and the length
    is kept.

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

        fr = base.frame
        u0 = _perp(base.axis)
        w0 = _cross(base.axis, u0)
        a, b = base.radii
        L = base.length
        cap0, cap1 = base.caps
        c0, c1 = base.closed

        def pose(x):
            t = np.hypot(x[2], x[3])
            d = base.axis * np.cos(t) + (u0 * x[2] + w0 * x[3]) * np.sinc(t / np.pi)
            d = d / np.linalg.norm(d)
            start = base.start + x[0] * fr[0] + x[1] * fr[1]
            fx = fr[0] - d * (fr[0] @ d)
            fx = fx / np.linalg.norm(fx)
            if elliptic:
                fx = fx * np.cos(x[4]) + _cross(d, fx) * np.sin(x[4])
            return start, d, fx

        def make(x):
            start, d, fx = pose(x)
            return base.replace(start=start, end=start + L * d, frame_x=fx)

        def resid(x):
            # SectionShape.coords' r, inlined for speed (same formula)
            start, d, fx = pose(x)
            rel = points - start
            X, Y, h = rel @ fx, rel @ _cross(d, fx), rel @ d
            e = np.where(h < 0, h, np.where(h > L, h - L, 0.0))
            c = np.where(h < 0, cap0, cap1)
            if not c0:
                e = np.where(h < 0, 0.0, e)
            if not c1:
                e = np.where(h > L, 0.0, e)
            q = np.sqrt((X / a) ** 2 + (Y / b) ** 2 + (e / c) ** 2)
            n = np.sqrt(X ** 2 + Y ** 2 + e ** 2)
            return np.where(q > 0, n * (1.0 - 1.0 / np.maximum(q, 1e-12)), -min(a, b))

        x0 = np.zeros(5 if elliptic else 4)
        lim = np.array([max_shift, max_shift, max_turn, max_turn, max_turn])[:len(x0)]
        res = least_squares(resid, x0, loss=loss, f_scale=scale, x_scale=0.05, max_nfev=40,
                            bounds=(-lim, lim))
        cur = make(res.x)
        if fit_radii:
            cur = _refit_radii(points, cur)
    if free_end:
        cur = _find_end(points, cur, end_threshold)
    rms = float(np.sqrt(np.mean(cur.coords(points)[0] ** 2))) if len(points) else np.nan
    return cur, rms


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


def _find_end(points, s: SectionShape, threshold: float) -> SectionShape:
    q = s.local(points)
    rho = np.hypot(q[:, 0], q[:, 1])
    near_axis = (rho < threshold * s.radii.mean()) & (q[:, 2] > 0.5 * s.length)
    closed = list(s.closed)
    if not near_axis.any():
        closed[1] = False
        return s.replace(closed=tuple(closed))
    tip = float(q[near_axis, 2].max())
    cap = float(s.radii.min())
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
    sin = float(np.linalg.norm(_cross(d1, d2)))
    if den < 1e-9:
        return None, sin
    t = (B * E - C * D) / den
    u = (A * E - B * D) / den
    return 0.5 * (a.start + t * d1 + b.start + u * d2), sin


def _fine(points, pose: _Pose, params: FitParams):
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


def _turn_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    v = _cross(a, b)
    s = float(np.linalg.norm(v))
    if s < 1e-9:
        return np.eye(3)
    return _rotvec(v / s * np.arctan2(s, float(a @ b)))


def _rejoin(new: dict, old: dict, pose: _Pose, body: StandardBody, points=None) -> dict:
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
    chest = c.replace(start=waist.end, end=waist.end + c.length * _unit(c.end - waist.end + 1e-12 * c.axis))
    chest = _keep_dir(chest, c.axis, waist.end, old["chest"].length)
    # the chest's top end hangs under the head, which the points place well (the chest's own
    # direction is poorly fixed: the arms beside it); within 25 degrees of the waist's axis
    h = new["head"]
    target = h.start + h.axis * ((chest.end - h.start) @ h.axis)   # nearest point of the head's axis
    d = _unit(target - waist.end)
    if d @ waist.axis > np.cos(np.radians(25)):
        chest = _keep_dir(chest, d, waist.end, old["chest"].length)
    head_dir = new["head"].axis
    shift = _neck_shift(points, chest, waist.axis, body) if points is not None else None
    if shift is not None:
        # the neck is left-right symmetric: its top end lies midway between the neck's sides
        d = _unit(chest.end + shift - waist.end)
        if d @ waist.axis > np.cos(np.radians(25)):
            chest = _keep_dir(chest, d, waist.end, old["chest"].length)
            # the head keeps its top (the crown is measured) and hangs from the moved neck
            hd = _unit(new["head"].end - chest.end)
            if hd @ head_dir > np.cos(np.radians(30)):
                head_dir = hd
    out["chest"] = chest
    out["head"] = _keep_dir(new["head"], head_dir, chest.end, new["head"].length)
    # the shoulders ride with the chest: the coarse shoulder joints turn with it from its coarse
    # direction to its final one (a coarse chest tilted sideways raises one shoulder and lowers
    # the other), then each is taken onto its adjusted upper arm's axis
    turn = _turn_between(old["chest"].axis, chest.axis)
    roots = {}
    for prox, *_ in LIMBS:
        r0 = old[prox].start
        if prox.startswith("upper_arm"):
            r0 = chest.start + turn @ (r0 - old["chest"].start)
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
    lat = _unit(chest.frame_x - up * (chest.frame_x @ up))
    fwd = _cross(up, lat)
    rel = points - chest.end
    h, x, y = rel @ up, rel @ lat, rel @ fwd
    sel = (h > 0.02 * H) & (h < 0.06 * H) & (np.abs(x) < 0.08 * H) & (np.abs(y) < 0.08 * H)
    if sel.sum() < 10:
        return None
    lo, hi = np.quantile(x[sel], [0.1, 0.9])
    return 0.5 * (lo + hi) * lat


def _anchor_on_head_top(secs: dict, body: StandardBody, params: FitParams) -> dict:
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

#: An elbow bent less than this (degrees) is placed the model's upper-arm length from the shoulder,
#: not where the axes meet: two axes this close to parallel meet poorly (1 cm across them moves the
#: meeting point 1 / tan(35 deg) = 1.4 cm along them; fitted straight arms of the library, bent 11
#: degrees, came out bent up to 28 degrees; the bent arms are 45 degrees or more; chosen).
_ELBOW_STRAIGHT_DEG = 35.0

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
        if np.linalg.norm(_cross(p.axis, q.axis)) < np.sin(np.radians(_ELBOW_STRAIGHT_DEG)):
            out[prox] = p.replace(start=p.start + s * p.axis, end=p.end + s * p.axis)
            out[dist] = q.replace(start=out[prox].end) if s * (p.axis @ q.axis) < q.length - 0.05 else q
        else:
            out[prox] = p.replace(start=p.start + s * p.axis)
            out[dist] = q
    return out


def _keep_dir(s: SectionShape, d, start, length) -> SectionShape:
    return s.replace(start=start, end=start + length * _unit(d))


# -- front / back -------------------------------------------------------------------------------
def _front_sign(points, secs: dict, R: np.ndarray) -> float:
    """+1 if the subject faces -R[:, 1] (the provisional front), -1 if it faces +R[:, 1]."""
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
    return 1.0 if votes >= 0 else -1.0


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


def _swap_sides(name: str) -> str:
    if name.endswith("_l"):
        return name[:-2] + "_r"
    if name.endswith("_r"):
        return name[:-2] + "_l"
    return name


def _shank_ratio(points, shin: SectionShape, body: StandardBody) -> float | None:
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


def _joints(secs: dict, body: StandardBody, back: np.ndarray, points=None) -> dict:
    """Joint positions from the sections; ``back`` (3,) is the subject's backward direction;
    ``points`` (n, 3), when given, place the ankles a foot height above the soles."""
    j = {}
    soled = set()   # lower legs whose ankle was placed from the detected sole
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
    for name, frac in SPINE_BACK.items():   # the rig's spine joints lie behind the axis
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
                # the fingertips are seen: the wrist lies a hand length before them
                full = q.length + q.caps[1]
                if points is not None:
                    full = _fingertip(points, q, body)
                j[c] = q.start + max(full - body.length("hand"), 0.5 * full) * q.axis
            else:  # otherwise the wrist or ankle lies a standard segment length beyond the joint
                seg = body.length("forearm" if dist.startswith("forearm") else "lower_leg")
                r = _shank_ratio(points, q, body) if points is not None and dist.startswith("lower_leg") else None
                if r is not None and SHANK_RANGE[0] < r < SHANK_RANGE[1]:
                    # the ankle lies a foot height above the sole (Winter 0.039 H; the rig's 0.043 H):
                    # shank lengths vary between people more than foot heights do
                    seg *= r
                    soled.add(dist)
                j[c] = q.start + seg * q.axis
    if "waist" in secs:   # the rig's hip joints lie behind and outside the thighs' tops
        left = _unit(_cross(back, secs["waist"].axis))
        for side, sign in (("l", 1.0), ("r", -1.0)):
            if f"hip_{side}" in j:
                j[f"hip_{side}"] = j[f"hip_{side}"] + body.stature * (
                    HIP_OFFSET["back"] * back + sign * HIP_OFFSET["out"] * left)
    for prox, dist, a, b, c in LIMBS:
        if dist in soled and prox in secs and a in j and "waist" in secs:
            k = _knee_between(j[a], j[c], secs[prox].axis, secs[dist].axis, back, left,
                              body.length("thigh") / (body.length("thigh") + body.length("lower_leg")))
            if k is not None:
                j[b] = k
    return {k: np.asarray(v, dtype=float) for k, v in j.items()}


def _knee_between(hip: np.ndarray, ankle: np.ndarray, d_thigh: np.ndarray, d_shin: np.ndarray,
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
    while the bend angle alone moves the knee little. Measured on the fits of the 21 shipped bodies
    (k = 1, turned 137 degrees, k = 3): knee error mean 3.7 -> 2.3 cm, largest 12.7 -> 8.1 cm.
    """
    v = ankle - hip
    D = float(np.linalg.norm(v))
    if D < 1e-3:
        return None
    e = v / D
    hinge = _cross(d_thigh, d_shin)
    if hinge @ left < 0:
        hinge = -hinge
    hinge = hinge + np.sin(np.radians(20.0)) * left
    hinge = hinge - e * (hinge @ e)
    nh = float(np.linalg.norm(hinge))
    if nh < 1e-6:
        return None
    fwd = _cross(e, hinge / nh)
    if fwd @ back > 0:
        fwd = -fwd
    F = frac
    cb = float(np.clip(d_thigh @ d_shin, -1.0, 1.0))
    L = D / np.sqrt(F ** 2 + (1 - F) ** 2 + 2 * F * (1 - F) * cb)
    t, s = F * L, (1 - F) * L
    ca = float(np.clip((t * t + D * D - s * s) / (2 * t * D), -1.0, 1.0))
    return hip + t * (ca * e + np.sqrt(1.0 - ca * ca) * fwd)


# -- entry point --------------------------------------------------------------------------------
def estimate_posture(points, params: FitParams | None = None, *, view_dir=None) -> BodyFit:
    """Fit the body model to a cloud: volume matching, then fine adjustment (paper section 2).

    Parameters
    ----------
    points : (n, 3) float, metres
        The cloud (any posture, any facing direction about the vertical).
    params : FitParams, optional
    view_dir : (n, 3) float, optional
        Per point direction towards its sensor (unused by the fit, accepted for symmetry with the
        reader; front and back are read from the body's shape).

    Returns
    -------
    fit : BodyFit
        Sections, joints by canonical name, residuals, unfitted sections, the coarse fit and the
        time of each stage.

    Raises
    ------
    ReconError
        Too few points, NaNs, not metres, or a cloud that does not look like a human body.
    """
    params = params or FitParams()
    points = check_points(points)
    times = {}
    t0 = time.perf_counter()
    rng = np.random.default_rng(params.fit_seed)
    work = points if len(points) <= params.fit_max_points else \
        points[np.sort(rng.choice(len(points), params.fit_max_points, replace=False))]
    size = voxel_size(work, params.voxel_min, params.voxel_max, k=params.voxel_density_k,
                      quantile=params.voxel_density_quantile, factor=params.voxel_spacing_factor,
                      seed=params.fit_seed)
    vol = voxelize(work, size, reach=params.voxel_reach)
    scorer = _Scorer(vol, params)
    times["voxelize"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    poses = _coarse_match(work, scorer, params)
    times["match"] = time.perf_counter() - t0

    # the best coarse pose; when its fit fails the checks, the next torso candidate (a wrong
    # coarse pose is retried, then refused, never returned)
    t0 = time.perf_counter()
    first = None
    for pose in poses:
        try:
            fit, unfitted = _finish(work, pose, params)
            break
        except ReconError as e:
            first = first or e
    else:
        raise first
    times["fine"] = time.perf_counter() - t0
    if unfitted:
        warnings.warn(f"sections not fitted (missing from the scan, or not placed with confidence): {', '.join(unfitted)}", stacklevel=2)
    fit.times.update(times)
    return fit


def _finish(work, pose: _Pose, params: FitParams):
    """Fine adjustment, front and back, checks and joints of one coarse pose: (BodyFit, unfitted);
    `ReconError` when the result is not a body (too few sections, too few points explained)."""
    secs, resid, counts = _fine(work, pose, params)
    secs = _anchor_on_head_top(secs, pose.body, params)

    # front and back from the data: relabel left/right when the provisional front was the back
    sign = _front_sign(work, secs, pose.R)
    coarse_secs = dict(pose.sections)
    coarse_scores = dict(pose.section_scores or {})
    shell_scores = dict(pose.shell_scores or {})
    if sign < 0:
        secs = {_swap_sides(k): v.replace(name=_swap_sides(k)) for k, v in secs.items()}
        resid = {_swap_sides(k): v for k, v in resid.items()}
        counts = {_swap_sides(k): v for k, v in counts.items()}
        coarse_secs = {_swap_sides(k): v.replace(name=_swap_sides(k)) for k, v in coarse_secs.items()}
        coarse_scores = {_swap_sides(k): v for k, v in coarse_scores.items()}
        shell_scores = {_swap_sides(k): v for k, v in shell_scores.items()}

    cover = _section_cover(work, secs, params.fit_coverage_distance)
    back = sign * pose.R[:, 1]
    unfitted = tuple(n for n in SECTIONS if counts.get(n, 0) < params.fit_min_points
                     or (kind_of(n) == "upper_arm" and _arm_behind(secs[n].axis, pose.R, back))
                     or (kind_of(n) == "thigh" and _thigh_up(secs[n].axis, pose.R))
                     or not np.isfinite(resid.get(n, np.nan)) or cover.get(n, 0.0) < params.fit_min_section_cover
                     or (coarse_scores.get(n, 1.0) < params.match_min_section_score
                         and shell_scores.get(n, -1.0) < params.match_min_shell_score
                         and not (kind_of(n) in ("thigh", "lower_leg")
                                  and cover.get(n, 0.0) >= params.fit_leg_seen_cover
                                  and resid.get(n, np.inf) <= params.fit_leg_seen_rms))
                     or (kind_of(n) in ("upper_arm", "forearm") and (
                         cover.get(n, 0.0) < params.fit_doubt_min_cover or (
                             cover.get(n, 0.0) < params.fit_doubt_cover and resid.get(n, 0.0) > params.fit_doubt_rms))))
    # a distal section hangs from its proximal one: without it, its position means nothing
    unfitted = tuple(n for n in SECTIONS if n in unfitted or any(
        n == dist and prox in unfitted for prox, dist, *_ in LIMBS))
    if "waist" in unfitted or "chest" in unfitted or len(unfitted) > params.fit_max_unfitted:
        raise ReconError(f"the cloud does not look like a human body: only {11 - len(unfitted)} of 11 "
                         f"body sections could be fitted")
    _check_plausible(secs, pose.body)
    fitted = {k: v for k, v in secs.items() if k not in unfitted}
    for prox, dist, *_ in LIMBS:
        if prox in fitted and dist not in fitted:
            # the elbow (knee) was placed where the axes of the two sections meet; without a
            # trusted distal section it lies the model's length along the proximal one
            p = fitted[prox]
            fitted[prox] = p.replace(end=p.start + pose.sections[prox].length * p.axis)
    # whether the posture was found at all: doubted sections were placed too, and count here
    explained = _explained(work, {k: v for k, v in secs.items() if counts.get(k, 0) >= params.fit_min_points},
                           params.fit_coverage_distance)
    if explained < params.fit_min_coverage:
        raise ReconError(f"the cloud does not look like a human body, or its posture was not found: "
                         f"the fitted model explains only "
                         f"{100 * explained:.0f}% of the points (a body scan: over "
                         f"{100 * params.fit_min_coverage:.0f}%)")
    _check_leg_length(work, fitted, pose.body)
    joints = _joints(fitted, pose.body, back, work)
    fitted = _joint_caps(_split_knees(_split_torso(work, fitted), joints, pose.body))
    coarse = BodyFit(sections=coarse_secs, joints=_joints(coarse_secs, pose.body, back, work))
    return BodyFit(sections=fitted, joints=joints,
                   residuals={k: float(resid[k]) for k in fitted}, unfitted=unfitted,
                   coarse=coarse, times={}), unfitted


def _arm_behind(d: np.ndarray, R: np.ndarray, back: np.ndarray) -> bool:
    """Whether an upper arm along ``d`` (3,) raises its elbow above the shoulder behind it: pointing
    up (torso frame ``R``, columns left, back, up) and more backwards (``back``) than sideways or
    upwards. A shoulder extends about 60 degrees from hanging and opens at most about 45 degrees
    behind the frontal plane: such an arm was fitted onto the shoulder of a misplaced torso."""
    up, bk, side = float(d @ R[:, 2]), float(d @ back), abs(float(d @ R[:, 0]))
    return up > 0 and bk > max(side, up)


def _thigh_up(d: np.ndarray, R: np.ndarray) -> bool:
    """Whether a thigh along ``d`` (3,) points up within 60 degrees of the torso's axis (``R``'s third
    column): a hip flexed beyond 120 degrees, the end of its active range (the library's deepest
    flexion, a squat, is 102). Such a thigh was fitted onto the torso or an arm: a seated body at
    20 mm came out with a thigh up the chest (54 degrees from a tilted torso's axis), 46 cm off."""
    return float(d @ R[:, 2]) > 0.5


def _section_cover(points, secs: dict, near: float, n_theta: int = 12, n_h: int = 6) -> dict:
    """Per section, the fraction of its column's (theta, h) cells holding points near its surface,
    counting only points for which this section's surface is the nearest."""
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


def _split_torso(points, secs: dict, split: float = TORSO_SPLIT) -> dict:
    """The reported waist and chest sections: split where the body's labels change, not at the
    chest joint where the fit joins the two columns.

    The waist column is cut at ``split`` of its length (from the pelvis) and the chest column runs
    from the cut to its top; the joints are not moved. Both sections then meet at the section
    boundary of the body file format (`recon.bodymodel.TORSO_SPLIT`), which is what the clustering
    separates: split at the chest joint, 5-17 % of a body's points (the lower ribs) were labelled
    waist. The chest's radii become the length-weighted mean of the two columns' radii over its new
    extent (the model's radii are means along a section; the lower ribs, fitted by the waist
    column, are narrower than the shoulders). Measured on 21 bodies against keeping the chest's
    radii or measuring them again (`_robust_radii`, which the arms beside the chest inflate): the
    same section accuracy (0.869-0.873), the least bridging (mean 1.27 % against 1.38 and 1.28 %).
    """
    if "waist" not in secs or "chest" not in secs:
        return secs
    w, c = secs["waist"], secs["chest"]
    cut = w.start + split * w.length * w.axis
    low = (1.0 - split) * w.length     # the part of the waist column that becomes chest
    radii = (low * w.radii + c.length * c.radii) / (low + c.length)
    chest = c.replace(start=cut, radii=radii, caps=np.array([min(c.caps[0], radii.min()), c.caps[1]]))
    return {**secs, "waist": w.replace(end=cut), "chest": chest}


def _split_knees(secs: dict, joints: dict, body: StandardBody, drop: float = KNEE_SPLIT) -> dict:
    """The reported thigh ends at the knee joint (placed by `_knee_between` when the ankle was found
    from the sole, not where the fitted axes meet), and the lower leg starts ``drop`` statures below
    it along the shank, where the body file's labels change (`recon.bodymodel.KNEE_SPLIT`).

    Estimated-posture section accuracy, 21 bodies: 0.892 -> 0.898 for the drop (0.894 when the
    thigh is also extended to meet it), then 0.905 -> 0.911 (min 0.810 -> 0.839) for meeting at
    the knee joint; bridging 1.22 -> 1.28 % of the area.
    """
    out = dict(secs)
    for thigh, shin, _, knee, _ in LIMBS:
        if kind_of(shin) != "lower_leg" or shin not in secs:
            continue
        s = secs[shin]
        meet = thigh in secs and knee in joints
        top = joints[knee] if meet else s.start
        if meet:
            out[thigh] = secs[thigh].replace(end=top)
        axis = _unit(s.end - top)
        out[shin] = s.replace(start=top + drop * body.stature * axis)
    return out


#: Section ends that are free (not a joint): (section, 0 for the start or 1 for the end).
_FREE_ENDS = {("waist", 0), ("head", 1)} | {(dist, 1) for _, dist, *_ in LIMBS}


def _joint_caps(secs: dict, height: float = JOINT_CAP) -> dict:
    """The reported sections with flat caps where they meet at a joint (``height`` minor radii,
    `recon.bodymodel.JOINT_CAP`), as the ground truth's sections have: the fit's hemispheres there
    reach into the neighbour (a thigh's, 9 cm into the waist, took its points). Free ends keep
    their caps. Estimated-posture section accuracy, 21 bodies: 0.873 -> 0.890."""
    out = {}
    for name, s in secs.items():
        caps = s.caps.copy()
        for end in (0, 1):
            if (name, end) not in _FREE_ENDS:
                caps[end] = min(caps[end], height * float(s.radii.min()))
        out[name] = s.replace(caps=caps)
    return out


#: A shank (knee to a foot height above the detected sole) outside these multiples of the model's
#: shank for the estimated stature: the body's size or posture was misjudged (the library's fits:
#: all within; a walker whose torso came out 15 cm high, sized 1.59 m for 1.97 m: 1.8).
SHANK_RANGE = (0.6, 1.6)


def _check_leg_length(points, secs: dict, body: StandardBody) -> None:
    """`ReconError` when a fitted lower leg's sole lies too far from its knee for the body's size
    (`SHANK_RANGE`): the fit is made again from the next torso candidate, or refused."""
    for name in ("lower_leg_l", "lower_leg_r"):
        r = _shank_ratio(points, secs[name], body) if name in secs else None
        if r is not None and not SHANK_RANGE[0] < r < SHANK_RANGE[1]:
            raise ReconError(f"the cloud does not look like a human body, or its posture was not found: "
                             f"the {name.replace('_', ' ')} would reach {r:.1f} times the shank of a "
                             f"{body.stature:.2f} m body (its size was misjudged)")


def _check_plausible(secs: dict, body: StandardBody) -> None:
    """Reject fits whose torso is not body-shaped (a sphere, a box, a wall)."""
    w, c = secs["waist"], secs["chest"]
    for s in (w, c):
        if s.radii.max() > 0.4 or s.radii.min() < 0.03:
            raise ReconError(f"the cloud does not look like a human body (its {s.name} would be "
                             f"{2 * s.radii.max():.2f} m wide)")
    if w.radii[0] < w.radii[1]:
        # a waist is wider than deep (ANSUR II: 0.31 x 0.22 m; the library's fits 1.3-1.7 x): deeper
        # than wide, the fit took the body's front-back for its left-right (a walker's stride for
        # legs spread apart)
        raise ReconError(f"the cloud does not look like a human body, or its posture was not found: the "
                         f"fitted waist would be deeper ({2 * w.radii[1]:.2f} m) than wide "
                         f"({2 * w.radii[0]:.2f} m)")
