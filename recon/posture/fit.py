"""Posture estimation (paper section 2): match the body model to the volume data, then adjust it on the points.

The steps, as the paper gives them, with the choices it leaves open (each one a `FitParams` field):

0. Facing (not in the paper, whose subjects face the camera; `fit_facing`): the cloud is turned
   about the vertical to a facing read from its own shape (`facing_frame`: across the shoulders
   along x, the feet pointing to -y), fitted there, and the fit turned back, so that a scan turned
   about the vertical gets the same fit, turned (the searches below run over finite sets of
   directions on an axis-aligned voxel grid: without it, a scan turned 60 or 250 degrees came
   out differently, 73 of 84 library runs meeting issue 4's targets, 2 wrong). Where the feet
   show the front (`feet_forward`), the fit takes front and back from them (step 6). When a fit
   is refused, leaves `fit_facing_retry` sections unfitted or explains fewer than
   `fit_min_coverage` of the points, the cloud is fitted turned by 90, 180 and 270 degrees too, and
   the fit with fewest sections unfitted, then most points explained, is kept (`_fit_facings`).
1. Volume data (`recon.posture.volume`): voxel size from the sparsest part's density, clamped to
   [`voxel_min`, `voxel_max`]. The volume and the coarse match (steps 2-4) use at most
   `match_max_points` of the points, the fine adjustment (step 5) up to `fit_max_points`: a scan
   finer than 10 mm is matched on a coarser volume, then adjusted on its own points (coarse to fine:
   the match's cost no longer grows with the scan's density). Given the points' view directions,
   the inside voxels are those behind the surface every camera saw (`voxel_views`, not in the
   paper, whose volume holds what the contours enclose): a body turned in the scanner shows the
   cameras its trunk's sides, its front and back along the lines of sight, and gaps that wide in
   the contours enclose nothing. Perspective heads' lines diverge, and behind both views lies also
   the space their shadows share beyond the body (below the soles, under a raised thigh): a loose
   bound there, which did not cost the fit (docs/tuning.md, `voxel_views`).
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
   A roll taken from the legs competes only when the waist, measured on the points, comes out
   wider than deep (`match_legs_roll_wide`; a waist is wider than deep): a walker's legs, split
   front-back by the stride, gave a roll that won by 0.002 of the points, was resized 1.61 -> 2.14 m
   and refused. The torso's radii are then measured on the points.
3. Sections from the chest outwards: chest (about the chest joint, within 20 degrees of the torso),
   head (about the neck, within 70 degrees of the chest's axis but at most `match_head_max_side`
   sideways: the neck's lateral flexion; a raised arm beside the head otherwise takes it), then thighs and lower legs, then upper arms and forearms (the paper does
   the arms before the legs; we place the legs first because hanging hands reach down beside the
   thighs). Where the paper does not say how a limb's direction is searched, each limb chain is
   searched on a sphere of `match_directions` directions for its proximal section, the best
   `match_beam` of them are extended by the same search for the distal section (elbow or knee bend
   at most `match_max_bend` degrees, the limb pointing at most `match_max_adduction` across the
   body; a thigh rising above the torso's horizontal by more than `match_thigh_max_rise` only by
   flexing front or back, a shin never above its thigh), and the best chain is refined by
   Nelder-Mead. Voxels inside sections already placed weigh
   `match_claimed_weight` (the torso's to `match_claim_margin` beyond its surface, the legs' to
   `match_leg_claim_margin`: a hanging hand lies against the thigh, whose real surface is wider than
   the model's), so a limb is not fitted into the torso or folded back over itself. A limb
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
   A head that finds no crown on its own axis leans into the air above a torso matched too high
   (a seated body's upright torso 19 cm high, a child's with raised arms 10 cm: the head leaned 50
   degrees onto nothing or onto an arm): the crown is then sought on the trunk's axis
   (`match_crown_on_trunk`), the torso may only slide down to it, and the slid placement is kept
   when its model explains more points than the one where it was (the trunk's axis misses a head
   held off it, a body leaning sideways, and finds the shoulders). This holds at any size, also
   below `fit_anchor_min_stature` where the crown on the head's axis is not used (a child's larger
   head only leaves the slid torso a little high; a child with raised arms at 20 mm, matched again
   at 1.40 m with its torso 17 cm high and its head in the air, was a silent nonsense fit). A head
   above a torso matched too high can also find points by leaning onto the face or the back of
   the skull, and explain them as well (a body seen from its side): where it leans forward or back
   from the chest beyond the neck's range of flexion (`match_head_max_lean`,
   `recon.posture.match.head_in_range`), the torso slid down to the crown on the trunk's axis is
   kept whatever the points say.
4. Body size: the paper uses the average adult male. The first match uses the extent of the cloud
   along the torso axis (at least `match_min_first_stature`; every torso candidate is matched
   again, locally, at that size); then each leg chain's length (hip to
   the farthest point along its lower leg) is measured and, when the legs' median ratio to the
   standard is off by more than `match_resize_tolerance`, the model is rescaled and matched again.
   When the winner's torso is tilted (beyond `match_upright_start`), the best upright torso is matched
   again at the new size too (`match_resize_upright`): the first size, the cloud's extent along a
   tilted axis, is short (the body leaves that axis), and at that wrong size the upright torso lost
   (a heavy body at k = 3: tilted 22 degrees, arms unfitted, explained 0.58; upright at the new size
   0.64, every section fitted); it may win, or be tried when the winner fails its checks, only when
   its head finds the crown on its axis (a seated body's upright torso brought back sat 16 cm high,
   its head in the air).
   The legs are measured from the matched hips, so a torso matched too high or too low along its
   axis makes them too long or too short; crown to sole (through each leg) does not depend on
   where the torso sits. When the two disagree by more than `match_size_disagree` (adult sizes),
   the hips were misplaced and the size comes from crown to sole, and the next match hangs the
   torso from the crown (`match_resized_anchor_shift`). A child stays sized by its legs (its
   large head and short legs make the two disagree by nature), but its size from crown to sole is
   matched too and is the first pose tried when the fit at the legs' size fails its checks: a
   child matched at the first size of 1.5 m can measure its legs from hips placed too low, and at
   the size they give its trunk and head no longer fit; the next pose tried was the first size's,
   both lower legs listed, knees 18 cm off. It is tried first when its model explains more points
   than the legs' by `match_crown_first_margin`: a short adult (under `fit_anchor_min_stature`)
   has legs short for its trunk, and sized from them its trunk and head do not fit (a 1.29 m
   adult sized 1.10 m from its legs, its neck 8 cm off). Crown to sole is measured over
   the coarse model: where a joint bends (a knee, the head on the trunk) the model's segment before
   it, not the points, sets where the next one hangs, so that segment's unseen part (its length x
   (1 - cos bend)) is taken out of the measured and the model lengths (`recon.posture.match.size_ratios`).
   (`match_size_from_crown` = 1 always sizes adult bodies from crown to sole; off by default: on
   the shipped library it fixes some k = 3 sizes but misplaces a seated and a squatting body.)
   When the legs size an adult body but crown to sole differs from them by more than
   `match_resize_tolerance`, the body is matched at both sizes and the match explaining more points
   is kept (`match_size_both`: a walker 1.97 m tall, legs 2.18 m, crown to sole 2.02 m; the 2.02 m
   match explained 0.869 of the points against 0.836). Legs cut from the scan (partial bodies) are
   told from whole ones by the trunk, crown to the crotch seen in the points, `recon.posture.match.CROWN_CROTCH`
   = 0.52 statures (ANSUR II): when both leg chains measure under `match_leg_trunk_min` of it, the
   trunk sizes the body and the lower legs are listed (a walker without its lower legs had been
   judged 1.22 m tall, true 1.71; now 1.68), unless the scan shows feet (`feet_forward`: soles
   reaching in front of their ankles by at least `FEET_MIN`): legs ending in feet are whole,
   however short against the trunk (a short heavy body, 1.27 m, matched at the first size of
   1.5 m measured its whole legs under 0.8 of its trunk: both lower legs listed, knees 18-20 cm
   off).
5. Fine adjustment on the points (paper 2.3(2)): each point within `fit_near_distance` of a section's
   surface is given to the nearest section; each section's axis (position, direction, roll) is
   adjusted by bounded least squares on the point-to-surface distances, its radius set to the mean
   distance of its points from the axis, and its free end (head top, fingertips, sole) found from
   the points nearer the axis than `fit_end_threshold` times the radius (none: the end is open and
   the length kept). Joints are then placed where adjacent axes meet (bent joints) or along the
   axis at the model's proportions (straight joints, and a joint whose distal section is
   unfitted; an elbow bent less than 35 degrees counts as straight); a knee whose ankle was found
   from the sole closes the triangle hip-knee-ankle with the model's thigh : shank ratio and the
   bend of the fitted axes (`recon.posture.joints.knee_between`: where two nearly straight axes meet is ill-defined);
   likewise an elbow bent less than 35 degrees whose wrist was placed from the seen fingertips, when
   shoulder to wrist measures more than `fit_arm_size_tolerance` off the model's arm (the body's size
   was misjudged: `recon.posture.joints.elbow_between`);
   the chest's top end is aimed at the fitted head (within 25 degrees of the waist's axis; the arms
   beside it fix the chest's own direction poorly), then centred between the sides of the neck
   (`recon.posture.adjust._neck_shift`), and the shoulders turn with it; the hips ride with the waist
   (moved and turned with it, then taken onto the thighs' axes). The torso, head and legs slide along the torso
   axis (at most `fit_max_shift`) so that the neck lies a standard head length below the detected
   crown (a leg section turned more than 45 degrees from that axis, a thigh held level, slides
   along its own axis only: it stays on its points), and the neck and head follow the crown up to
   `fit_anchor_max_shift` further up; the arms stay on their points and only the shoulders follow,
   along the upper arms, rising with an arm raised above the horizontal (`recon.posture.adjust._move_shoulders`). A
   wrist whose fingertips are seen lies midway between a hand length before them and a model
   forearm past the elbow (the two err in opposite ways when the body's size or proportions are
   misjudged); a hand resting on the thigh or hip, whose points went to those sections, is
   followed along the forearm's axis (`recon.posture.joints._fingertip`).
6. Front and back, hence left and right, come from the data, never from the scanner: the feet
   point forward from the ankles, read on the whole cloud before the fit (`feet_forward`, step 0).
   Where the scan shows no feet that say so (legs cut from the scan, a deep squat on tilted
   feet), the fitted sections vote (`recon.posture.joints.front_sign`): feet point
   forward from the shins, knees bend backward, hips bend forward. The foot is the lowest part of
   the leg chain (against the scanner's +z), not the fitted shin's end, which in a sparse scan
   falls short of the sole onto the calf (a calf bulges backwards: left and right came out swapped
   at 20-30 mm). Only the leg sections the scan shows vote; when one is missing or none votes, the
   head and chest vote too (`recon.posture.joints._trunk_vote`: the face and the chest stick out in front of
   their sections' axes; it agreed with the legs on all 42 library runs at k = 1 and 3). A scan
   rotated about the vertical gives the same fit.
7. Checks: a limb section whose volume score is below `match_min_section_score` or whose surface
   cells hold too few points (`fit_min_section_cover`) is unfitted: missing from the scan (what hangs
   from it stands on its own points and checks: a thigh held level, seen from the front, holds no
   inside voxels while its lower leg is seen well); a section listed by the checks below was placed
   wrongly, and what hangs from it is listed too;
   so is an arm section both poorly covered (`fit_doubt_cover`) and poorly fitted
   (`fit_doubt_rms`), or very poorly covered (`fit_doubt_min_cover`): an arm matched onto the torso's side or a half-seen arm is listed, with a
   warning, rather than placed wrongly. Before that check, a doubted forearm, and a lower leg left
   off its points (`fit_min_points`, `fit_min_section_cover`), is searched again on the points from
   its elbow or knee (`recon.posture.adjust.research_distal`: a forearm against the body merges with
   the trunk in a coarse volume and is sent into flesh the torso's column does not hold; legs seen
   from their sides merge into one slab, and a lower leg is matched across to the other ankle) and
   kept when the check no longer doubts it and its axis does not run inside another section
   (`recon.posture.adjust._inside_others`: an unseen forearm pointed at the cameras took the neck's
   points). An arm section whose axis comes within `fit_arm_clearance` of its radii of the
   trunk's fitted columns is listed (`_on_trunk`; also after `recon.posture.reach`): an arm against the
   body keeps its axis a radius outside the skin, and one nearer is a patch of the trunk's own
   surface (scans without an arm found a forearm across the chest, an upper arm down its front).
   A section in empty voxels whose seen surface fits it (shell
   score at least `match_min_shell_score`) is kept, and so is a leg section whose fitted surface the
   points cover (`fit_leg_seen_cover`, `fit_leg_seen_rms`: a thigh raised level, seen from the
   front and above, encloses no inside voxels). An upper arm raising its elbow behind the
   shoulder (pointing up, and more backwards than sideways or upwards: not anatomy) was fitted onto
   the shoulder of a misplaced torso and is listed, and so is a thigh pointing up within 60 degrees
   of the torso's axis (a hip flexed past its active range), a lower leg pointing above the
   horizontal (`_shank_up`: the ankle above the knee), and a lower leg whose chain, thigh's
   start to sole, runs across the body more than `match_max_adduction` of its length (`_leg_across`:
   the match searches no such chain; a lower leg cut from the scan was dragged onto the other
   knee). A fit whose sections (all placed ones) explain fewer than
   `fit_min_coverage` of the points within `fit_coverage_distance`, or with more than
   `fit_max_unfitted` sections unfitted, or whose head is unfitted although the scan shows one above
   the neck (`_head_seen`: the head, whose crown pins the torso along its axis, was not found, so the
   torso was misplaced), failed: the fit is made again from the next torso
   candidate (up to `match_alternatives`, turned by at least `match_alt_min_turn` or moved), and
   when none passes the cloud is refused (`ReconError`): a wrong coarse pose is never returned
   silently as a fit. The points explained are one half of the test; the other is whether the
   model is where the cameras saw it (`recon.posture.seen`, given the points' view directions): the
   final fit, drawn from each head, shows it surfaces, and of those where the head saw a point, at
   least `fit_min_agreement` must have a point within `fit_agreement_tolerance` of their depth, for
   the trunk (waist, chest, head) and for the limbs apart, or the cloud is refused (summed over
   all sections, the limbs' agreement hid a torso placed 11-24 cm off). A model placed wrongly
   inside the body's outline explains the points
   nearly as well as a right one, but shows the cameras surfaces where they looked through to
   others, or saw others in front. A fit with left and right swapped shows the cameras the same
   surfaces: this check cannot see it. A refused cloud is fitted once more, on the volume's
   lattice shifted by half a voxel (`fit_regrid`; not in the paper): the binary voxels make the
   match chaotic (a change of a few points can change the fit), so another discretization of the
   same points is another draw; its fit passes the same checks or the first refusal stands.
8. The chest's top (the neck) is centred between the sides of the neck seen in the points, the
   head and shoulders following (`recon.posture.joints.centre_neck`). The joints are the rig's (the body
   file format's), placed off the sections' ends and axes where the rig's lie
   (`recon.posture.bodymodel.JOINT_OFFSET`); the clustering cuts where the sections meet, at the
   fit's seams (`recon.posture.joints.place_seams`), not at the joints. An elbow or knee whose distal
   section is unfitted is not reported (`_reported_joints`: only the proximal section's model length
   would place it). The sections reported in the
   `BodyFit` meet where the body file's section labels change, which is not always at a joint: the
   torso splits into waist and chest at `recon.posture.bodymodel.TORSO_SPLIT_CROTCH` of the way from the crotch seen in
   the points to the chest joint (with the hips flexed, no crotch: at `TORSO_SPLIT` of the waist
   column; `recon.posture.joints.split_torso`), the thighs start no higher than `CROTCH_SPLIT` thigh lengths
   above the crotch seen in the points (`recon.posture.joints.split_hips`), the lower legs start
   `KNEE_SPLIT` statures below the knees, sections meeting at a joint have flat caps (`JOINT_CAP`),
   and the reported upper arms and lower legs are deeper front to back than across, the upper arm
   with a cap over the shoulder (`recon.posture.joints.shape_limbs`: the deltoid is upper arm, the calf lies
   behind the shin). The clustering separates the sections there.

The code: `recon.posture.match` (steps 2-4), `recon.posture.adjust` (step 5), `recon.posture.joints` (joints, front and
back, reported sections: steps 5, 6, 8); the entry point and the checks (step 7) are here; the
parameters are `recon.params.FitParams`.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .. import ReconError
from .bodymodel import LIMBS, StandardBody, kind_of
from ..cloud import check_points
from ..geometry import rotvec
from .adjust import (anchor_on_head_top, arm_doubtful, fine_adjust, fit_section, research_distal, section_cover,
                     too_few)
from .joints import (SHANK_RANGE, centre_neck, front_sign, joint_caps, place_joints, place_seams, shank_ratio,
                     split_hips, split_knees, split_torso, swap_sides)
from .match import Pose, Scorer, coarse_match, explained_fraction, waist_wider_than_deep
from ..model import BodyFit, SECTIONS
from ..params import FitParams
from .reach import reach_arms
from .seen import confirmed_parts, scan_views
from .volume import voxel_size, voxelize

__all__ = ["FitParams", "estimate_posture", "fit_section"]


def estimate_posture(points, params: FitParams | None = None, *, view_dir=None, head=None) -> BodyFit:
    """Fit the body model to a cloud: volume matching, then fine adjustment (paper section 2).

    Parameters
    ----------
    points : (n, 3) float, metres
        The cloud (any posture, any facing direction about the vertical).
    params : FitParams, optional
    view_dir : (n, 3) float, optional
        Per point direction towards its sensor: the fitted model is checked against what the
        cameras saw (`recon.posture.seen`, `fit_min_agreement`); without it, it is not. Front and
        back are read from the body's shape.
    head : (n,) int, optional
        Per point, the scanner head that measured it (needed for that check with perspective
        heads; parallel heads are told apart by their view direction).

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
    views = None if view_dir is None else _views(points, view_dir, head, params)
    try:
        fit = _fit_checked(points, params, views, 0.0)
    except ReconError as first:
        if not params.fit_regrid:
            raise
        try:   # the same points on the lattice shifted by half a voxel
            fit = _fit_checked(points, params, views, 0.5)
        except ReconError:
            raise first from None
    if fit.unfitted:
        warnings.warn(f"sections not fitted (missing from the scan, or not placed with confidence): "
                      f"{', '.join(fit.unfitted)}", stacklevel=2)
    return fit


