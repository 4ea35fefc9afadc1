"""Clustering into body sections: each rule against scenes whose answer is known."""

import numpy as np
import pytest

from bodyscan.recon import ReconError
from bodyscan.recon.clustering import cluster as C
from bodyscan.recon.model import SECTIONS, BodyFit, SectionShape
from bodyscan.recon.params import ClusterParams, FitParams, ReconParams

X = np.array([1.0, 0, 0])
I = {name: i for i, name in enumerate(SECTIONS)}


def column_points(shape, spacing=0.008, seed=0, noise=0.0):
    """Points on the side of a section's column, roughly ``spacing`` apart (m, 3)."""
    rng = np.random.default_rng(seed)
    n = int(2 * np.pi * shape.radii.mean() * shape.length / spacing ** 2)
    t = rng.uniform(0, 2 * np.pi, n)
    h = rng.uniform(0, shape.length, n)
    R = shape.radius_at(t) + rng.normal(0, noise, n)
    fx, fy, z = shape.frame
    return shape.start + (R * np.cos(t))[:, None] * fx + (R * np.sin(t))[:, None] * fy + h[:, None] * z


def test_simple_clustering_is_the_t_d_threshold():
    shape = SectionShape("waist", [0, 0, 0], [0, 0, 0.4], [0.1, 0.1], X)
    fit = BodyFit(sections={"waist": shape}, joints={})
    # points at known distances outside the column, mid-height
    d = np.array([0.0, 0.02, 0.059, 0.061, 0.2])
    P = np.column_stack([0.1 + d, np.zeros(5), np.full(5, 0.2)])
    r, _, _ = C.section_coordinates(P, fit)
    assert np.allclose(r[:, I["waist"]], d)
    m = C.simple_clustering(r, C.section_widths(fit), t_d=0.3)     # T_d = 0.3 * 0.2 m = 6 cm
    assert m[:, I["waist"]].tolist() == [True, True, True, False, False]
    assert not m[:, [i for i in range(11) if i != I["waist"]]].any()


def test_otsu_splits_two_peaks_and_keeps_one_peak():
    rng = np.random.default_rng(0)
    one = rng.normal(0.0, 0.003, 200)
    two = np.concatenate([rng.normal(0.0, 0.003, 150), rng.normal(0.05, 0.003, 50)])
    cell = np.repeat([0, 1], 200)
    thr, split = C.otsu_cells(cell, np.concatenate([one, two]), 2, t_n_factor=0.5)
    assert split.tolist() == [False, True]
    assert 0.005 < thr[1] < 0.045                                    # between the peaks
    # few points: never split
    _, split = C.otsu_cells(np.zeros(5, int), two[[0, 1, 2, 160, 161]], 1, min_points=12)
    assert not split[0]


def test_otsu_threshold_matches_brute_force():
    rng = np.random.default_rng(3)
    v = np.concatenate([rng.normal(0, 1, 300), rng.normal(4, 0.5, 100)])
    thr, _ = C.otsu_cells(np.zeros(len(v), int), v, 1, bins=16)
    edges = np.linspace(v.min(), v.max(), 17)
    best = max(edges[1:-1], key=lambda t: (v < t).mean() * (v >= t).mean()
               * (v[v < t].mean() - v[v >= t].mean()) ** 2)
    assert np.isclose(thr[0], best)


def two_columns(gap=0.02, spacing=0.008):
    """A waist column and a forearm beside it, ``gap`` apart; both fully sampled."""
    waist = SectionShape("waist", [0, 0, 0.9], [0, 0, 1.3], [0.15, 0.15], X, closed=(False, False))
    x = 0.15 + gap + 0.04
    arm = SectionShape("forearm_l", [x, 0, 1.3], [x, 0, 0.9], [0.04, 0.04], X, closed=(False, False))
    fit = BodyFit(sections={"waist": waist, "forearm_l": arm}, joints={})
    pw, pa = column_points(waist, spacing, 0), column_points(arm, spacing, 1)
    P = np.vstack([pw, pa])
    truth = np.concatenate([np.full(len(pw), I["waist"]), np.full(len(pa), I["forearm_l"])])
    return P, truth, fit


