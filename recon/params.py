"""Parameters of the reconstruction stages: one frozen dataclass per stage, and their bundle.

Every field has the paper's value as default where the paper gives one (its section in the comment);
where the paper is silent the choice is documented on the field. `ReconParams.from_overrides` sets
fields by their flat, globally unique names, as the CLI's ``--param name=value`` does.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields

from bodyscan._params import check_fields, coerce

from . import ReconError

#: Losses of `scipy.optimize.least_squares` (``fit_loss``).
FIT_LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


@dataclass(frozen=True)
class ClusterParams:
    """Clustering of the points into body sections (paper section 3).

    The measurements behind the chosen values are in docs/tuning.md.

    Attributes
    ----------
    t_d : float
        Simple clustering: a point joins every section whose model surface is nearer than
        ``t_d`` times the section's width (paper sections 3 and 4.2: 30 %).
    mesh_theta, mesh_h : int
        Cells of the (theta, h) mesh on each section's side surface (paper section 4.2: 10 x 10).
    t_n_factor : float
        T_n = the cell histogram's maximum frequency times this factor (paper section 4.2; the
        factor is lost in the text). A cell is single-peaked, and kept whole, when more than T_n
        points lie within ``near_band`` of its Otsu threshold. Chosen by a sweep.
    otsu_bins : int
        Bins of each cell's histogram of r, spanning that cell's r range (paper silent).
    near_band : float
        "r near the threshold": within this many bin widths of it (paper silent).
    min_cell_points : int
        Cells with fewer points are kept whole (too few to tell two peaks; paper silent).
    neighbor_radius : float
        Radius of the neighbourhood used by the multi-section rules, metres (paper section 3.2,
        value not given). 0 means automatic: ``neighbor_spacing`` times the median
        nearest-neighbour distance of the cloud.
    neighbor_spacing : float
        Automatic neighbour radius in median point spacings (used when ``neighbor_radius`` is 0).
    seam_width : float
        Joint rule: points of the proximal section with a point of the distal one nearer than this
        many median point spacings stay in both sections, as the seam (paper 3.2: "sufficiently
        few" points in both; the paper gives no number). With a fixed ``neighbor_radius``, the
        spacing is taken as a third of it.
    joint_reach : float
        A point is "at the joint" of two adjacent sections when it is nearer to the joint than
        this times the larger of the two widths (paper silent: it says "at a joint").
    joint_plane_weight : float
        Joint rule: weight of the model's joint plane against the erosion fronts (paper silent:
        its rule uses the neighbours only; 0 keeps that). See `recon.clustering.cluster.resolve_joints`.
        The plane passes through the distal section's end, or through the middle of the two
        columns' overlap where they overlap (``joint_plane_overlap_middle``). Chosen.
    side_joint_planes : bool
        Joint rule: at a side joint whose joint lies beside the proximal column (the shoulders),
        the plane through the joint across the distal axis also votes (chosen; paper silent; see
        `recon.clustering.cluster.joint_plane_score`). The hips, whose joint lies beyond the waist's
        column, keep no plane; the plane votes only along the distal column, not in its cap.
    three_keep_nearest : float
        Three-or-more rule: a point that lies on a section's surface (nearer than this many of
        that section's widths) copies only from a neighbour that is also in that section
        (chosen; paper 3.2 says "the nearest point with fewer labels"; 0: the paper's rule).
        Without it, arm points in chest, waist and arm copy the labels of the nearest torso point
        and are meshed with the chest; the limit is needed, as a misplaced section's surface is no
        evidence.
    joint_plane_overlap_middle : bool
        The joint plane through the middle of the two columns' overlap, where they overlap, rather
        than through the distal section's end (chosen).
    mitre_band : float
        Joint plane: it is the mitre of the two axes only where the joint lies within this many
        widths of the distal section's end; where the joint lies further inside the distal
        section, the plane is the proximal section's cross-section, and vice versa (chosen; see
        `recon.clustering.cluster.joint_plane_score`: the spine bends at the chest joint, 0.46 widths above
        the chest section's lower end, and the body below the bend follows the waist).
    joint_plane_bones : bool
        Joint plane at the end joints (chest, neck, elbows, knees): the bones' directions from the
        fit's seams (`recon.model.BodyFit.seams`) instead of the columns' axes (paper silent; see
        `recon.clustering.cluster.joint_plane_score`). The body file's sections change where the skinning
        changes bones; the estimated waist's column stands more upright than the lumbar spine (the
        chest joint lies behind the pelvis joint), and its plane cut the front of the chest too
        low: truth waist labelled chest at the front, truth chest labelled waist at the back.
    side_plane_tilt : float
        The shoulders' plane (``side_joint_planes``), the arm's cross-section through the joint,
        is tilted toward the body's midline by this (the tangent of the tilt; paper silent; see
        `recon.clustering.cluster.joint_plane_score`, guarded by
        `recon.clustering.cluster._tilt_to_midline` against arms along the shoulder line): the
        body file's upper arm includes the deltoid, which caps the joint from outside, and its
        chest reaches below the joint on the armpit's side. Chosen.
    claim_across_joints : float
        A point claimed by one section alone, inside the column of an adjacent section and on that
        section's side of their joint plane (within this many widths of the distal section), goes
        to the adjacent section (paper silent; 0: off; see `recon.clustering.cluster.claim_across_joints`).
        The T_d shell misses the body where it lies deeper than T_d inside a column near a joint:
        the base of the neck and the trapezius inside the chest's column are claimed by the head
        alone, likewise around the knees. Chosen.
    hip_planes : bool
        With the hips flexed (no crotch found along the thighs, `recon.posture.joints.find_crotch`), the
        joint rule's plane at the hips is the groin's crease (paper silent; see
        `recon.clustering.cluster.joint_plane_score` and `recon.clustering.cluster.flexed_hip_plane`): the mitre of the
        waist's downward axis and the thigh's axis, tilted out by ``hip_plane_tilt``,
        ``hip_plane_offset`` thigh widths past the hip joint. Without it (False), a flexed hip whose
        joint lies within the waist's length gets the shoulders' plane, the thigh's cross-section
        through the joint, which gave the lower belly above a squatting thigh to the thigh; upright
        hips keep no plane either way.
    hip_plane_tilt : float
        Outward tilt of the hips' planes, the tangent (measured on the labels, not swept).
    hip_plane_offset : float
        Thigh widths past the hip joint along the plane's normal (measured on the labels, as the
        tilt).
    max_rounds : int
        Rounds of the three-or-more rule, of the two-section rule and of label adoption before
        the remaining points are settled by their distance to the model (paper silent; the joint
        rule is solved exactly, see `recon.clustering.cluster.resolve_joints`).
    adopt_unlabeled : bool
        Points left in no section after refinement take the sections of their nearest labelled
        neighbour within the neighbour radius (paper silent; it leaves them out).
    """

    t_d: float = field(default=0.30,  # paper 3, 4.2: 30 % of each section's width
        metadata={"help": "simple clustering: a point joins every section whose model surface is nearer than this times the section's width (T_d)", "unit": "", "range": (0.01, 2.0)})
    mesh_theta: int = field(default=10,  # paper 4.2
        metadata={"help": "cells around each section's side surface (theta) for the T_n refinement", "unit": "", "range": (1, 1000)})
    mesh_h: int = field(default=10,  # paper 4.2
        metadata={"help": "cells along each section's axis (h) for the T_n refinement", "unit": "", "range": (1, 1000)})
    t_n_factor: float = field(default=0.5,  # paper 4.2: value lost; chosen by sweep
        metadata={"help": "T_n = the cell histogram's maximum frequency times this; a cell with more points near its Otsu threshold is kept whole", "unit": "", "range": (0, 100)})
    otsu_bins: int = field(default=16,  # paper silent
        metadata={"help": "bins of each cell's histogram of r (the Otsu threshold)", "unit": "", "range": (2, 1000)})
    near_band: float = field(default=1.0,  # paper silent, bin widths
        metadata={"help": "'near the Otsu threshold': within this many bin widths of it", "unit": "bins", "range": (0.01, 100)})
    min_cell_points: int = field(default=12,  # paper silent
        metadata={"help": "cells with fewer points are kept whole", "unit": "", "range": (2, None)})
    neighbor_radius: float = field(default=0.0,  # paper 3.2: "a certain distance"; 0 = automatic
        metadata={"help": "neighbourhood radius of the multi-section rules; 0 = automatic (neighbor_spacing)", "unit": "m", "range": (0, 1)})
    neighbor_spacing: float = field(default=3.0,  # paper silent
        metadata={"help": "automatic neighbour radius, in median point spacings", "unit": "spacings", "range": (0.1, 100)})
    seam_width: float = field(default=1.5,  # paper 3.2, spacings
        metadata={"help": "joint rule: points of the proximal section this near the distal one stay in both (the seam)", "unit": "spacings", "range": (0.01, 100)})
    joint_reach: float = field(default=0.75,  # paper silent
        metadata={"help": "a point is at the joint of two sections within this times the larger width", "unit": "widths", "range": (0.01, 10)})
    joint_plane_weight: float = field(default=1.0,  # paper silent; 0 = the paper's erosion alone
        metadata={"help": "joint rule: weight of the model's joint plane against the erosion fronts (0 = the paper's fronts alone)", "unit": "", "range": (0, 100)})
    joint_plane_overlap_middle: bool = field(default=True,  # paper silent (chosen: see joint_plane_weight)
        metadata={"help": "the joint plane passes through the middle of the two columns' overlap, not the distal end", "unit": "", "range": None})
    mitre_band: float = field(default=0.1,  # paper silent (chosen: see above), widths
        metadata={"help": "the joint plane is the mitre of the two axes only where the joint lies within this of the distal end", "unit": "widths", "range": (0, 100)})
    side_joint_planes: bool = field(default=True,  # paper silent (chosen: see above)
        metadata={"help": "at the shoulders, the arm's cross-section through the joint also votes", "unit": "", "range": None})
    three_keep_nearest: float = field(default=0.1,  # paper silent (chosen: see above)
        metadata={"help": "three-or-more rule: a point this near a section's surface copies only from that section (0 = the paper's rule)", "unit": "widths", "range": (0, 10)})
    claim_across_joints: float = field(default=0.5,  # paper silent (chosen: see above), widths
        metadata={"help": "a point claimed by one section alone, within this of an adjacent section past their joint plane, goes to that section (0 = off)", "unit": "widths", "range": (0, 10)})
    joint_plane_bones: bool = field(default=True,  # paper silent (chosen: see above)
        metadata={"help": "joint planes at the end joints from the fitted bones, not the columns' axes", "unit": "", "range": None})
    side_plane_tilt: float = field(default=1.0,  # paper silent (chosen: see above), tangent of the tilt
        metadata={"help": "the shoulders' plane is tilted toward the midline by this (tangent of the tilt)", "unit": "", "range": (0, 100)})
    hip_planes: bool = field(default=True,  # paper silent (chosen: see above), flexed hips only
        metadata={"help": "at flexed hips, the joint plane is the groin's crease", "unit": "", "range": None})
    hip_plane_tilt: float = field(default=0.55,  # paper silent (chosen: measured on the labels, see above)
        metadata={"help": "outward tilt of the hips' planes (tangent)", "unit": "", "range": (0, 100)})
    hip_plane_offset: float = field(default=0.15,  # paper silent (chosen: measured on the labels), thigh widths
        metadata={"help": "the hips' planes lie this far past the hip joint", "unit": "thigh widths", "range": (0, 10)})
    max_rounds: int = field(default=20,  # paper silent
        metadata={"help": "rounds of the multi-section rules before the rest is settled by distance to the model", "unit": "", "range": (1, 1000)})
    adopt_unlabeled: bool = field(default=True,  # paper silent
        metadata={"help": "points in no section take the sections of their nearest labelled neighbour", "unit": "", "range": None})

    def __post_init__(self):
        check_fields(self, ReconError)
        _check(self.t_d > 0, "t_d", self.t_d, "a positive fraction of the section width")
        for name in ("mesh_theta", "mesh_h", "otsu_bins", "max_rounds"):
            _check(int(getattr(self, name)) >= 1, name, getattr(self, name), "an integer >= 1")
        _check(self.otsu_bins >= 2, "otsu_bins", self.otsu_bins, "an integer >= 2")
        _check(self.t_n_factor >= 0, "t_n_factor", self.t_n_factor, ">= 0")
        _check(self.near_band > 0, "near_band", self.near_band, "> 0")
        _check(self.min_cell_points >= 2, "min_cell_points", self.min_cell_points, ">= 2")
        _check(self.neighbor_radius >= 0, "neighbor_radius", self.neighbor_radius, ">= 0 metres")
        _check(self.neighbor_spacing > 0, "neighbor_spacing", self.neighbor_spacing, "> 0")
        _check(self.joint_reach > 0, "joint_reach", self.joint_reach, "> 0")
        _check(self.joint_plane_weight >= 0, "joint_plane_weight", self.joint_plane_weight, ">= 0")
        _check(self.mitre_band >= 0, "mitre_band", self.mitre_band, ">= 0 widths")
        _check(self.side_plane_tilt >= 0, "side_plane_tilt", self.side_plane_tilt, ">= 0")
        _check(self.claim_across_joints >= 0, "claim_across_joints", self.claim_across_joints,
               ">= 0 widths")
        _check(self.seam_width > 0, "seam_width", self.seam_width, "> 0 spacings")
        _check(self.hip_plane_tilt >= 0, "hip_plane_tilt", self.hip_plane_tilt, ">= 0")
        _check(self.hip_plane_offset >= 0, "hip_plane_offset", self.hip_plane_offset, ">= 0 widths")


@dataclass(frozen=True)
class SurfaceParams:
    """Per-section surfaces by 2D Delaunay on the model surface (paper section 3.3).

    The measurements behind the chosen values are in see above.

    Attributes
    ----------
    seam_overlap : float
        Points within this angle (radians) of theta = 0 are copied past theta = 2*pi and back,
        so that the seam gets triangles (paper 3.3, width not given).
    cap_overlap : float
        The column and cap projections overlap by this many mean radii along the axis
        (paper 3.3, width not given).
    max_edge_factor : float
        Triangles with a 3D edge longer than this times the section's median point spacing (and
        than ``max_edge_min``) are removed. 0 keeps every triangle, as the paper does: holes in
        the data are covered by a few large triangles (paper 4.2).
    hull_edge_factor : float
        Delaunay triangulates the convex hull of the projected points: triangles on the
        triangulation's boundary with an edge longer than this times the median spacing are
        peeled off, repeatedly, so that open ends and boundary concavities get no long slivers
        (paper silent; interior holes are not touched). ``proposed`` measures the edges as the
        camera saw them (``peel_same_side``) and keeps 6 spacings: on a coarse scan the flanks
        between the front and rear views stay covered; ``paper`` and ``simple`` measure in 3D and
        keep 4 (`PAPER`), where longer slivers are air.
    min_section_points : int
        A section with fewer points is skipped with a warning (paper silent).
    workers : int
        Threads triangulating the sections in parallel (numpy and Qhull release the GIL), and of
        the closed surface's KD-tree queries; the result does not depend on it. 1: one after
        another.
    open_joints : bool
        Project a section's proximal end, where it joins its parent section at a joint, onto the
        extended column instead of a cap (paper 3.3 does so for open ends): its surface then ends
        at the seam points it shares with the parent instead of closing across the joint.
    open_joint_ends : bool
        Likewise leave open a section's end where a child section continues it (neck, waist to
        chest, elbows, knees; not the shoulders and hips, where the child leaves through the
        side): a cap there would only close the body's inside across the seam (paper silent;
        part of the removal of inner triangles, so ``proposed`` only).
    fold_cos, fold_edge_factor : float
        A triangle folds against its chart when its 3D normal, with the vertex order that is
        counter-clockwise in the chart, has a cosine below ``fold_cos`` with the chart's
        projection direction (the column's radial direction, the cap's direction from its centre;
        see `recon.surface.mesh.chart_agreement`); such a triangle whose longest 3D edge is also longer
        than ``fold_edge_factor`` median spacings is removed (paper: none; ``fold_cos = -1``
        switches it off; ``proposed`` only: ``simple`` keeps the paper's surface, as for the
        inner triangles). The reason is geometric, not the length: where the surface folds back
        over the chart (curled fingers over the palm, in the forearm's column chart at 10 mm), the
        two layers' points interleave in 2D and Delaunay joins them with triangles flipped against
        the chart, in the air; a short flipped triangle turns around the fold's rim, which is
        surface, so only the long ones (longer than the hull peel's limit) are joins across the
        fold. A hole in the data, covered by the paper, is not flipped and stays covered.
        (chosen)
    carve_margin, carve_min_edge, carve_reach : float
        Free-space carving (paper: none; ``carve_margin = 0`` switches it off): every point was
        measured along a ray from its camera (``view_dir``), so a triangle that such a ray crosses
        in front of a point lying more than ``carve_margin`` median spacings behind the triangle's
        plane is air, not surface, and is removed (``proposed`` only; see
        `recon.surface.mesh.seen_through`). Only triangles with an edge longer than ``carve_min_edge``
        spacings are tested, against the points within their circumradius plus ``carve_reach``
        spacings of their centroid. It removes the flaps across armpits, crotch, curled fingers and
        under the chin where the sensor looked through them, but not the cover of a hole that no
        ray looked through (the paper's choice, ``max_edge_factor``). (chosen; ``carve_reach`` 1
        rather than 3 for speed on dense scans)
    carve_min_rays : int
        Free-space carving: a triangle is air when at least this many points' rays cross it
        (paper: none). 1 (chosen): most flaps are crossed by one ray only (within
        ``carve_reach``); raise it for clouds with many stray points.
    facing_cos, facing_min_edge : float
        View consistency (paper: none; ``facing_cos = -1`` switches it off; ``proposed`` only):
        a point is measured only where the surface faces its camera, so a triangle of real
        surface faces the camera of each of its vertices, up to the surface's turn across the
        triangle. A triangle that, turned either way, has a cosine below ``facing_cos`` with the
        viewing direction of one of its vertices (`recon.surface.mesh.view_consistency`) joins points
        seen from opposite sides across a gap (a forearm beside the hip, touching thighs, across
        an armpit) and is removed when its longest edge is also longer than ``facing_min_edge``
        spacings (shorter ones turn around a thin part's rim: fingers, silhouettes; a convex
        capsule's lowest value is about -0.14). One viewing direction for all points: no effect.
        (chosen)
    peel_same_side : float
        The boundary peel (and the far charts' ``far_max_edge``) measures a triangle whose vertices
        were seen along one axis (their unit viewing directions, turned to one side, at least this
        long on average) across the view, as the cameras saw it
        (`recon.surface.mesh.view_edge_length`): the flanks of limbs and trunk, steep to the
        cameras, are long in 3D but a grid step apart to them, where one head's samples end and
        the other's begin as well (paper: 3D, 2);
        at least the 3D length over ``peel_stretch`` (two surfaces one behind the other, a thigh
        over a calf in a squat, are near across the view too).
    cover_max_edge : float
        Metres: triangles longer than this (as their camera saw them, never below the peel's
        limit) are removed, so holes wider than it stay open (paper: every hole covered, 0).
    rejoin_edge : float
        Spacings: the points the peel and the air rules left out of every face are put back with
        triangles no longer than this on their own chart (`recon.surface.mesh.rejoin_left_out`;
        paper: 0).
    curve_edge : float
        Spacings: every edge of the open surface longer than this is split, repeatedly, at its
        midpoint lifted toward the tangent planes of its ends (`recon.surface.curve`; normals from
        `recon.surface.mesh.point_normals`, turned outward with the surface). A long flat triangle
        over the flank of a limb, which the cameras see at grazing angles, is a chord 5-9 mm inside
        the body; the split one follows it. The new vertices come after the input points
        (``Reconstruction.point_index`` -1). Paper: 0 (flat triangles). ``proposed-closed``
        closes the flat surface: its seen band is steadier on noisy scans.
    curve_min_edge : float
        Metres: no edge shorter than this is split, whatever the spacing. A chord of length L lies
        L**2 / (8 r) inside an arc of radius r: 0.3 mm for 1 cm on a 4 cm limb. On a dense, noisy
        scan (the ``scanner`` preset, 2 mm) lifting the short edges follows the noise of the
        normals, and costs time.
    concave_height, concave_mean_height, concave_min_edge : float
        Covers of concavities (paper: none; ``concave_height = 0`` switches it off; ``proposed``
        only): a triangle of surface lies in the surface's tangent planes at its vertices, up to
        the curvature: a cover of a hole in convex surface lies behind them, inside the body (the
        paper's hole covering, kept). A triangle whose centroid stands more than
        ``concave_height`` spacings in front of the tangent plane at every one of its vertices,
        or more than ``concave_mean_height`` in front of them on average
        (`recon.surface.mesh.over_concavity`; normals from `recon.surface.mesh.point_normals`, turned
        toward the cameras), bridges a concavity: the flat cover over a hole in concave surface
        (under the chin, behind the ears, the armpit, the thumb web) or surface across a gap; it
        is removed when its longest edge is also longer than ``concave_min_edge`` spacings.
    concave_neighbours : int
        Points (with itself) whose least-spread direction is a point's normal for that rule.
        (chosen; ``concave_min_edge`` 2.5 rather than 2 for speed on dense scans)
    tilt_cos, tilt_min_edge : float
        Tilted triangles (paper: none; ``tilt_cos = 0`` switches it off; ``proposed`` only): a
        triangle of the surface lies in the tangent planes at its vertices up to the surface's turn
        across it (`recon.surface.mesh.normal_agreement`, the normals of the concavity rule). A
        triangle longer than ``tilt_min_edge`` spacings whose normal has a mean ``|cos|`` below
        ``tilt_cos`` with its vertices' normals stands across the surface the data show (a cover
        spanning a curved hole, a rim face across a thin part, fingers joined across their gaps):
        the paper's spurious surface, which the data do not support. It is removed.
    orient_model_weight : float
        Orientation (paper: none, the sensor's side alone, ``0``; ``proposed`` only): a triangle
        faces the side of its vertices' mean viewing direction (unit) plus this times the section
        model's outward direction at its centroid (`recon.surface.mesh.orient_faces`). A triangle
        turned nearly edge-on to the camera that saw its corners (a limb's flank at a grazing view,
        a cover across the strip neither camera sees) cannot be told outward from inward by that
        camera: the small tilt that decides is the noise's or the triangulation's, and half such
        triangles came out flipped. With weight ``w`` the model decides where the triangle turns
        more than ``1 / w`` times as much toward or away from the model's outward direction as
        toward or away from the camera. Only the fitted sections' own charts: a hand's, a foot's
        or a far part's faces its camera alone, or its chart's own column where its cameras
        disagree (no fitted section is their surface; `recon.surface.mesh.orient_charts`). (chosen)
    """

    seam_overlap: float = field(default=0.6,  # paper 3.3, radians
        metadata={"help": "points within this angle of theta = 0 are copied across the seam", "unit": "rad", "range": (0.01, 3.14)})
    cap_overlap: float = field(default=0.35,  # paper 3.3, mean radii
        metadata={"help": "the column and cap projections overlap by this along the axis", "unit": "mean radii", "range": (0.01, 2)})
    max_edge_factor: float = field(default=0.0,  # paper 4.2: holes are covered (0 = no limit)
        metadata={"help": "triangles with an edge longer than this are removed (0 = keep all: holes covered, as the paper)", "unit": "spacings", "range": (0, 1000)})
    hull_edge_factor: float = field(default=6.0,  # paper silent; chosen (4 in PAPER and simple)
        metadata={"help": "boundary triangles with an edge longer than this are peeled off", "unit": "spacings", "range": (0.01, 1000)})
    min_section_points: int = field(default=10,  # paper silent
        metadata={"help": "a section with fewer points is skipped with a warning", "unit": "", "range": (3, None)})
    open_joints: bool = field(default=True,  # paper 3.3 (open ends), applied at joints
        metadata={"help": "leave a section's proximal end at a joint open (no cap)", "unit": "", "range": None})
    open_joint_ends: bool = field(default=True,  # paper silent
        metadata={"help": "leave a section's end open where a child section continues it", "unit": "", "range": None})
    workers: int = field(default=2,  # not a method parameter: speed only
        metadata={"help": "threads triangulating the sections, and of the closed surface's KD-tree queries (speed only, same result)", "unit": "", "range": (1, 256)})
    fold_cos: float = field(default=0.0,  # paper: none (-1 = off); chosen, see above
        metadata={"help": "fold rule: long triangles whose normal has a cosine below this with their chart are removed (-1 = off)", "unit": "", "range": (-1, 1)})
    fold_edge_factor: float = field(default=4.0,  # paper: none; chosen, spacings (= PAPER's hull_edge_factor)
        metadata={"help": "fold rule: only triangles with an edge longer than this", "unit": "spacings", "range": (0, 1000)})
    carve_margin: float = field(default=0.5,  # paper: none (0 = off); chosen, see above, spacings
        metadata={"help": "free-space carving: a triangle crossed by a camera ray to a point this far behind it is removed (0 = off)", "unit": "spacings", "range": (0, 1000)})
    carve_min_edge: float = field(default=2.0,  # chosen, spacings
        metadata={"help": "carving tests only triangles with an edge longer than this", "unit": "spacings", "range": (0, 1000)})
    carve_reach: float = field(default=1.0,  # chosen, spacings
        metadata={"help": "carving tests the points within the circumradius plus this of the centroid", "unit": "spacings", "range": (0, 1000)})
    carve_min_rays: int = field(default=1,  # chosen, see above
        metadata={"help": "carving: a triangle is air when at least this many rays cross it", "unit": "", "range": (1, None)})
    facing_cos: float = field(default=-0.4,  # paper: none (-1 = off); chosen, see above
        metadata={"help": "view consistency: long triangles with a cosine below this with a vertex's viewing direction are removed (-1 = off)", "unit": "", "range": (-1, 1)})
    facing_min_edge: float = field(default=2.0,  # chosen, spacings (= carve_min_edge)
        metadata={"help": "view consistency tests only triangles with an edge longer than this", "unit": "spacings", "range": (0, 1000)})
    concave_height: float = field(default=0.3,  # paper: none (0 = off); chosen, see above, spacings
        metadata={"help": "concavity covers: a triangle standing this far in front of every vertex's tangent plane is removed (0 = off)", "unit": "spacings", "range": (0, 1000)})
    concave_mean_height: float = field(default=0.6,  # chosen on tune62, spacings
        metadata={"help": "concavity covers: a triangle standing this far in front of its vertices' tangent planes on average is removed", "unit": "spacings", "range": (0, 1000)})
    concave_min_edge: float = field(default=2.5,  # chosen, spacings (speed on dense scans, see above)
        metadata={"help": "the concavity rule tests only triangles with an edge longer than this", "unit": "spacings", "range": (0, 1000)})
    concave_neighbours: int = field(default=8,  # chosen, points
        metadata={"help": "points (with itself) whose least-spread direction is a point's normal", "unit": "", "range": (3, 1000)})
    tilt_cos: float = field(default=0.75, metadata={
        "help": "tilted covers: a long triangle whose normal has a mean |cosine| below this with the "
                "normals estimated at its vertices is removed (0 = off)", "unit": "", "range": (0.0, 1.0)})
    tilt_min_edge: float = field(default=2.5, metadata={
        "help": "the tilt rule tests only triangles with an edge longer than this", "unit": "spacings",
        "range": (0, 1000)})
    orient_model_weight: float = field(default=0.5, metadata={
        "help": "orientation: a triangle faces its vertices' viewing direction plus this times the "
                "model's outward direction (0 = the view alone, as the paper)", "unit": "",
        "range": (0.0, 1000.0)})
    hull_edge_min: float = field(default=0.05, metadata={
        "help": "the boundary peel never removes triangles shorter than this: dense scans keep "
                "the unseen gaps at the silhouettes covered (0 = spacings alone)",
        "unit": "m", "range": (0.0, None)})
    max_edge_min: float = field(default=0.04, metadata={
        "help": "the edge limits (max_edge_factor, the feet's and far charts' far_max_edge) never "
                "remove triangles shorter than this (0 = spacings alone)",
        "unit": "m", "range": (0.0, None)})
    peel_same_side: float = field(default=0.9, metadata={
        "help": "the peel measures a triangle seen along one axis (its view directions' mean, up "
                "to sign, at least this long) across the view (above 1: in 3D)", "unit": "", "range": (0.0, 2.0)})
    peel_stretch: float = field(default=1.5, metadata={
        "help": "a triangle seen from one side counts at least its 3D length over this (a depth "
                "step is short across the view)", "unit": "", "range": (1.0, None)})
    cover_max_edge: float = field(default=0.06, metadata={
        "help": "triangles longer than this (as their camera saw them; at least the peel's limit) "
                "are removed: large holes stay open (0: all covered)",
        "unit": "m", "range": (0.0, None)})
    rejoin_edge: float = field(default=2.5, metadata={
        "help": "points the rules left out of every face are put back with triangles no longer than "
                "this, on their own chart (0 = off)", "unit": "spacings", "range": (0.0, None)})
    curve_edge: float = field(default=2.0, metadata={
        "help": "longer edges are split at midpoints lifted toward their ends' tangent planes: "
                "long triangles follow the body, not a chord (0 = flat, as the paper)",
        "unit": "spacings", "range": (0.0, None)})
    curve_min_edge: float = field(default=0.01, metadata={
        "help": "the curved subdivision splits no edge shorter than this (within 0.3 mm of a 4 cm "
                "radius; on dense scans its normals follow the noise)", "unit": "m", "range": (0.0, None)})
    far_charts: bool = field(default=True, metadata={
        "help": "mesh the points beyond T_d of every section and those the charts left out "
                "(hands, feet, unfitted sections) on charts of their own (False: the paper)",
        "unit": "", "range": (False, True)})
    far_link: float = field(default=4.0, metadata={
        "help": "far points nearer than this form one part (one chart)", "unit": "spacings",
        "range": (0.5, None)})
    far_join: float = field(default=3.0, metadata={
        "help": "meshed points within this of a far part join its chart", "unit": "spacings",
        "range": (0.0, None)})
    far_max_edge: float = field(default=4.0, metadata={
        "help": "longer triangles (as their camera saw them; at least max_edge_min, a hand's this "
                "many far_hand_spacing) leave the hands', feet's and far charts (0 = no limit)",
        "unit": "spacings", "range": (0.0, None)})
    far_hand_spacing: float = field(default=0.0075, metadata={
        "help": "hands are meshed as range images on scans with a median spacing up to this, else "
                "around their column (a range image bridges the fingers' gaps; 0: never)",
        "unit": "m", "range": (0.0, None)})
    far_view: bool = field(default=True, metadata={
        "help": "far parts are meshed as their cameras' range images (Delaunay across each camera's "
                "view) instead of around a column on their principal axis",
        "unit": "", "range": (False, True)})
    close_voxel: float = field(default=0.008, metadata={
        "help": "proposed-closed: grid step of the closed surface, at least the points' median spacing "
                "(recon.surface.closed.closed_surface)",
        "unit": "m", "range": (0.001, 0.05)})
    close_cell: float = field(default=1.5, metadata={
        "help": "proposed-closed: cell size of the sections' radial height fields",
        "unit": "spacings", "range": (0.5, None)})
    close_envelope: float = field(default=0.3, metadata={
        "help": "proposed-closed: holes are filled at most this beyond the model radius",
        "unit": "widths", "range": (0.0, None)})
    close_band: float = field(default=2.0, metadata={
        "help": "proposed-closed: grid points over the open mesh, up to this outside it (half of "
                "it inside; at least two grid steps), take their signed distance to it (0 = off)",
        "unit": "spacings", "range": (0.0, None)})
    close_carve: float = field(default=0.25, metadata={
        "help": "proposed-closed: what lies this far in front of the surface a camera saw, along "
                "its line of sight, is air and stays out of the closed surface (0 = off)",
        "unit": "spacings", "range": (0.0, None)})
    close_background: float = field(default=0.5, metadata={
        "help": "proposed-closed: what every head sees farther than this beside its silhouette (its "
                "points' image, the gaps between them closed) is air (0 = off)",
        "unit": "spacings", "range": (0.0, None)})
    close_smooth: int = field(default=12, metadata={
        "help": "proposed-closed: Taubin smoothing steps (a shrink and an inflate each) on the "
                "marching-cubes surface, against the grid's facets (0 = off)",
        "unit": "", "range": (0, 100)})
    far_min_points: int = field(default=5, metadata={
        "help": "far parts with fewer points are outliers, left out of the surface", "unit": "",
        "range": (3, None)})

    def __post_init__(self):
        check_fields(self, ReconError)
        _check(0 < self.seam_overlap < 3.14, "seam_overlap", self.seam_overlap, "in (0, pi) radians")
        _check(0 < self.cap_overlap <= 2, "cap_overlap", self.cap_overlap, "in (0, 2] mean radii")
        _check(self.max_edge_factor >= 0, "max_edge_factor", self.max_edge_factor, ">= 0 (0 = no limit)")
        _check(self.hull_edge_factor > 0, "hull_edge_factor", self.hull_edge_factor, "> 0")
        # below a spacing every triangle would be split, again each round: 4^8 times the faces
        _check(self.curve_edge == 0 or self.curve_edge >= 1, "curve_edge", self.curve_edge,
               "0 (flat) or at least 1 spacing")
        _check(self.min_section_points >= 3, "min_section_points", self.min_section_points, ">= 3")
        _check(int(self.workers) >= 1, "workers", self.workers, "an integer >= 1")
        _check(-1 <= self.fold_cos <= 1, "fold_cos", self.fold_cos, "in [-1, 1] (-1 = off)")
        _check(self.fold_edge_factor >= 0, "fold_edge_factor", self.fold_edge_factor, ">= 0 spacings")
        _check(self.carve_margin >= 0, "carve_margin", self.carve_margin, ">= 0 spacings (0 = off)")
        _check(self.carve_min_edge >= 0, "carve_min_edge", self.carve_min_edge, ">= 0 spacings")
        _check(self.carve_reach >= 0, "carve_reach", self.carve_reach, ">= 0 spacings")
        _check(int(self.carve_min_rays) >= 1, "carve_min_rays", self.carve_min_rays, "an integer >= 1")
        _check(-1 <= self.facing_cos <= 1, "facing_cos", self.facing_cos, "in [-1, 1] (-1 = off)")
        _check(self.facing_min_edge >= 0, "facing_min_edge", self.facing_min_edge, ">= 0 spacings")
        _check(self.concave_height >= 0, "concave_height", self.concave_height, ">= 0 spacings (0 = off)")
        _check(self.concave_mean_height >= 0, "concave_mean_height", self.concave_mean_height, ">= 0 spacings")
        _check(self.concave_min_edge >= 0, "concave_min_edge", self.concave_min_edge, ">= 0 spacings")
        _check(int(self.concave_neighbours) >= 3, "concave_neighbours", self.concave_neighbours, "an integer >= 3")


@dataclass(frozen=True)
class CleanParams:
    """Real scanner conditions (beyond the paper, whose clouds were noise-free): outlier
    rejection before the fit, registration between heads, and a denoised surface
    (`recon.clean.denoise`, `recon.clean.register`). ``outlier_z=0 denoise=False register_heads=False`` gives
    the paper's input. The simple baseline is never denoised (it keeps the paper's surface).
    """

    outlier_z: float = field(default=5.0, metadata={
        "help": "a point farther than this many robust scales (MAD) from its neighbours' surface "
                "is an outlier (0 = keep every point)", "unit": "", "range": (0.0, None)})
    outlier_floor: float = field(default=1.0, metadata={
        "help": "outlier threshold at least this many point spacings", "unit": "", "range": (0.0, None)})
    outlier_isolation: float = field(default=1.5, metadata={
        "help": "an outlier also has no other point within this many point spacings", "unit": "",
        "range": (0.0, None)})
    outlier_neighbours: int = field(default=16, metadata={
        "help": "neighbours of each outlier test's surface fit", "unit": "", "range": (6, None)})
    denoise: bool = field(default=True, metadata={
        "help": "proposed: mesh each point moved onto the robust local surface of its section",
        "unit": "", "range": None})
    denoise_min_noise: float = field(default=0.04, metadata={
        "help": "denoise only a cloud whose measured noise is at least this many point spacings; "
                "a quieter one is meshed as measured (0 = always denoise)", "unit": "", "range": (0.0, None)})
    denoise_passes: int = field(default=2, metadata={
        "help": "denoising projections where the noise widened the fits: each moves the points onto "
                "the surfaces fitted again to where the last one put them", "unit": "", "range": (1, None)})
    denoise_neighbours: int = field(default=40, metadata={
        "help": "points of each denoising fit", "unit": "", "range": (10, None)})
    denoise_radius: float = field(default=0.02, metadata={
        "help": "points of each denoising fit lie within this distance (at least 10 of them)",
        "unit": "m", "range": (0.0, None)})
    denoise_share: float = field(default=3.0, metadata={
        "help": "denoising fits only at one point per cube of this many point spacings, each point "
                "moved by the mean of its 3 nearest fits (0 = a fit at every point)", "unit": "",
        "range": (0.0, None)})
    denoise_error: float = field(default=0.15, metadata={
        "help": "denoising fits widen (past denoise_neighbours, within denoise_reach) until their "
                "error from the measured noise is at most this many spacings (0 = off)",
        "unit": "", "range": (0.0, None)})
    denoise_reach: float = field(default=0.012, metadata={
        "help": "widened denoising fits (see denoise_error), and every fit of a hand's points, "
                "take their points within this distance",
        "unit": "m", "range": (0.0, None)})
    denoise_clamp: float = field(default=3.0, metadata={
        "help": "no point moves farther than this many robust scales (outlier_z where the noise "
                "widened the fits)", "unit": "", "range": (0.0, None)})
    register_heads: bool = field(default=False, metadata={
        "help": "correct the rigid offset between scanner heads: ICP on their overlap, or for two "
                "opposite parallel heads their common silhouette (needs the head of each point)",
        "unit": "", "range": None})

    def __post_init__(self):
        check_fields(self, ReconError)
        _check(self.outlier_z >= 0, "outlier_z", self.outlier_z, ">= 0 (0 = off)")
        _check(self.outlier_floor >= 0, "outlier_floor", self.outlier_floor, ">= 0 spacings")
        _check(self.outlier_isolation >= 0, "outlier_isolation", self.outlier_isolation, ">= 0 spacings")
        _check(int(self.outlier_neighbours) >= 6, "outlier_neighbours", self.outlier_neighbours, "an integer >= 6")
        _check(int(self.denoise_neighbours) >= 10, "denoise_neighbours", self.denoise_neighbours,
               "an integer >= 10")
        _check(int(self.denoise_passes) >= 1, "denoise_passes", self.denoise_passes, "an integer >= 1")
        _check(self.denoise_radius >= 0, "denoise_radius", self.denoise_radius, ">= 0 metres")
        _check(self.denoise_share >= 0, "denoise_share", self.denoise_share, ">= 0 spacings")
        _check(self.denoise_error >= 0, "denoise_error", self.denoise_error, ">= 0 spacings")
        _check(self.denoise_min_noise >= 0, "denoise_min_noise", self.denoise_min_noise, ">= 0 spacings")
        _check(self.denoise_clamp >= 0, "denoise_clamp", self.denoise_clamp, ">= 0 robust scales")
        _check(self.denoise_reach >= 0, "denoise_reach", self.denoise_reach, ">= 0 metres")


def _check(ok, name, value, what):
    if not ok:
        raise ReconError(f"parameter {name}={value!r}: must be {what}")


@dataclass(frozen=True)
class FitParams:
    """Parameters of posture estimation; paper values as defaults, paper section in each comment.

    The measurements behind the chosen values are in docs/tuning.md.
    """

    voxel_min: float = field(default=0.010,  # 2.2: lower limit of the voxel edge, m (value not given; chosen)
        metadata={"help": "lower limit of the voxel edge", "unit": "m", "range": (0.001, 0.5)})
    voxel_max: float = field(default=0.040,  # 2.2, 4.2: upper limit of the voxel edge, 40 mm
        metadata={"help": "upper limit of the voxel edge (paper: 40 mm)", "unit": "m", "range": (0.001, 0.5)})
    voxel_density_k: int = field(default=6,  # 2.2: density = distance to the k-th nearest neighbour (chosen)
        metadata={"help": "cloud density = distance to the k-th nearest neighbour", "unit": "", "range": (1, 100)})
    voxel_density_quantile: float = field(default=0.95,  # 2.2: "the sparsest part": this quantile of it (chosen)
        metadata={"help": "'the sparsest part': this quantile of the densities", "unit": "", "range": (0, 1)})
    voxel_spacing_factor: float = field(default=1.0,  # 2.2: voxel edge / sparsest spacing (chosen)
        metadata={"help": "voxel edge = this times the sparsest spacing", "unit": "", "range": (0.1, 100)})
    voxel_reach: float = field(default=0.3,  # 2.2: inside test: enclosing contours within this, m (chosen)
        metadata={"help": "inside test (without view directions, or voxel_views off): enclosing contour voxels within this", "unit": "m", "range": (0, 2)})
    voxel_views: bool = field(default=True,  # 2.2: inside = behind every camera's seen surface (ours; chosen)
        metadata={"help": "given the points' view directions, inside voxels are those behind what every camera saw "
                          "(off: what the contours enclose)", "unit": "", "range": None})
    contour_weight: float = field(default=2.0,  # 2.3(1), 4.2: weight n of contour voxels, n = 2
        metadata={"help": "weight n of contour voxels in the match (paper: 2)", "unit": "", "range": (-100, 100)})
    match_empty_weight: float = field(default=-1.0,  # 2.3(1): weight of empty voxels in the match (chosen)
        metadata={"help": "weight of empty voxels in the match", "unit": "", "range": (-100, 100)})
    match_claimed_weight: float = field(default=-0.5,  # 2.3(2): weight of voxels inside sections already placed (chosen)
        metadata={"help": "weight of voxels inside sections already placed", "unit": "", "range": (-100, 100)})
    match_max_adduction: float = field(default=0.25,  # 2.3(2): limb may point at most this far (cosine) across the body (chosen)
        metadata={"help": "a limb points at most this far (cosine) across the body", "unit": "", "range": (-1, 1)})
    match_leg_claim_margin: float = field(default=0.02,  # 2.3(2): the legs, placed before the arms, claim their voxels this far beyond
        metadata={"help": "the legs claim their voxels this far beyond their model radii", "unit": "m", "range": (0, 0.5)})
                                           # their model radii, m: a real thigh is wider than the standard column, and the
                                           # contour voxels just outside it drew a hanging forearm onto the thigh's front
                                           # (chosen, as `match_claim_margin`)
    match_claim_margin: float = field(default=0.02,  # 2.3(2): torso claimed this far beyond its surface, m (chosen)
        metadata={"help": "the torso claims voxels this far beyond its surface", "unit": "m", "range": (0, 0.5)})
    match_upright_prior: float = field(default=0.5,  # 2.3(1): score penalty x (1 - cos tilt) of the torso from +z (chosen)
        metadata={"help": "score penalty times (1 - cos tilt) of the torso from +z", "unit": "", "range": (0, 100)})
    match_torso_candidates: int = field(default=2,  # 2.3(1): best torso poses whose whole-body match is compared,
        metadata={"help": "best torso poses whose whole-body match is compared", "unit": "", "range": (1, 100)})
                                           # each also with its roll from the legs (chosen)
    match_min_section_score: float = field(default=0.0,  # 2.3(2): a limb section whose volume weight is below: unfitted (chosen)
        metadata={"help": "a limb section whose volume weight is below this is unfitted", "unit": "", "range": (-100, 100)})
    match_min_shell_score: float = field(default=0.3,  # 2.3(2): ... unless placed on its seen surface, by a shell score at
        metadata={"help": "a limb section below match_min_section_score is kept when its shell score on its seen surface is at least this", "unit": "", "range": (-100, 100)})
                                           # least this (a limb seen from one side only; chosen)
    match_shell_voxel: float = field(default=0.025,  # 2.3(2): the shell score only on volumes of voxels this fine, m: the 2 mm
        metadata={"help": "the shell score is used only on volumes of voxels this fine", "unit": "m", "range": (0, 1)})
                                           # scans (15 mm voxels; chosen)
    match_thigh_max_rise: float = field(default=0.2,  # 2.3(2): a thigh rising more than this (cosine) towards the torso's top
        metadata={"help": "a thigh rising more than this (cosine) toward the torso's top must flex more than it rises", "unit": "", "range": (-1, 1)})
                                           # must flex front or back more than it rises (anatomy; chosen)
    match_upright_start: float = field(default=5.0,  # 2.3(1): the best torso within this of +z (degrees) is always among
        metadata={"help": "the best torso within this of +z is always matched whole", "unit": "deg", "range": (0, 90)})
                                           # those matched whole, and stays so when refined (chosen)
    match_torso_directions: int = field(default=200,  # 2.3(1): torso axis candidates on a hemisphere (chosen)
        metadata={"help": "torso axis candidates on a hemisphere", "unit": "", "range": (10, 100000)})
    match_directions: int = field(default=300,  # 2.3(2): limb direction candidates on a sphere (chosen)
        metadata={"help": "limb direction candidates on a sphere", "unit": "", "range": (10, 100000)})
    match_beam: int = field(default=6,  # 2.3(2): proximal directions kept per limb chain (chosen)
        metadata={"help": "proximal directions kept per limb chain", "unit": "", "range": (1, 1000)})
    match_max_bend: float = field(default=150.0,  # 2.3(2): largest knee bend searched, degrees (chosen)
        metadata={"help": "largest knee bend searched", "unit": "deg", "range": (0, 180)})
    match_max_elbow_bend: float = field(default=140.0,  # 2.3(2): largest elbow bend searched, degrees (anatomy: about 145;
        metadata={"help": "largest elbow bend searched", "unit": "deg", "range": (0, 180)})
                                           # a forearm folded back down a raised arm was matched at 150; chosen)
    match_rounds: int = field(default=2,  # 2.1: matches with the size re-estimated in between (chosen)
        metadata={"help": "matches with the body's size re-estimated in between", "unit": "", "range": (1, 10)})
    match_resize_upright: int = field(default=1,  # 2.1: 1 = when the best match's torso is tilted (more than
        metadata={"help": "1 = after a resize, the best upright torso is matched again too", "unit": "", "range": (0, 1)})
                                           # `match_upright_start`) and the body is resized, the best upright torso
                                           # is matched again at the new size too; it may win only when its head finds the
                                           # crown on its axis (chosen)
    match_legs_roll_wide: int = field(default=1,  # 2.3(1): 1 = a torso roll taken from the legs (`_roll_from_legs`) competes only
        metadata={"help": "1 = a torso roll from the legs competes only when the waist is wider than deep", "unit": "", "range": (0, 1)})
                                           # when the waist, measured on the points, comes out wider than deep (anatomy, as
                                           # `_check_plausible`): legs split front-back by a stride give the wrong roll
                                           # (chosen)
    match_resize_tolerance: float = field(default=0.06,  # 2.1: re-match only when the limbs measure off by more (chosen)
        metadata={"help": "re-match only when the limbs measure off by more than this ratio", "unit": "", "range": (0, 10)})
    match_min_anchor_shift: float = field(default=0.08,  # 2.3(1): slide the torso to hang from the crown when it is off
        metadata={"help": "slide the torso to hang from the crown when it is off by more than this", "unit": "m", "range": (0, 2)})
    match_max_anchor_shift: float = field(default=0.15,  #   by more than this, and at most this far, m (chosen)
        metadata={"help": "the torso slides at most this far to hang from the crown", "unit": "m", "range": (0, 2)})
    match_crown_on_trunk: int = field(default=1,  # 2.3(1): 1 = when the head finds no crown on its own axis, the crown is sought
        metadata={"help": "1 = seek the crown on the trunk's axis when the head finds none on its own", "unit": "", "range": (0, 1)})
                                           # on the trunk's axis (`recon.posture.match._crown_on_trunk`: the head sits on the
                                           # trunk; a torso matched too high leaves its head leaning onto nothing) and
                                           # the torso slid down to it when that explains more points, at any stature
                                           # (not only from `fit_anchor_min_stature`; chosen)
    match_size_from_crown: int = field(default=0,  # 2.1: 1 = size from crown-to-sole lengths, 0 = from the legs (chosen)
        metadata={"help": "1 = size the body from crown-to-sole lengths, 0 = from the legs", "unit": "", "range": (0, 1)})
    match_min_first_stature: float = field(default=1.5,  # 2.1: stature of the first match at least this, m (chosen)
        metadata={"help": "stature of the first match at least this", "unit": "m", "range": (0.3, 3)})
    match_size_disagree: float = field(default=0.1,  # 2.1: the legs' length (from the matched hips) and crown to sole (which does
        metadata={"help": "legs and crown-to-sole differing by more than this ratio: size from crown to sole", "unit": "", "range": (0, 10)})
                                           # not depend on where the torso sits along its axis) differ by more than this
                                           # ratio: the hips were misplaced, size from crown to sole (adult sizes;
                                           # children stay sized by the legs; chosen)
    match_leg_trunk_min: float = field(default=0.8,  # 2.1: both leg chains (hip to the farthest point along the lower leg) measuring
        metadata={"help": "leg chains shorter than this times the trunk are legs cut from the scan (0 = off)", "unit": "", "range": (0, 10)})
                                           # less than this times the trunk (crown to the crotch seen in the points,
                                           # over `recon.posture.match.CROWN_CROTCH` statures) are not whole legs (cut from the
                                           # scan): the trunk sizes the body and the lower legs are listed
                                           # (`recon.posture.match.size_ratios`); not applied when the scan shows feet
                                           # (`recon.posture.fit.feet_forward`) (0 = off; chosen)
    match_size_both: int = field(default=1,  # 2.1: 1 = when the legs size the body (see `match_size_disagree`) but crown to
        metadata={"help": "1 = when legs and crown-to-sole disagree, match at both sizes and keep the one explaining more points (sized as a child: by match_crown_first_margin)", "unit": "", "range": (0, 1)})
                                           # sole differs from them by more than `match_resize_tolerance`, the body is
                                           # matched at both sizes and the one explaining more points is kept: the
                                           # two measures disagree because the hips sit off along the torso's axis,
                                           # or because the body's proportions are not the standard's, and the
                                           # points tell which (chosen)
    match_crown_first_margin: float = field(default=0.2,  # 2.1: with `match_size_both`: a body sized by its legs as a child
        metadata={"help": "with match_size_both: a child-sized body's crown-to-sole match goes first when it explains this fraction of the points more (1 = never)", "unit": "", "range": (0, 1)})
                                           # (crown to sole under `fit_anchor_min_stature`) whose crown to sole
                                           # disagrees by more than `match_size_disagree` is matched at both sizes;
                                           # the crown-to-sole match is tried first when its model explains more
                                           # than this fraction of the points more than the legs' match, and is
                                           # otherwise the first fallback. A short adult's legs are short for its
                                           # trunk and size it far too small; a child's larger model explains a
                                           # little more by nature, hence the margin (chosen)
    match_resized_anchor_shift: float = field(default=0.0,  # 2.3(1): after sizing from the crown (`match_size_disagree`: the torso was
        metadata={"help": "after sizing from the crown, hang the torso from the crown when off by more than this", "unit": "m", "range": (0, 2)})
                                           # misplaced along its axis), the next match slides the torso to hang from the
                                           # crown when it is off by more than this, m (0: always; chosen)
    match_alternatives: int = field(default=2,  # 2.3(1): other torso poses tried, best first, when the fit of the best
        metadata={"help": "other torso poses tried, best first, when the best one's fit fails its checks", "unit": "", "range": (0, 100)})
                                           # fails its checks (a sparse scan's coarse volume often ties an upright
                                           # torso with one tilted onto an arm; chosen)
    match_explain_distance: float = field(default=0.03,  # 2.3(1)-(2): of the whole-body matches of the torso candidates, the one
        metadata={"help": "a point is explained by a whole-body match within this", "unit": "m", "range": (0.001, 1)})
                                           # explaining most points within this (m) wins: on a coarse volume the
                                           # volume score ties right and wrong torsos, the points do not (chosen)
    match_explain_points: int = field(default=4000,  # 2.3(1): points sampled (fit_seed) for that count (chosen)
        metadata={"help": "points sampled (fit_seed) to count the explained ones", "unit": "", "range": (10, 10000000)})
    match_max_points: int = field(default=20000,  # 2.2-2.3(1): the volume and the coarse match use a subsample
        metadata={"help": "points the volume and the coarse match use, subsampled (the fine fit uses up to fit_max_points)", "unit": "", "range": (100, 100000000)})
                                           # (fit_seed) of at most this many points (a 10 mm scan has 8-11
                                           # thousand: unchanged), so a finer scan is matched on a coarser volume,
                                           # then adjusted on up to fit_max_points (coarse to fine)
    match_alt_min_turn: float = field(default=10.0,  # 2.3(1): an alternative's torso axis turned at least this, degrees (chosen)
        metadata={"help": "an alternative's torso axis is turned at least this", "unit": "deg", "range": (0, 180)})
    fit_near_distance: float = field(default=0.05,  # 2.3(2): points this near a section surface adjust it, m
        metadata={"help": "points this near a section's surface adjust it", "unit": "m", "range": (0.001, 1)})
    fit_end_threshold: float = field(default=0.6,  # 2.3(2): end points: nearer the axis than this x radius
        metadata={"help": "end points: nearer the axis than this times the radius", "unit": "", "range": (0, 10)})
    fit_iterations: int = field(default=2,  # 2.3(2): rounds of point assignment and adjustment (chosen)
        metadata={"help": "rounds of point assignment and adjustment", "unit": "", "range": (0, 100)})
    fit_section_points: int = field(default=500,  # 2.3(2): points per section per round, subsampled (chosen)
        metadata={"help": "points per section per round, subsampled", "unit": "", "range": (10, 10000000)})
    fit_max_shift: float = field(default=0.04,  # 2.3(2): largest axis move per round, m (chosen)
        metadata={"help": "largest axis move per round", "unit": "m", "range": (0, 1)})
    fit_max_turn: float = field(default=12.0,  # 2.3(2): largest axis turn per round, degrees (chosen)
        metadata={"help": "largest axis turn per round", "unit": "deg", "range": (0, 180)})
    fit_max_points: int = field(default=30000,  # 2.3(2): points used by the fine fit, subsampled (chosen)
        metadata={"help": "points used by the fine fit, subsampled", "unit": "", "range": (100, 100000000)})
    fit_loss: str = field(default="soft_l1",  # 2.3(2): least-squares loss (paper: squares; robust chosen)
        metadata={"help": "least-squares loss: linear, soft_l1, huber, cauchy or arctan (paper: squares)", "unit": "", "range": None})
    fit_min_points: int = field(default=30,  # 2.3(2): fewer points: the section is unfitted (chosen)
        metadata={"help": "a section with fewer points is unfitted", "unit": "", "range": (3, None)})
    fit_coverage_distance: float = field(default=0.02,  # 2.3(2): a point is explained within this of a surface, m (chosen)
        metadata={"help": "a point is explained within this of a section's surface", "unit": "m", "range": (0.001, 1)})
    fit_min_section_cover: float = field(default=0.2,  # 2.3(2): fewer of a section's cells with points: unfitted (chosen)
        metadata={"help": "a section with fewer of its cells holding points is unfitted", "unit": "", "range": (0, 1)})
    fit_doubt_cover: float = field(default=0.55,  # 2.3(2): an arm section both this little covered and
        metadata={"help": "an arm section covered less than this and fitted worse than fit_doubt_rms is unfitted", "unit": "", "range": (0, 1)})
    fit_doubt_rms: float = field(default=0.015,  #   fitted worse than this rms (m) is not trusted: unfitted,
        metadata={"help": "an arm section covered less than fit_doubt_cover and fitted worse than this rms is unfitted", "unit": "m", "range": (0, 1)})
    fit_doubt_min_cover: float = field(default=0.35,  #   and so is one covered less than this (chosen)
        metadata={"help": "an arm section covered less than this is unfitted", "unit": "", "range": (0, 1)})
    reach_candidates: int = field(default=60,  # 2.3(2): an arm listed unfitted is searched again as a chain from its
        metadata={"help": "arm search (reach): an unfitted arm is searched again from its shoulder; upper-arm directions kept", "unit": "", "range": (1, 10000)})
    reach_min_hand_points: int = field(default=10,  #   shoulder on the points no other section explains (`recon.posture.reach`):
        metadata={"help": "arm search (reach): points needed at the hand end of a found forearm", "unit": "", "range": (0, None)})
    reach_hand_fraction: float = field(default=0.3,  #   upper-arm directions kept for the forearm's search; points needed at
        metadata={"help": "arm search (reach): the hand end is the last this fraction of the forearm", "unit": "", "range": (0, 1)})
    reach_max_core_fraction: float = field(default=0.1,  #   the hand end (the last this fraction of the forearm, a radius beyond);
        metadata={"help": "arm search (reach): points inside the columns allowed per point on the surface", "unit": "", "range": (0, 100)})
    reach_min_upper_bins: int = field(default=4,  #   points inside the columns (and past the hand) allowed per surface (hand)
        metadata={"help": "arm search (reach): fifths of the upper arm that must hold points", "unit": "", "range": (0, 5)})
                                           #   point; fifths of the upper arm holding points (chosen)
    reach_back_clearance: float = field(default=0.1,  # 2.3(2): ... a hand behind the trunk nearer its columns than this (m): not
        metadata={"help": "arm search (reach): a hand behind the trunk nearer its columns than this is not taken", "unit": "m", "range": (0, 2)})
                                           #   taken (the back's own surface lies 5-7 cm outside the fitted chest at the
                                           #   shoulder blades; chosen)
    reach_max_halo_fraction: float = field(default=0.25,  # 2.3(2): ... and the free points around the upper arm (1.6 to 3 radii from
        metadata={"help": "arm search (reach): free points around the upper arm allowed per point on its surface", "unit": "", "range": (0, 100)})
                                           #   its axis) allowed per point on its surface: a limb stands apart, a patch
                                           #   of trunk the fitted torso misses spreads around a column laid on it
                                           #   (chosen)
    reach_max_shared_fraction: float = field(default=0.5,  # 2.3(2): ... and not taken when more than this fraction of the points
        metadata={"help": "arm search (reach): not taken when more than this fraction of its points lie on another section", "unit": "", "range": (0, 1)})
                                           #   either found section is nearest to lie within fit_coverage_distance of
                                           #   another section's surface (a limb explains points no other explains;
                                           #   chosen)
    fit_leg_seen_cover: float = field(default=0.4,  # 2.3(2): a leg section in empty voxels (a thigh raised level, seen from
        metadata={"help": "a leg section in empty voxels is kept when its cells hold points at least this much", "unit": "", "range": (0, 1)})
    fit_leg_seen_rms: float = field(default=0.012,  #   the front and above: no inside voxels) is kept when its fitted surface's
        metadata={"help": "a leg section in empty voxels is kept when it also fits its points within this rms", "unit": "m", "range": (0, 1)})
                                           #   cells hold points at least this much and it fits them within this rms
                                           #   (m): the points show the limb the volume missed (chosen)
    fit_arm_clearance: float = field(default=0.7,  # 2.3(2): an arm section whose axis comes nearer the trunk's fitted columns
        metadata={"help": "an arm's axis nearer the trunk's columns than this many of its radii: unfitted", "unit": "radii", "range": (0, 100)})
                                           #   than this many model radii of it (a forearm at 0.25 to 1 of its
                                           #   length, an upper arm, which starts at the shoulder, at 0.75 and 1) is
                                           #   unfitted: an arm against the body keeps its axis a radius outside the
                                           #   skin, which the trunk's columns fit to 1-2 cm; one nearer lies on the
                                           #   trunk's own surface (chosen)
    fit_max_unfitted: int = field(default=4,  # 2.3(2): more sections unfitted (two arms' worth): the posture was not
        metadata={"help": "more sections unfitted: the posture was not found", "unit": "", "range": (0, 11)})
                                           # found (chosen)
    fit_min_coverage: float = field(default=0.6,  # 2.3(2): fewer points explained: not a body (chosen)
        metadata={"help": "fewer of the points explained: not a body", "unit": "", "range": (0, 1)})
    fit_min_agreement: float = field(default=0.68,  # 2.3(2): the fitted model drawn from each camera: under this fraction of
        metadata={"help": "less of the trunk's or the limbs' surface the cameras see confirmed by the scan: posture not found (0 = off; needs view directions)", "unit": "", "range": (0, 1)})
                                           # the surface its trunk, or its limbs, show a camera, where that camera saw
                                           # a point, confirmed by a point at its depth: the posture was not found
                                           # (`recon.posture.seen.confirmed_parts`; chosen)
    fit_agreement_tolerance: float = field(default=0.03,  # 2.3(2): a shown model surface sample is confirmed by a seen point
        metadata={"help": "a model surface sample a camera would see is confirmed by a seen point this near in depth", "unit": "m", "range": (0.001, 1)})
                                           # this near in depth (in its pixel or the eight around; chosen)
    match_head_max_side: float = field(default=55.0,  # 2.3(2): the head's coarse axis leans at most this far sideways (towards the
        metadata={"help": "the head's coarse axis leans at most this far sideways from the chest's", "unit": "deg", "range": (0, 180)})
                                           # torso's wide axis) from the chest's, degrees: the neck bends about 45 degrees
                                           # sideways (its range of lateral flexion), 10 more for the chest's own error;
                                           # front and back it keeps the 70 degree cone (chosen)
    match_head_max_lean: float = field(default=60.0,  # 2.3(1): a torso whose head leans further than this forward or back
        metadata={"help": "a torso whose head leans further forward or back from its chest slides down to the crown on the trunk's axis", "unit": "deg", "range": (0, 180)})
                                           # from its chest's axis, degrees, slides down to the crown found on the
                                           # trunk's axis (`match_crown_on_trunk`) whatever the points say: the neck's
                                           # range of flexion (about 50 degrees), 10 more for the chest's own error
                                           # (`recon.posture.match.head_in_range`; chosen)
    fit_anchor_min_stature: float = field(default=1.5,  # 2.3(2): anchor on the crown only for bodies this tall, m (chosen)
        metadata={"help": "anchor on the crown only for bodies at least this tall", "unit": "m", "range": (0, 3)})
    fit_anchor_max_shift: float = field(default=0.04,  # 2.3(2): the neck and head follow the crown this much further than the
        metadata={"help": "the neck and head follow the crown this much further than the torso", "unit": "m", "range": (0, 1)})
                                           # torso (fit_max_shift), the chest stretching, m (chosen)
    fit_arm_size_tolerance: float = field(default=0.1,  # 2.3(2): a nearly straight arm whose shoulder-to-wrist (wrist from the seen
        metadata={"help": "a straight arm off the model's length by more than this ratio gets its elbow at the model's proportion", "unit": "", "range": (0, 10)})
                                           # fingertips) differs from the model's arm by more than this ratio has its elbow
                                           # placed at the model's proportion of the measured arm, not the model's upper-arm
                                           # length from the shoulder: the body's size was misjudged (chosen)
    fit_facing: int = field(default=4,  # 2.1: fit the cloud turned about the vertical to a facing read from its own
        metadata={"help": "fit the cloud turned to its own facing, retried in 360/this degree steps (0 = as it lies)", "unit": "", "range": (0, 36)})
                                           # shape (`recon.posture.fit.facing_frame`), so that a scan turned about the
                                           # vertical gets the same fit, turned; when refused, with fit_facing_retry
                                           # sections unfitted or explaining fewer than fit_min_coverage of the
                                           # points, also turned further in 360 / fit_facing degree steps,
                                           # the best fit kept (`recon.posture.fit._fit_facings`); 0 = fit the cloud as it
                                           # lies (chosen; measured in the module docstring of recon.posture)
    fit_regrid: bool = field(default=True,  # 2.2: a fit refused on the voxel lattice is made again on the lattice
        metadata={"help": "a refused fit is made again on the voxel lattice shifted by half a voxel", "unit": "", "range": None})
                                           # shifted by half a voxel: the same data, another discretization (the
                                           # volume's binary voxels make the match chaotic; not in the paper)
    fit_facing_retry: int = field(default=3,  # 2.1: ... this many sections unfitted (more than one limb: a fit that lost
        metadata={"help": "this many sections unfitted: try the other facings too", "unit": "", "range": (0, 11)})
                                           # its way; a scan missing one limb is not fitted again, each try being a
                                           # chance to place the limb on points not its own; chosen)
    fit_facing_band: float = field(default=0.70,  # 2.1: the facing is read from the points between this and
        metadata={"help": "the facing is read from the points between this and fit_facing_band_top of the height", "unit": "", "range": (0, 1)})
    fit_facing_band_top: float = field(default=0.85,  #   this fraction of the cloud's height (the shoulders), where the widest
        metadata={"help": "upper end of that band, fraction of the height", "unit": "", "range": (0, 1)})
                                           # horizontal spread is across the body (chosen)
    fit_stature: float = field(default=0.0,  # 2.1: body stature, m; 0 = estimate it from the cloud
        metadata={"help": "body stature; 0 = estimate it from the cloud", "unit": "m", "range": (0, 3)})
    fit_seed: int = field(default=0,  # random subsampling seed
        metadata={"help": "seed of the random subsampling", "unit": "", "range": (0, None)})
    extremities: bool = field(default=True,  # beyond the paper: hands and feet (recon.posture.extremities)
        metadata={"help": "place hands and feet past the fitted wrists and ankles, cluster and mesh them as "
                          "sections (False: the paper's 11 sections)", "unit": "", "range": (False, True)})

    def __post_init__(self):
        check_fields(self, ReconError)
        _check(self.fit_loss in FIT_LOSSES, "fit_loss", self.fit_loss, f"one of {', '.join(FIT_LOSSES)}")
        _check(self.voxel_min <= self.voxel_max, "voxel_min", self.voxel_min,
               f"at most voxel_max ({self.voxel_max:g} m)")
        _check(self.fit_facing_band < self.fit_facing_band_top, "fit_facing_band", self.fit_facing_band,
               f"below fit_facing_band_top ({self.fit_facing_band_top:g})")
        _check(self.match_min_anchor_shift <= self.match_max_anchor_shift, "match_min_anchor_shift",
               self.match_min_anchor_shift, f"at most match_max_anchor_shift ({self.match_max_anchor_shift:g} m)")

    @classmethod
    def from_strings(cls, pairs) -> "FitParams":
        """Build from ``["name=value", ...]`` (the CLI's ``--param``); raise `ReconError` on a bad one."""
        known = {f.name: f for f in fields(cls)}
        kw = {}
        for pair in pairs or ():
            name, sep, value = pair.partition("=")
            name = name.strip()
            if not sep:
                raise ReconError(f"--param {pair!r}: expected name=value")
            if name not in known:
                raise ReconError(f"--param {pair!r}: unknown posture parameter {name!r}"
                                 f"{_did_you_mean(name, known)} (`bodyscan fit --param help` lists them)")
            kw[name] = coerce(known[name], value, ReconError)
        return cls(**kw)


#: The paper's method as itself (`ReconParams.paper`, the ``paper`` method): every rule of ours
#: that a parameter switches off, off. Clustering: no joint planes (the joint rule weighs the
#: neighbours' erosion fronts alone, paper 3.2), no claims across joints, no adoption of
#: unlabelled points (the paper leaves them out), the three-or-more rule copies from the nearest
#: neighbour with fewer labels. Surface: the paper's removal of inner triangles (multi-section
#: points) only: no open joint ends, no fold, carving, view or concavity rule, flat triangles.
#: Posture: the cloud fitted as it lies (subjects face the camera, paper 4.1), one size estimate,
#: no alternatives, no check against the cameras' view, the volume enclosed by its contours (not
#: between the cameras' views). Kept, being steps without which nothing works, and the same in
#: ``simple``: the hull peel of Delaunay's convex hull (``hull_edge_factor``), the fit's search
#: itself (``recon.posture.match``, whose voxel score is paper 2.3).
PAPER = {
    # clustering (paper 3.1-3.2)
    "joint_plane_weight": 0.0, "side_joint_planes": False, "joint_plane_bones": False,
    "hip_planes": False, "claim_across_joints": 0.0, "three_keep_nearest": 0.0,
    "adopt_unlabeled": False,
    # surface (paper 3.3)
    "fold_cos": -1.0, "carve_margin": 0.0, "facing_cos": -1.0, "concave_height": 0.0, "tilt_cos": 0.0,
    "orient_model_weight": 0.0,
    "open_joint_ends": False,
    "far_charts": False, "far_view": False,
    "hull_edge_factor": 4.0, "hull_edge_min": 0.0, "max_edge_min": 0.0, "peel_same_side": 2.0,
    "rejoin_edge": 0.0, "cover_max_edge": 0.0, "curve_edge": 0.0,
    # real scanner conditions (the paper's clouds were noise-free)
    "outlier_z": 0.0, "denoise": False, "register_heads": False,
    # posture (paper 2)
    "fit_facing": 0, "match_size_both": 0, "match_alternatives": 0, "extremities": False,
    "fit_min_agreement": 0.0, "fit_regrid": False, "voxel_views": False,
}


@dataclass(frozen=True)
class ReconParams:
    """All parameters of the reconstruction: ``fit`` (posture estimation), ``cluster``, ``surface``,
    ``clean`` (outliers, registration, denoising)."""

    fit: FitParams = field(default_factory=FitParams)
    cluster: ClusterParams = field(default_factory=ClusterParams)
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    clean: CleanParams = field(default_factory=CleanParams)

    def paper(self) -> "ReconParams":
        """These parameters with every rule of ours switched off (`PAPER`): the paper's steps."""
        changes: dict = {}
        for stage, obj in self.stages().items():
            names = {f.name for f in fields(obj)}
            changes[stage] = dataclasses.replace(obj, **{k: v for k, v in PAPER.items() if k in names})
        return dataclasses.replace(self, **changes)

    def stages(self) -> dict:
        """{stage name: that stage's dataclass} for the stages present."""
        return {k: v for k, v in (("fit", self.fit), ("cluster", self.cluster), ("surface", self.surface),
                                  ("clean", self.clean)) if v is not None}

    def to_dict(self) -> dict:
        """Flat {name: value} of every parameter."""
        out = {}
        for stage in self.stages().values():
            out.update(dataclasses.asdict(stage))
        return out

    @classmethod
    def from_overrides(cls, overrides: dict | None = None) -> "ReconParams":
        """Default parameters with some fields set by their flat names.

        Parameters
        ----------
        overrides : dict of str to value
            E.g. ``{"t_d": 0.3, "t_n_factor": 0.5}``; strings (from the CLI) are converted to the
            field's type.

        Raises
        ------
        ReconError
            An unknown name, or a value of the wrong type or out of range.
        """
        base = cls()
        stages = base.stages()
        owner = {}
        for stage, obj in stages.items():
            for f in fields(obj):
                if f.name in owner:  # names must be unique across stages to be set flat
                    raise ReconError(f"parameter {f.name!r} is defined by both {owner[f.name]} and {stage}")
                owner[f.name] = stage
        changes: dict = {stage: {} for stage in stages}
        for name, value in (overrides or {}).items():
            if name not in owner:
                raise ReconError(f"unknown parameter {name!r}{_did_you_mean(name, owner)} (`bodyscan "
                                 f"reconstruct --param help` lists all {len(owner)}, by stage)")
            stage = owner[name]
            changes[stage][name] = coerce(_field(type(stages[stage]), name), value, ReconError)
        built = {}
        for stage, obj in stages.items():
            try:
                built[stage] = dataclasses.replace(obj, **changes[stage]) if changes[stage] else obj
            except ReconError:
                raise
            except (TypeError, ValueError) as exc:
                raise ReconError(f"bad {stage} parameter: {exc}") from None
        return cls(**built)


def stage_help(stages=("fit", "clean", "cluster", "surface")) -> str:
    """The ``--param help`` text of the reconstruction's parameters, grouped by stage."""
    from bodyscan._params import param_help

    titles = {"fit": ("fit: posture estimation (paper section 2)", FitParams),
              "cluster": ("cluster: clustering into body sections (paper section 3)", ClusterParams),
              "surface": ("surface: per-section Delaunay surfaces (paper section 3.3)", SurfaceParams),
              "clean": ("clean: outliers, head registration, denoising (real scans; beyond the paper)",
                        CleanParams)}
    return param_help(dict(titles[s] for s in stages))


def _field(cls, name):
    """The dataclass field ``name`` of ``cls``."""
    return next(f for f in fields(cls) if f.name == name)


#: Parameters that were removed, and why: a sweep file or script that still sets one is told so.
REMOVED = {
    "inner_depth": "removed: the rule changed no score measurably (commit ac243cc)",
    "match_arms_first_retry": "removed: the rule changed 3 of 488 corpus fits, net none (commit c17ba13)",
    "refine_adjacent": "removed: it was off in every method and measured worse (commit 55d73a9)",
    "mesh_adopted": "removed: it was off in every method; far_charts meshes those points (commit 55d73a9)",
}


def _did_you_mean(name: str, known) -> str:
    """``"; did you mean 'a' or 'b'?"``: the known names nearest to a mistyped one (those it
    begins or is part of, then the most alike; a stage prefix such as ``surface.`` dropped), or
    ``""``; for a parameter that was removed, why (`REMOVED`)."""
    import difflib

    bare = name.rsplit(".", 1)[-1].strip().lower()
    if bare in REMOVED:
        return f"; {REMOVED[bare]}: leave it out"
    known = sorted(known)
    if bare in known:
        return f"; the names take no stage prefix: {bare!r}"
    near = [k for k in known if bare and k.startswith(bare)]
    near += difflib.get_close_matches(bare, known, n=3, cutoff=0.6)
    near += [k for k in known if bare and bare in k]
    near = list(dict.fromkeys(near))[:3]
    return f"; did you mean {' or '.join(repr(k) for k in near)}?" if near else ""