def _fit_checked(points, params: FitParams, views, lattice: float) -> BodyFit:
    """The fit on the volume whose lattice is shifted by ``lattice`` voxels, checked against the
    cameras' view ``views`` (`_views`; None: not known) by `_check_seen`; `ReconError` when
    refused. The volume is enclosed between the views (`voxel_views`; perspective heads' views
    leave their shared shadows in, `Views.behind`)."""
    behind = views.behind if views is not None and params.voxel_views else None
    fit = _fit_facings(points, params, lattice, behind) if params.fit_facing else \
        _estimate(points, params, lattice=lattice, behind=behind)
    if views is not None and params.fit_min_agreement > 0:
        _check_seen(fit, views, params)
    return fit


def _views(points, view_dir, head, params: FitParams):
    """The cameras' depth buffers (`recon.posture.seen.scan_views`) of at most `fit_max_points` of
    the points (a 2 mm scan's pixels of a centimetre hold many), in pixels of at least a third of
    `fit_agreement_tolerance`."""
    vd = np.broadcast_to(np.asarray(view_dir, dtype=np.float64), points.shape)
    if not np.isfinite(vd).all():
        raise ReconError("view_dir must be finite (n, 3) directions, one per point")
    step = max(1, -(-len(points) // params.fit_max_points))
    return scan_views(points[::step], vd[::step], None if head is None else np.asarray(head)[::step],
                      min_pixel=params.fit_agreement_tolerance / 3)


def _check_seen(fit: BodyFit, views, params: FitParams) -> None:
    """`ReconError` when the cameras' view ``views`` (`_views`) contradicts the fitted model: of
    the surface its trunk, or its limbs, show them where they saw points, under
    `fit_min_agreement` is confirmed by a point at its depth (`recon.posture.seen.confirmed_parts`).
    A model placed wrongly inside the body's outline explains the points about as well as a right
    one (the coverage check passes it), but shows the cameras surfaces where they saw none, or saw
    them at other depths."""
    parts = confirmed_parts(fit.sections, views, params.fit_agreement_tolerance)
    part = min(parts, key=parts.get)
    if parts[part] < params.fit_min_agreement:
        raise ReconError(f"the cloud does not look like a human body, or its posture was not found: "
                         f"the scan confirms only {100 * parts[part]:.1f}% of the surface the cameras "
                         f"would see of the fitted model's {part} (a body scan: over "
                         f"{100 * params.fit_min_agreement:.0f}%)")


def _fit_facings(points, params: FitParams, lattice: float = 0.0, behind=None) -> BodyFit:
    """The fit of the cloud turned to its own facing (`facing_frame`), turned back; made again in
    every turn of 360 / `fit_facing` degrees when it is in doubt. Every facing is read from the
    cloud's shape, so a scan turned about the vertical gets the same fit, turned.

    Where the feet show the front (`feet_forward`, at least `FEET_MIN` along the facing), the fit
    takes its front from them, in every turn (`_finish`): the fit's own reading from its leg and
    trunk sections (`recon.posture.joints.front_sign`) can turn left and right round, most often
    on a body seen from its sides.

    A fit is in doubt when it is refused, leaves at least `fit_facing_retry` sections unfitted
    (more than one limb's worth: a fit that lost its way, rarely a scan missing that much), or its
    sections explain fewer than `fit_min_coverage` of the points (the check of `_finish` counts
    the sections before they are split at the joints, this the reported ones: a body matched low
    can pass that check and fail this one). Then
    the fit with fewest sections unfitted, then most points explained, of all turns is kept."""
    feet = feet_forward(points)
    R0, c = facing_frame(points, params.fit_facing_band, params.fit_facing_band_top, feet)
    front = np.array([-R0[1, 0], -R0[1, 1], 0.0])    # the facing's front (-y turned back)
    sure = abs(float(feet @ front[:2])) >= FEET_MIN
    sample = points[::max(1, len(points) // params.fit_max_points + 1)]
    n = int(params.fit_facing)
    fits, errors = {}, []
    for i in range(n):
        R = rotvec(np.array([0.0, 0.0, 2 * np.pi * i / n])) @ R0
        try:
            # rounded to 1 nm: the same cloud turned differently comes out equal to the last bit
            # (the volume's voxels and the searches would otherwise see different rounding)
            turned = _estimate(np.round((points - c) @ R.T, 9), params, front=R @ front if sure else None,
                               lattice=lattice, behind=None if behind is None else
                               (lambda x, R=R: behind(x @ R + c)))
        except ReconError as e:
            errors.append(e)
            continue
        fit = turned.moved(R.T, c)
        fits[i] = (-len(fit.unfitted), explained_fraction(sample, fit.sections, params.fit_coverage_distance), fit)
        if i == 0 and -fits[i][0] < params.fit_facing_retry and fits[i][1] >= params.fit_min_coverage:
            return fit
    if not fits:
        raise errors[0]
    return max(fits.values(), key=lambda f: f[:2])[2]


def _estimate(points, params: FitParams, front=None, lattice: float = 0.0, behind=None) -> BodyFit:
    """`estimate_posture` on checked points, as they lie; ``front`` (3,): where the body faces, when
    known (None: read by the fit, `recon.posture.joints.front_sign`); ``lattice``: the volume's
    lattice shifted by this fraction of a voxel (`recon.posture.volume.voxelize`'s ``offset``);
    ``behind``: whether positions lie behind every camera's seen surface, in these points' frame
    (`recon.views.Views.behind`; given, the volume is enclosed between the views)."""
    times = {}
    t0 = time.perf_counter()
    rng = np.random.default_rng(params.fit_seed)
    work = points if len(points) <= params.fit_max_points else \
        points[np.sort(rng.choice(len(points), params.fit_max_points, replace=False))]
    # coarse to fine: the volume and the match on at most `match_max_points` (a finer scan is matched
    # as a 10 mm one), the fine adjustment on up to `fit_max_points`
    coarse = work if len(work) <= params.match_max_points else \
        work[np.sort(rng.choice(len(work), params.match_max_points, replace=False))]
    size = voxel_size(coarse, params.voxel_min, params.voxel_max, k=params.voxel_density_k,
                      quantile=params.voxel_density_quantile, factor=params.voxel_spacing_factor,
                      seed=params.fit_seed)
    vol = voxelize(coarse, size, reach=params.voxel_reach, offset=lattice, behind=behind)
    scorer = Scorer(vol, params)
    times["voxelize"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    # feet in the scan: its legs are whole (`coarse_match`)
    poses = coarse_match(coarse, scorer, params, feet=bool(np.linalg.norm(feet_forward(work)) >= FEET_MIN))
    times["match"] = time.perf_counter() - t0

    # the best coarse pose; when its fit fails the checks, the next torso candidate (a wrong
    # coarse pose is retried, then refused, never returned)
    t0 = time.perf_counter()
    first = None
    for pose in poses:
        try:
            fit, unfitted = _finish(work, pose, params, front)
            break
        except ReconError as e:
            first = first or e
    else:
        raise first
    times["fine"] = time.perf_counter() - t0
    fit.times.update(times)
    return fit


#: The feet, read at the bottom of the cloud (`feet_forward`), metres above its lowest point: the
#: soles and toes lie below ``SOLE``, the ankles (the lower shins) between ``ANKLE``; an adult's
#: ankle joint is 7-8 cm above the sole (Winter: 0.043 statures), a child's 4-5 cm. The toes
#: reach 12-18 cm in front of the ankle, the heel 3-5 cm behind it.
SOLE, ANKLE = 0.03, (0.08, 0.12)

#: The feet show front and back when the soles lie on average at least this far (metres) in front
#: of (or behind) the nearest ankle point (feet seen whole: 3-10 cm; the stumps of lower legs cut
#: from the scan, deep squats on tilted feet: under 2 cm); below it the cloud's third moment turns
#: the facing and the fit reads front and back from its sections.
FEET_MIN = 0.02


def feet_forward(points) -> np.ndarray:
    """(2,) where the feet point, horizontally: the mean offset, metres, of the points at the soles
    (within `SOLE` of the cloud's lowest point) from the nearest point at the ankles (`ANKLE` above
    it; at most 0.3 m away, else not counted); zero when the scan shows fewer than 10 of either.

    A foot reaches far in front of its ankle (the toes) and little behind it (the heel), so the
    soles' offsets point forward on average whatever the legs do: a stride splits them front and
    back, a squat or a seat bends them, a body turned in the scanner is seen from its sides; the
    feet still point forward from their ankles (the nearest ankle point is the foot's own)."""
    from scipy.spatial import cKDTree

    z = points[:, 2] - points[:, 2].min()
    sole = points[z < SOLE, :2]
    ankle = points[(z > ANKLE[0]) & (z < ANKLE[1]), :2]
    if len(sole) < 10 or len(ankle) < 10:
        return np.zeros(2)
    d, i = cKDTree(ankle).query(sole, distance_upper_bound=0.3)
    ok = np.isfinite(d)
    return (sole[ok] - ankle[i[ok]]).mean(axis=0) if ok.sum() >= 10 else np.zeros(2)


def facing_frame(points, band: float = 0.70, top: float = 0.85, feet=None) -> tuple[np.ndarray, np.ndarray]:
    """The turn about the vertical that brings a body to the facing read from its own shape.

    Across the shoulders is a body's widest horizontal spread in nearly every posture: the points
    between ``band`` and ``top`` of the cloud's height are turned so that their principal
    horizontal direction is +x (arms held forward at the shoulders can turn it; the match searches
    the torso's turn about the vertical anyway). Front and back: the feet point forward
    (`feet_forward`), turned to -y, the facing of the standard body; where they say too little
    (less than `FEET_MIN`: no feet in the scan, or the stumps of lower legs cut from it), the third
    moment of the whole cloud along y is made negative (limbs held forward, a squat's knees stick
    out in front; alone, it turns strides round, whose legs split front and back). Both depend on
    the cloud's shape only, so a cloud turned about the vertical (and moved sideways) comes to the
    same place. Where the feet decide (`FEET_MIN`), the fit takes its front from them
    (`_fit_facings`); elsewhere it reads front and back from its own sections
    (`recon.posture.joints.front_sign`).

    Parameters
    ----------
    points : (n, 3) float, metres
    band, top : float
        Fractions of the cloud's height bounding the slab read (0 <= band < top <= 1); fewer than
        10 points there: the whole cloud is read.
    feet : (2,) float, optional
        `feet_forward` of ``points``, if already measured.

    Returns
    -------
    R : (3, 3) float
        Rotation about +z.
    c : (3,) float
        The cloud's horizontal centroid (z = 0); the turned cloud is ``(points - c) @ R.T``.
    """
    if not 0 <= band < top <= 1:
        raise ReconError(f"parameters fit_facing_band={band!r}, fit_facing_band_top={top!r}: must "
                         f"satisfy 0 <= fit_facing_band < fit_facing_band_top <= 1")
    c = np.array([*points[:, :2].mean(axis=0), 0.0])
    z = points[:, 2]
    lo, hi = z.min() + np.array([band, top]) * (z.max() - z.min())
    sel = (z >= lo) & (z <= hi)
    xy = points[sel, :2] if sel.sum() >= 10 else points[:, :2]
    xy = xy - xy.mean(axis=0)
    _, vec = np.linalg.eigh(xy.T @ xy)
    ax = vec[:, 1]                                   # widest direction
    fwd = np.array([-ax[1], ax[0]])                  # +y of the turned frame
    ahead = float((feet_forward(points) if feet is None else feet) @ fwd)   # > 0: the feet point to +y
    if abs(ahead) < FEET_MIN:
        ahead = float(np.mean(((points[:, :2] - c[:2]) @ fwd) ** 3))
    if ahead > 0:
        ax, fwd = -ax, -fwd
    R = np.array([[ax[0], ax[1], 0.0], [fwd[0], fwd[1], 0.0], [0.0, 0.0, 1.0]])
    return R, c


def _finish(work, pose: Pose, params: FitParams, front=None):
    """Fine adjustment, front and back (from ``front`` (3,), where the body faces, when given),
    checks and joints of one coarse pose: (BodyFit, unfitted); `ReconError` when the result is not a
    body (too few sections, too few points explained)."""
    secs, resid, counts = fine_adjust(work, pose, params)
    secs = anchor_on_head_top(secs, pose.body, params)
    secs, resid, counts, researched = research_distal(work, secs, resid, counts, pose.body, params)

    coarse_secs = dict(pose.sections)
    coarse_scores = {k: v for k, v in (pose.section_scores or {}).items() if k not in researched}
    shell_scores = dict(pose.shell_scores or {})
    # front and back from the data: relabel left/right when the provisional front was the back. The
    # legs vote only with sections the scan shows (the checks below, those not depending on the
    # front): a lower leg cut from the scan, placed in empty voxels, points anywhere, and its knee
    # "bend" voted the body round (standing without its lower legs: wrists 52-145 cm off)
    cover = section_cover(work, secs, params.fit_coverage_distance)

    def unseen(n):
        # the checks that do not depend on the front: too few points, too little of the surface
        # covered, or matched in empty voxels (a leg section kept when its fitted surface is seen)
        return (too_few(counts.get(n, 0), cover.get(n, 0.0), params)
                or (coarse_scores.get(n, 1.0) < params.match_min_section_score
                    and shell_scores.get(n, -1.0) < params.match_min_shell_score
                    and not (kind_of(n) in ("thigh", "lower_leg")
                             and cover.get(n, 0.0) >= params.fit_leg_seen_cover
                             and resid.get(n, np.inf) <= params.fit_leg_seen_rms)))

    missing = {n for n in secs if kind_of(n) in ("thigh", "lower_leg") and unseen(n)}
    missing |= {dist for prox, dist, *_ in LIMBS if prox in missing}
    sign = front_sign(work, {k: v for k, v in secs.items() if k not in missing}, pose.R) if front is None \
        else (1.0 if pose.R[:, 1] @ front < 0 else -1.0)
    if sign < 0:
        secs = {swap_sides(k): v.replace(name=swap_sides(k)) for k, v in secs.items()}
        resid = {swap_sides(k): v for k, v in resid.items()}
        counts = {swap_sides(k): v for k, v in counts.items()}
        cover = {swap_sides(k): v for k, v in cover.items()}   # the same surfaces, renamed
        coarse_secs = {swap_sides(k): v.replace(name=swap_sides(k)) for k, v in coarse_secs.items()}
        coarse_scores = {swap_sides(k): v for k, v in coarse_scores.items()}
        shell_scores = {swap_sides(k): v for k, v in shell_scores.items()}

    back = sign * pose.R[:, 1]
    unfitted = tuple(n for n in SECTIONS if unseen(n)
                     or (kind_of(n) == "upper_arm" and _arm_behind(secs[n].axis, pose.R, back))
                     or (kind_of(n) == "thigh" and _thigh_up(secs[n].axis, pose.R))
                     or (kind_of(n) == "lower_leg" and _shank_up(secs[n].axis, pose.R))
                     or (kind_of(n) == "lower_leg" and _leg_across(n, secs, params.match_max_adduction))
                     or not np.isfinite(resid.get(n, np.nan))
                     or (kind_of(n) in ("upper_arm", "forearm")
                         and arm_doubtful(cover.get(n, 0.0), resid.get(n, 0.0), params))
                     or _on_trunk(n, secs, pose.body, params))
    # an arm seen only sparsely (held towards a camera), searched as a chain from its shoulder
    secs, resid, counts, reached = reach_arms(work, secs, resid, counts, unfitted, pose.body, params, back)
    unfitted = tuple(n for n in unfitted if n not in reached or _on_trunk(n, secs, pose.body, params))
    # a distal section hangs from its proximal one: when that was placed wrongly, its position means
    # nothing; when that is only missing from the scan (its points too few, or in empty voxels: a
    # thigh held level, seen from the front), the distal section stands on its own points and checks
    wrong = {n for n in unfitted if not unseen(n)}
    unfitted = tuple(n for n in SECTIONS if n in unfitted or any(
        n == dist and prox in wrong for prox, dist, *_ in LIMBS))
    if "waist" in unfitted or "chest" in unfitted or len(unfitted) > params.fit_max_unfitted:
        raise ReconError(f"the cloud does not look like a human body: only {11 - len(unfitted)} of 11 "
                         f"body sections could be fitted")
    if "head" in unfitted and _head_seen(work, secs["chest"], pose.body, params.fit_min_points):
        # the head is in the scan (points above the neck, near the torso's axis) but was not placed:
        # the torso, which the head (the crown) pins along its axis, was misplaced
        raise ReconError("the cloud does not look like a human body, or its posture was not found: the "
                         "scan shows a head above the torso, but the head could not be fitted")
    _check_plausible(secs, pose.body)
    fitted = {k: v for k, v in secs.items() if k not in unfitted}
    for prox, dist, *_ in LIMBS:
        if prox in fitted and dist not in fitted:
            # the elbow (knee) was placed where the axes of the two sections meet; without a
            # trusted distal section it lies the model's length along the proximal one
            p = fitted[prox]
            fitted[prox] = p.replace(end=p.start + pose.sections[prox].length * p.axis)
    # whether the posture was found at all: doubted sections were placed too, and count here
    explained = explained_fraction(work, {k: v for k, v in secs.items() if counts.get(k, 0) >= params.fit_min_points},
                           params.fit_coverage_distance)
    if explained < params.fit_min_coverage:
        raise ReconError(f"the cloud does not look like a human body, or its posture was not found: "
                         f"the fitted model explains only "
                         f"{100 * explained:.0f}% of the points (a body scan: over "
                         f"{100 * params.fit_min_coverage:.0f}%)")
    _check_leg_length(work, fitted, pose.body)
    fitted = centre_neck(work, fitted)
    seams = place_seams(fitted, pose.body, back, work, arm_tolerance=params.fit_arm_size_tolerance)
    joints = _reported_joints(place_joints(fitted, pose.body, back, work, arm_tolerance=params.fit_arm_size_tolerance),
                              unfitted)
    fitted = joint_caps(split_knees(split_hips(work, split_torso(work, fitted)), seams, pose.body))
    coarse = BodyFit(sections=coarse_secs, joints=place_joints(coarse_secs, pose.body, back, work,
                                                                arm_tolerance=params.fit_arm_size_tolerance))
    return BodyFit(sections=fitted, joints=joints, seams=seams,
                   residuals={k: float(resid[k]) for k in fitted}, unfitted=unfitted,
                   coarse=coarse, times={}), unfitted


def _reported_joints(joints: dict, unfitted) -> dict:
    """``joints`` without the elbows and knees whose distal section is in ``unfitted``.

    An elbow or knee lies where its two sections meet. Without the distal one, only the proximal
    section's model length places it (`_finish`): a guess, on a limb the fit has already lost part
    of, which is better missing than silently off. The seams, where the clustering cuts, keep it."""
    drop = {mid for _, dist, _, mid, _ in LIMBS if dist in unfitted}
    return {k: v for k, v in joints.items() if k not in drop}


def _head_seen(points, chest, body: StandardBody, min_points: int) -> bool:
    """Whether the scan shows a head above the fitted ``chest`` (its top end is the neck): at least
    ``min_points`` points within a head length above the neck along the chest's axis and within the
    head's width (1.5 standard head radii) of that axis. A head cut from the scan leaves none; a head
    in the scan that the fit could not place means the torso was misplaced along its axis (a
    child's raised arms beside the head pushed the torso 10 cm up at 20 mm, and the head's column
    found only air above the neck)."""
    rel = points - chest.end
    h = rel @ chest.axis
    rho2 = np.einsum("ij,ij->i", rel, rel) - h * h
    near = (h > 0) & (h < body.section_length("head")) & (rho2 < (1.5 * body.radii("head").max()) ** 2)
    return int(near.sum()) >= min_points


def _on_trunk(name: str, secs: dict, body: StandardBody, params: FitParams) -> bool:
    """Whether the arm section ``name`` lies on the trunk's own surface: a sample of its axis nearer
    the fitted chest's or waist's surface than `fit_arm_clearance` model radii of the section, or
    inside them (a forearm's axis at 0.25, 0.5, 0.75 and 1 of its length; an upper arm's, which
    starts inside the shoulder, at 0.75 and 1: the elbow's half).

    An arm against the body (hanging beside the chest, across it, a hand on the hip) keeps its
    axis a radius outside the skin, which the trunk's columns fit to 1-2 cm; an "arm" nearer is
    a patch of the trunk's surface that its columns leave out (a breast, the shoulder blades, the
    side of the chest): scans without the arm found a forearm across the chest (walking, 134
    degrees off, wrist 55 cm off) and an upper arm down the front of the chest (arms_forward,
    elbow 32 cm off). Not an arm section: False."""
    kind = kind_of(name)
    if kind not in ("upper_arm", "forearm") or name not in secs:
        return False
    s = secs[name]
    f = np.linspace(0.25, 1.0, 4) if kind == "forearm" else np.array([0.75, 1.0])
    samples = s.start + f[:, None] * (s.end - s.start)
    clear = params.fit_arm_clearance * float(body.radii(kind).mean())
    return any(float(secs[t].coords(samples)[0].min()) < clear for t in ("chest", "waist") if t in secs)


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


def _shank_up(d: np.ndarray, R: np.ndarray) -> bool:
    """Whether a lower leg along ``d`` (3,), knee to ankle, points above the horizontal (``R``'s
    third column up): the ankle above the knee needs the hip flexed more than 90 degrees plus the
    knee's bend, beyond a straight leg's raise. Such a lower leg was fitted onto an arm: seated
    bodies whose thigh was not found came out with a lower leg up the hanging arm, ankle 1.2-1.4 m
    off, not listed."""
    return float(d @ R[:, 2]) > 0.0


def _leg_across(name: str, secs: dict, max_adduction: float) -> bool:
    """Whether the leg chain ending in the lower leg ``name`` runs across the body: from its thigh's
    start to its sole, more than ``max_adduction`` (cosine) of its length toward the other hip. The
    coarse match searches no such chain (`match_max_adduction`), so a fitted one was dragged across
    by the fine fit onto the other leg's points: a walker's left lower leg cut from the scan, placed
    in empty voxels and kept as a leg seen on its surface, ended on the right knee, ankle 74 cm
    off."""
    other = {"lower_leg_l": "thigh_r", "lower_leg_r": "thigh_l"}[name]
    thigh = "thigh" + name[len("lower_leg"):]
    if thigh not in secs or other not in secs or name not in secs:
        return False
    out = secs[thigh].start - secs[other].start
    if np.linalg.norm(out) < 1e-9:
        return False
    chain = secs[name].end - secs[thigh].start
    return bool(chain @ out / np.linalg.norm(out) < -max_adduction * np.linalg.norm(chain))


def _check_leg_length(points, secs: dict, body: StandardBody) -> None:
    """`ReconError` when a fitted lower leg's sole lies too far from its knee for the body's size
    (`SHANK_RANGE`): the fit is made again from the next torso candidate, or refused."""
    for name in ("lower_leg_l", "lower_leg_r"):
        r = shank_ratio(points, secs[name], body) if name in secs else None
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
    if not waist_wider_than_deep(w):
        # the fit took the body's front-back for its left-right (a walker's stride for legs spread
        # apart)
        raise ReconError(f"the cloud does not look like a human body, or its posture was not found: the "
                         f"fitted waist would be deeper ({2 * w.radii[1]:.2f} m) than wide "
                         f"({2 * w.radii[0]:.2f} m)")