def test_simple_clustering_mixes_an_arm_beside_the_body_and_proposed_separates_it():
    P, truth, fit = two_columns()
    simple = C.cluster_points(P, fit, "simple")
    assert (simple.sum(axis=1) == 2).mean() > 0.05                  # T_d = 9 cm swallows the arm
    m = C.cluster_points(P, fit, "proposed")
    assert (m.sum(axis=1) == 1).all()                               # not adjacent: one section each
    assert (m[np.arange(len(P)), truth]).mean() > 0.99


def test_refinement_removes_the_far_peak_only_where_another_section_claims_it():
    P, truth, fit = two_columns()
    r, th, h = C.section_coordinates(P, fit)
    m0 = C.simple_clustering(r, C.section_widths(fit), 0.3)
    m1 = C.refine_by_distance(m0, r, th, h, fit, ClusterParams())
    arm_in_waist0 = m0[truth == I["forearm_l"], I["waist"]].sum()
    arm_in_waist1 = m1[truth == I["forearm_l"], I["waist"]].sum()
    assert arm_in_waist1 < 0.5 * arm_in_waist0
    assert m1[truth == I["waist"], I["waist"]].all()                # the waist keeps all its points
    assert (m1.sum(axis=1) >= 1).all()


def test_three_or_more_copies_from_the_nearest_point_with_fewer():
    P = np.array([[0, 0, 0], [0.01, 0, 0], [0.5, 0, 0], [0.51, 0, 0.0], [0.53, 0, 0]])
    m = np.zeros((5, 11), bool)
    m[0, [0, 1, 2]] = True          # three sections
    m[1, [1, 2]] = True             # nearest, two sections
    m[2, [3, 4, 5, 6]] = True       # four sections
    m[3, [5, 6, 7]] = True          # nearest has three: fewer than four
    m[4, [6, 7]] = True
    r = np.zeros((5, 11))
    out = C.reduce_to_two(m, P, r, np.ones(11))
    assert out[0].nonzero()[0].tolist() == [1, 2]
    assert out.sum(axis=1).max() <= 2
    # point 2 copies point 3's (5, 6, 7) while point 3 copies point 4's (6, 7), all from the labels
    # before the round; the next round it copies point 3 again: (6, 7)
    assert out[2].nonzero()[0].tolist() == [6, 7]
    assert out[3].nonzero()[0].tolist() == [6, 7]


def test_joint_rule_leaves_a_thin_seam_at_the_junction():
    """Upper arm and forearm, straight, meeting at the elbow: both-labelled points become a seam."""
    upper = SectionShape("upper_arm_l", [0, 0, 1.4], [0, 0, 1.1], [0.045, 0.045], X)
    fore = SectionShape("forearm_l", [0, 0, 1.1], [0, 0, 0.8], [0.045, 0.045], X)
    fit = BodyFit(sections={"upper_arm_l": upper, "forearm_l": fore},
                  joints={"elbow_l": np.array([0, 0, 1.1])})
    tube = SectionShape("x", [0, 0, 0.8], [0, 0, 1.4], [0.045, 0.045], X, closed=(False, False))
    P = column_points(tube, 0.006)
    m = C.cluster_points(P, fit, "proposed")
    up, fo = m[:, I["upper_arm_l"]], m[:, I["forearm_l"]]
    z = P[:, 2]
    assert (up | fo).all()
    assert up[z > 1.13].all() and not fo[z > 1.13].any()
    assert fo[z < 1.07].all() and not up[z < 1.07].any()
    both = up & fo
    assert 0 < both.sum() < 0.06 * len(P)                          # a seam, not the whole overlap
    assert np.abs(z[both] - 1.1).max() < 0.03


def test_neighbor_radius_follows_the_spacing():
    P, _, _ = two_columns(spacing=0.01)
    auto = C.neighbor_radius(P, ClusterParams())
    assert 0.01 < auto < 0.04
    assert C.neighbor_radius(P, ClusterParams(neighbor_radius=0.05)) == 0.05


def test_params_overrides_resolve_names_and_reject_bad_ones():
    p = ReconParams.from_overrides({"t_d": "0.25", "mesh_theta": 12, "max_edge_factor": "3"})
    assert p.cluster.t_d == 0.25 and p.cluster.mesh_theta == 12 and p.surface.max_edge_factor == 3.0
    with pytest.raises(ReconError, match="unknown parameter 'td'; did you mean 't_d'") as err:
        ReconParams.from_overrides({"td": 0.3})
    assert "mesh_theta" not in str(err.value)    # the nearest names, not all of them
    with pytest.raises(ReconError, match="did you mean 'close_voxel'"):
        ReconParams.from_overrides({"close_voxl": 0.01})
    with pytest.raises(ReconError, match="no stage prefix: 'close_voxel'"):
        ReconParams.from_overrides({"surface.close_voxel": 0.01})
    with pytest.raises(ReconError, match="unknown parameter 'inner_depth'; removed: .* leave it out"):
        ReconParams.from_overrides({"inner_depth": 0.15})    # a sweep file from before the removal
    with pytest.raises(ReconError, match="unknown posture parameter 'fit_facng'; did you mean 'fit_facing'"):
        FitParams.from_strings(["fit_facng=4"])
    with pytest.raises(ReconError, match="expected name=value"):
        FitParams.from_strings(["fit_facing"])
    with pytest.raises(ReconError, match=r"unknown parameter 'bogus' \(`bodyscan reconstruct --param help`"):
        ReconParams.from_overrides({"bogus": 1})
    with pytest.raises(ReconError, match="t_d"):
        ReconParams.from_overrides({"t_d": -1})
    with pytest.raises(ReconError, match="mesh_h"):
        ReconParams.from_overrides({"mesh_h": "ten"})
    with pytest.raises(ReconError, match="mesh_h"):
        ReconParams.from_overrides({"mesh_h": 2.5})


def test_joint_plane_score_is_the_mitre_of_the_axes():
    """A bent knee: the plane bisects the two axes at the joint; a side joint (hip) has none."""
    knee = np.array([0.1, 0, 0.5])
    thigh = SectionShape("thigh_l", [0.1, 0, 0.9], knee, [0.07, 0.07], X)
    shin = SectionShape("lower_leg_l", knee, knee + [0, -0.4, 0], [0.05, 0.05], X)   # bent 90 deg
    waist = SectionShape("waist", [0, 0, 1.2], [0, 0, 0.9], [0.15, 0.1], X)
    fit = BodyFit(sections={"thigh_l": thigh, "lower_leg_l": shin, "waist": waist},
                  joints={"knee_l": knee, "hip_l": np.array([0.1, 0, 0.9])})
    # mitre normal (down + forward) / sqrt(2): signed distance d along it, score d / (0.3 * width)
    n = np.array([0, -1.0, -1.0]) / np.sqrt(2)
    d = np.array([-0.02, -0.005, 0.005, 0.02, 0.5])
    side = np.cross(n, [1.0, 0, 0])                    # along the plane: no effect
    pts = knee + d[:, None] * n + 0.03 * side
    k, s = I["thigh_l"], I["lower_leg_l"]
    score = C.joint_plane_score(pts, np.full(5, k), np.full(5, s), fit, 0.3)
    assert np.allclose(score, np.clip(d / (0.3 * shin.width), -1, 1))
    # the hip lies a whole radius off the waist's axis: a side joint, no plane
    hip = C.joint_plane_score(pts, np.full(5, I["waist"]), np.full(5, k), fit, 0.3)
    assert np.all(hip == 0)


def test_three_or_more_keeps_the_surface_the_point_lies_on():
    """An arm point against the torso (chest, waist, arm; on the arm's surface) whose nearest point
    with fewer labels is a torso point (chest, waist): it copies from the arm's side instead."""
    P = np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    c, w, a = I["chest"], I["waist"], I["upper_arm_l"]
    m = np.zeros((3, 11), bool)
    m[0, [c, w, a]] = True
    m[1, [c, w]] = True             # nearest with fewer: torso
    m[2, [c, a]] = True             # next: chest and arm
    r = np.full((3, 11), np.nan)
    r[0, [c, w, a]] = [0.06, 0.07, 0.0]        # on the arm's surface
    widths = np.full(11, 0.3)
    paper = C.reduce_to_two(m, P, r, widths)
    assert paper[0].nonzero()[0].tolist() == [c, w]
    kept = C.reduce_to_two(m, P, r, widths, keep_nearest=0.1)
    off = C.reduce_to_two(m, P, r + 0.05, widths, keep_nearest=0.1)    # off its surface: the paper's
    assert off[0].nonzero()[0].tolist() == [c, w]
    assert kept[0].nonzero()[0].tolist() == [c, a]


def test_joint_plane_is_the_proximal_cross_section_where_the_joint_lies_inside_the_distal_section():
    """A spine: the chest starts 0.1 m below the joint at which it bends forward 30 degrees; the
    body below the bend follows the waist, so the plane at the chest's end is horizontal."""
    joint = np.array([0, 0, 1.3])
    tilt = np.array([0, -np.sin(np.radians(30)), np.cos(np.radians(30))])
    start = joint - 0.1 * tilt
    waist = SectionShape("waist", start, [0, start[1], 0.95], [0.15, 0.1], X)
    chest = SectionShape("chest", start, start + 0.35 * tilt, [0.15, 0.1], X)
    fit = BodyFit(sections={"waist": waist, "chest": chest}, joints={"chest": joint})
    # points in front of and behind the axis, 1 cm above the chest's end: the mitre would tilt
    pts = start + np.array([[0, -0.12, 0.01], [0, 0.12, 0.01], [0, -0.12, -0.01], [0, 0.12, -0.01]])
    w, c = np.full(4, I["waist"]), np.full(4, I["chest"])
    flat = C.joint_plane_score(pts, w, c, fit, 0.3, mitre_band=0.1)
    assert np.allclose(flat, np.array([0.01, 0.01, -0.01, -0.01]) / (0.3 * chest.width), atol=1e-3)
    mitre = C.joint_plane_score(pts, w, c, fit, 0.3)
    assert mitre[0] > 0 > mitre[1]          # the mitre tilts forward: the front point goes to the chest


def test_the_joint_planes_are_cut_at_the_seams_not_at_the_joints():
    """The clustering reads a fit's seams (where its sections meet), not its reported joints: moving
    the joints 30 cm leaves the chest's plane where it was; moving the seam moves it."""
    joint = np.array([0, 0, 1.3])
    waist = SectionShape("waist", [0, 0, 0.95], joint, [0.15, 0.1], X)
    chest = SectionShape("chest", joint, [0, 0, 1.65], [0.15, 0.1], X)
    fit = BodyFit(sections={"waist": waist, "chest": chest}, joints={"chest": joint})
    pts = joint + np.array([[0, -0.12, 0.02], [0, 0.12, 0.02], [0, -0.12, -0.02], [0, 0.12, -0.02]])
    w, c = np.full(4, I["waist"]), np.full(4, I["chest"])
    at = C.joint_plane_score(pts, w, c, fit, 0.3)
    assert (at[:2] > 0).all() and (at[2:] < 0).all()
    away = BodyFit(sections=fit.sections, joints={"chest": joint + [0, 0.3, 0.0]}, seams={"chest": joint})
    assert np.array_equal(C.joint_plane_score(pts, w, c, away, 0.3), at)
    cut = BodyFit(sections=fit.sections, joints={"chest": joint}, seams={"chest": joint + [0, 0.3, 0.0]})
    assert not np.array_equal(C.joint_plane_score(pts, w, c, cut, 0.3), at)

def test_side_joint_plane_is_the_arms_cross_section_through_the_shoulder():
    """A hanging arm beside the chest: points below the shoulder joint score for the arm, points
    above for the chest; none in the arm's cap above its column; none at a hip below the waist."""
    shoulder = np.array([0.2, 0, 1.40])
    chest = SectionShape("chest", [0, 0, 1.15], [0, 0, 1.45], [0.15, 0.10], X)
    arm = SectionShape("upper_arm_l", shoulder + [0, 0, 0.04], [0.2, 0, 1.10], [0.045, 0.045], X)
    waist = SectionShape("waist", [0, 0, 1.15], [0, 0, 0.95], [0.15, 0.10], X)
    thigh = SectionShape("thigh_l", [0.09, 0, 0.92], [0.09, 0, 0.5], [0.07, 0.07], X)
    fit = BodyFit(sections={"chest": chest, "upper_arm_l": arm, "waist": waist, "thigh_l": thigh},
                  joints={"shoulder_l": shoulder, "hip_l": np.array([0.09, 0, 0.92])})
    pts = shoulder + np.array([[-0.03, 0, -0.02], [-0.03, 0, 0.02], [0, 0, 0.06]])
    c, a = np.full(3, I["chest"]), np.full(3, I["upper_arm_l"])
    score = C.joint_plane_score(pts, c, a, fit, 0.3, side_planes=True)
    reach = 0.3 * arm.width
    assert np.allclose(score, [0.02 / reach, -0.02 / reach, 0.0])
    assert np.all(C.joint_plane_score(pts, c, a, fit, 0.3) == 0)      # off: no plane
    hip = C.joint_plane_score(pts - [0.1, 0, 0.5], np.full(3, I["waist"]), np.full(3, I["thigh_l"]),
                              fit, 0.3, side_planes=True)
    assert np.all(hip == 0)


def test_joint_plane_splits_an_overlap_of_the_columns_in_its_middle():
    """Upper arm down to z = 1.08, forearm from z = 1.12: the plane is at z = 1.10."""
    upper = SectionShape("upper_arm_l", [0, 0, 1.4], [0, 0, 1.08], [0.045, 0.045], X)
    fore = SectionShape("forearm_l", [0, 0, 1.12], [0, 0, 0.8], [0.045, 0.045], X)
    fit = BodyFit(sections={"upper_arm_l": upper, "forearm_l": fore},
                  joints={"elbow_l": np.array([0, 0, 1.1])})
    z = np.array([1.13, 1.11, 1.10, 1.09, 1.07])
    pts = np.column_stack([np.full(5, 0.045), np.zeros(5), z])
    score = C.joint_plane_score(pts, np.full(5, I["upper_arm_l"]), np.full(5, I["forearm_l"]), fit, 0.3)
    assert np.allclose(score, np.clip((1.10 - z) / (0.3 * fore.width), -1, 1))


def test_a_point_claimed_across_the_neck_goes_to_the_column_it_lies_in():
    """The base of the neck inside the chest's column, deeper than T_d: only the head's start cap
    claims it. It lies below the neck plane, inside the chest: it goes to the chest. A point above
    the plane, and one further below it than the reach, keep the head."""
    neck = np.array([0, 0, 1.45])
    chest = SectionShape("chest", [0, 0, 1.15], neck, [0.15, 0.10], X)
    head = SectionShape("head", neck, [0, 0, 1.65], [0.05, 0.05], X)
    fit = BodyFit(sections={"chest": chest, "head": head}, joints={"neck": neck})
    P = np.array([[0.05, 0, 1.42], [0.05, 0, 1.47], [0.05, 0, 1.38]])
    r, _, h = C.section_coordinates(P, fit)
    m = C.simple_clustering(r, C.section_widths(fit), 0.3)
    assert m[0, I["head"]] and not m[0, I["chest"]]             # the T_d shell misses the chest
    m[:, I["head"]], m[:, I["chest"]] = True, False                  # all three claimed by the head
    out = C.claim_across_joints(m, P, r, h, fit, reach=0.5)          # reach 0.5 * 0.1 m = 5 cm
    assert out[0].nonzero()[0].tolist() == [I["chest"]]
    assert out[1].nonzero()[0].tolist() == [I["head"]]
    assert out[2].nonzero()[0].tolist() == [I["head"]]
    # outside the chest's column (beside it): not the chest's
    side = np.array([[0.16, 0, 1.42]])
    rs, _, hs = C.section_coordinates(side, fit)
    ms = np.zeros((1, 11), bool)
    ms[0, I["head"]] = True
    assert C.claim_across_joints(ms, side, rs, hs, fit, reach=0.5)[0, I["head"]]


def test_joint_plane_follows_the_bones_between_the_joints():
    """An upright waist column whose spine (pelvis -> chest joint) leans back 21.8 degrees: with
    ``bones`` the plane's normal bisects the spine and the chest's bone, not the columns' axes; a
    joint placed far off its column (a bone 63 degrees from the axis) is not used."""
    j = np.array([0, 0, 1.2])
    waist = SectionShape("waist", j, [0, 0, 0.95], [0.15, 0.1], X)
    chest = SectionShape("chest", j, [0, 0, 1.5], [0.15, 0.1], X)
    joints = {"pelvis": np.array([0, -0.1, 0.95]), "chest": j, "neck": np.array([0, 0, 1.5])}
    fit = BodyFit(sections={"waist": waist, "chest": chest}, joints=joints)
    pts = j + np.array([[0, -0.1, 0.01], [0, 0.1, 0.01], [0, 0, -0.02]])
    w, c = np.full(3, I["waist"]), np.full(3, I["chest"])
    spine = np.array([0, 0.1, 0.25]) / np.hypot(0.1, 0.25)
    normal = (spine + [0, 0, 1]) / np.linalg.norm(spine + [0, 0, 1])
    score = C.joint_plane_score(pts, w, c, fit, 0.3, bones=True)
    assert np.allclose(score, (pts - j) @ normal / (0.3 * chest.width))
    assert score[0] < 0 < score[1]        # 1 cm above the joint: waist in front, chest behind
    axes = C.joint_plane_score(pts, w, c, fit, 0.3)
    assert np.allclose(axes, (pts[:, 2] - 1.2) / (0.3 * chest.width))
    joints["pelvis"] = np.array([0, -0.5, 0.95])
    moved = BodyFit(sections=fit.sections, joints=joints)
    off = C.joint_plane_score(pts, w, c, moved, 0.3, bones=True)
    assert np.allclose(off, axes)


def test_shoulder_plane_tilts_toward_the_midline():
    """A hanging arm: with the tilt, a point outside and above the joint (the deltoid) scores for
    the arm, a point inside and below it (the chest beside the armpit) for the chest; an arm held
    out along the shoulder line keeps the plain cross-section."""
    shoulder = np.array([0.2, 0, 1.40])
    chest = SectionShape("chest", [0, 0, 1.15], [0, 0, 1.45], [0.15, 0.10], X)
    arm = SectionShape("upper_arm_l", shoulder + [0, 0, 0.04], [0.2, 0, 1.10], [0.045, 0.045], X)
    joints = {"shoulder_l": shoulder, "shoulder_r": np.array([-0.2, 0, 1.40])}
    fit = BodyFit(sections={"chest": chest, "upper_arm_l": arm}, joints=joints)
    pts = shoulder + np.array([[0.04, 0, 0.02], [-0.04, 0, -0.02]])
    c, a = np.full(2, I["chest"]), np.full(2, I["upper_arm_l"])
    plain = C.joint_plane_score(pts, c, a, fit, 0.3, side_planes=True)
    assert plain[0] < 0 < plain[1]
    tilted = C.joint_plane_score(pts, c, a, fit, 0.3, side_planes=True, side_tilt=1.0)
    normal = np.array([1.0, 0, -1.0]) / np.sqrt(2)                # down, tilted 45 deg outward
    assert np.allclose(tilted, (pts - shoulder) @ normal / (0.3 * arm.width))
    assert tilted[1] < 0 < tilted[0]
    out = SectionShape("upper_arm_l", shoulder, [0.5, 0, 1.40], [0.045, 0.045], [0, 0, 1.0])
    fit_t = BodyFit(sections={"chest": chest, "upper_arm_l": out}, joints=joints)     # T-pose
    q = shoulder + np.array([[0.02, 0, 0.03], [0.02, 0, -0.03]])
    assert np.allclose(C.joint_plane_score(q, c, a, fit_t, 0.3, side_planes=True, side_tilt=1.0),
                       C.joint_plane_score(q, c, a, fit_t, 0.3, side_planes=True))


def squatting_hip():
    """A waist and a left thigh held forward (the hip flexed 90 degrees), the hip joint beside the
    waist's column within its length (as the fits place a squat's)."""
    hip = np.array([0.1, 0, 0.47])
    waist = SectionShape("waist", [0, 0, 0.45], [0, 0, 0.70], [0.15, 0.11], X)
    thigh = SectionShape("thigh_l", hip + [0, -0.03, 0], hip + [0, -0.43, 0], [0.085, 0.085], X)
    fit = BodyFit(sections={"waist": waist, "thigh_l": thigh},
                  joints={"hip_l": hip, "hip_r": hip * [-1, 1, 1],
                          "pelvis": np.array([0, 0, 0.45])})
    return hip, waist, thigh, fit


def test_hip_plane_is_the_groins_crease_tilted_out():
    """A flexed hip: the plane is the mitre of the waist's downward axis and the thigh's, tilted
    out, ``offset`` thigh widths past the joint; the lower belly above the thigh's start scores
    for the waist, the thigh's top further along for the thigh. The shoulders' plane (the thigh's
    cross-section through the joint) gave the belly to the thigh. `flexed_hip_plane` gives the
    plane here (no crotch along the thighs), not with the legs down."""
    hip, waist, thigh, fit = squatting_hip()
    pts = hip + np.array([[0, -0.10, 0.10], [0, -0.15, 0.085]])        # belly, top of the thigh
    w, t = np.full(2, I["waist"]), np.full(2, I["thigh_l"])
    old = C.joint_plane_score(pts, w, t, fit, 0.3, side_planes=True, side_tilt=1.0)
    assert old[0] > 0                                   # the belly went to the thigh
    score = C.joint_plane_score(pts, w, t, fit, 0.3, side_planes=True, side_tilt=1.0,
                                hip_plane=(0.55, 0.15))
    n = np.array([0.55, -1 / np.sqrt(2), -1 / np.sqrt(2)])
    n = n / np.linalg.norm(n)                           # down + forward, tilted out (+x)
    origin = hip + 0.15 * thigh.width * n
    assert np.allclose(score, np.clip((pts - origin) @ n / (0.3 * thigh.width), -1, 1))
    assert score[0] < 0 < score[1]
    cloud = np.concatenate([column_points(waist), column_points(thigh)])
    assert C.flexed_hip_plane(cloud, fit, ClusterParams()) == (0.55, 0.15)
    assert C.flexed_hip_plane(cloud, fit, ClusterParams(hip_planes=False)) is None
    down = SectionShape("thigh_l", hip + [0, 0, -0.03], hip + [0, 0, -0.43], [0.07, 0.07], X)
    right = SectionShape("thigh_r", down.start * [-1, 1, 1], down.end * [-1, 1, 1], [0.07, 0.07], X)
    legs = {"waist": waist, "thigh_l": down, "thigh_r": right}
    standing = BodyFit(sections=legs, joints=fit.joints)
    crotch = np.array([[0, 0, 0.38], [0.005, 0.01, 0.385]])           # points between the legs
    cloud = np.concatenate([column_points(waist), column_points(down), column_points(right),
                            crotch])
    assert C.flexed_hip_plane(cloud, standing, ClusterParams()) is None

