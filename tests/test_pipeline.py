"""The whole reconstruction: analytic capsule body, the shipped postures, bad input, the PLY and CLI."""

import warnings

import numpy as np
import pytest

from bodyscan.recon import ReconError, ReconParams, reconstruct
from bodyscan.recon.model import SECTIONS, BodyFit, SectionShape
from bodyscan.recon.surface.mesh import model_outward
from views import front_rear_zbuffer

X = np.array([1.0, 0, 0])
ARMS = [SECTIONS.index(s) for s in ("upper_arm_l", "upper_arm_r", "forearm_l", "forearm_r")]
TORSO = [SECTIONS.index(s) for s in ("chest", "waist")]


def capsule_body(gap=0.02, pixel=0.01, seed=0, noise=0.0005):
    """A body of model sections (arms ``gap`` from the torso, thighs ``gap`` apart), scanned from
    the front and the back on a ``pixel`` grid (z-buffer, so inner sides are occluded), with
    Gaussian ``noise`` (metres, each axis).

    Returns points (n, 3), true section (n,), true normal (n, 3), view_dir (n, 3), the exact fit.
    """
    arm_x = 0.15 + gap + 0.045
    leg_x = 0.07 + gap / 2
    S = {
        "waist": ((0, 0, 1.15), (0, 0, 0.88), (0.15, 0.10)),
        "chest": ((0, 0, 1.15), (0, 0, 1.42), (0.15, 0.10)),
        "head": ((0, 0, 1.45), (0, 0, 1.62), (0.08, 0.09)),
        "upper_arm_l": ((arm_x, 0, 1.40), (arm_x, 0, 1.12), (0.045, 0.045)),
        "upper_arm_r": ((-arm_x, 0, 1.40), (-arm_x, 0, 1.12), (0.045, 0.045)),
        "forearm_l": ((arm_x, 0, 1.12), (arm_x, 0, 0.86), (0.04, 0.04)),
        "forearm_r": ((-arm_x, 0, 1.12), (-arm_x, 0, 0.86), (0.04, 0.04)),
        "thigh_l": ((leg_x, 0, 0.85), (leg_x, 0, 0.48), (0.07, 0.07)),
        "thigh_r": ((-leg_x, 0, 0.85), (-leg_x, 0, 0.48), (0.07, 0.07)),
        "lower_leg_l": ((leg_x, 0, 0.48), (leg_x, 0, 0.08), (0.05, 0.05)),
        "lower_leg_r": ((-leg_x, 0, 0.48), (-leg_x, 0, 0.08), (0.05, 0.05)),
    }
    sections = {k: SectionShape(k, s, e, r, X) for k, (s, e, r) in S.items()}
    pts, lab = [], []
    for j, name in enumerate(SECTIONS):
        sh = sections[name]
        p = sh.surface_points(n_theta=int(2 * np.pi * sh.radii.max() / 0.003), n_h=int(sh.length / 0.003))
        pts.append(p)
        lab.append(np.full(len(p), j))
    P, L = np.concatenate(pts), np.concatenate(lab)
    inside = np.zeros(len(P), bool)
    for j, name in enumerate(SECTIONS):
        inside |= (sections[name].coords(P)[0] < -1e-4) & (L != j)
    P, L = P[~inside], L[~inside]
    N = np.zeros_like(P)
    for j, name in enumerate(SECTIONS):
        N[L == j] = model_outward(sections[name], P[L == j])
    keep, vd = front_rear_zbuffer(P, N, pixel)
    rng = np.random.default_rng(seed)
    P = P[keep] + rng.normal(0, noise, (keep.sum(), 3))
    joints = {"neck": np.array(S["head"][0]), "chest": np.array(S["chest"][0]),
              "shoulder_l": np.array(S["upper_arm_l"][0]), "shoulder_r": np.array(S["upper_arm_r"][0]),
              "elbow_l": np.array(S["forearm_l"][0]), "elbow_r": np.array(S["forearm_r"][0]),
              "hip_l": np.array(S["thigh_l"][0]), "hip_r": np.array(S["thigh_r"][0]),
              "knee_l": np.array(S["lower_leg_l"][0]), "knee_r": np.array(S["lower_leg_r"][0])}
    return P, L[keep], N[keep], vd[keep], BodyFit(sections=sections, joints=joints)


@pytest.fixture(scope="module")
def capsules():
    P, L, N, vd, fit = capsule_body()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = {m: reconstruct(P, m, view_dir=vd, fit=fit) for m in ("simple", "proposed")}
    return P, L, N, vd, fit, recs


def outside_distance(fit, x):
    """(k,) distance (metres) of ``x`` outside the union of the model sections (<= 0 inside)."""
    return np.min([s.coords(x)[0] for s in fit.sections.values()], axis=0)


def test_no_triangle_joins_an_arm_to_the_torso_2cm_away(capsules):
    P, L, N, vd, fit, recs = capsules
    lab = L[recs["proposed"].point_faces]
    assert not (np.isin(lab, ARMS).any(axis=1) & np.isin(lab, TORSO).any(axis=1)).any()
    thighs = [SECTIONS.index("thigh_l"), SECTIONS.index("thigh_r")]
    assert not ((lab == thighs[0]).any(axis=1) & (lab == thighs[1]).any(axis=1)).any()


def test_capsule_body_clustering_and_surface_against_truth(capsules):
    P, L, N, vd, fit, recs = capsules
    rec = recs["proposed"]
    # 0.954 with the paper's joint rule alone (joint_plane_weight=0); the joint plane gives the
    # capsules' domes around a narrower child (chest around the head, thigh around the lower leg)
    # to the child: 0.937 here, while the shipped postures gain (mean 0.945 -> 0.951, squat +4)
    assert rec.point_sections[np.arange(len(P)), L].mean() > 0.935
    assert (rec.point_sections.sum(axis=1) <= 2).all()
    v = rec.vertices[rec.faces]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    air = outside_distance(fit, v.mean(axis=1)) > 0.005
    assert area[air].sum() < 0.005 * area.sum()
    # the rules' air against the baseline's, on the triangles over the points (the curved
    # subdivision lifts one of proposed's faces from 4.8 to 5.3 mm outside: 0.3 cm2)
    simple = recs["simple"]
    vs, v = simple.vertices[simple.faces], rec.vertices[rec.point_faces]
    area_s = 0.5 * np.linalg.norm(np.cross(vs[:, 1] - vs[:, 0], vs[:, 2] - vs[:, 0]), axis=1)
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    assert area_s[outside_distance(fit, vs.mean(axis=1)) > 0.005].sum() > \
        area[outside_distance(fit, v.mean(axis=1)) > 0.005].sum()


def test_mesh_is_valid_and_outward(capsules):
    P, L, N, vd, fit, recs = capsules
    rec = recs["proposed"]
    f = rec.faces
    v = rec.vertices[f]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    assert (area > 0).all()
    assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, c = np.unique(e, axis=0, return_counts=True)
    assert (c > 2).mean() < 0.005
    f = rec.point_faces                           # the true normals are per point
    v = rec.vertices[f]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert (np.einsum("ij,ij->i", n, N[f].mean(axis=1)) > 0).mean() > 0.98
    assert rec.face_section.dtype == np.int8 and len(rec.face_section) == len(rec.faces)
    assert set(rec.times) >= {"cluster", "surface", "total"}


def test_write_mesh_round_trip(capsules, tmp_path):
    import trimesh

    rec = capsules[-1]["proposed"]
    path = rec.write(tmp_path / "mesh.ply")
    m = trimesh.load(path, process=False)
    assert np.array_equal(np.asarray(m.faces), rec.faces)
    assert np.array_equal(m.vertices, rec.vertices)          # double: the cloud's points exactly
    bits = np.asarray(m.metadata["_ply_raw"]["vertex"]["data"]["sections"]).astype(int)
    n = len(rec.point_sections)                              # then the curved subdivision's vertices
    assert np.array_equal((bits[:n, None] >> np.arange(11)) & 1 == 1, rec.point_sections)
    assert len(bits) > n and not bits[n:].any()
    raw = path.read_bytes()
    assert b"property uchar section" in raw[:1000]
    sec = np.frombuffer(raw[-len(rec.faces) * 14:], dtype=[("n", "u1"), ("i", "<i4", 3), ("s", "u1")])["s"]
    assert np.array_equal(sec, rec.face_section)


# -- bad input ---------------------------------------------------------------------------------------
def test_bad_points_are_refused_with_a_clear_message(capsules):
    fit = capsules[4]
    good = capsules[0]
    for bad, msg in [(np.zeros((5, 2)), r"\(n, 3\)"), (good[:50], "at least"),
                     (np.vstack([good, [[np.nan, 0, 0]]]), "NaN"), (good * 1000, "metres")]:
        with pytest.raises(ReconError, match=msg):
            reconstruct(bad, fit=fit)
    with pytest.raises(ReconError, match="unknown method"):
        reconstruct(good, "poisson", fit=fit)
    with pytest.raises(ReconError, match="view_dir"):
        reconstruct(good, fit=fit, view_dir=np.zeros((3, 3)))


def test_missing_section_is_skipped_with_a_warning_and_output_not_empty(capsules):
    P, L, N, vd, fit, _ = capsules
    keep = L != SECTIONS.index("forearm_l")
    arm = fit.sections["forearm_l"]
    moved = BodyFit(sections={**fit.sections, "forearm_l": arm.replace(start=arm.start + 5, end=arm.end + 5)},
                    joints=fit.joints)
    with pytest.warns(UserWarning, match="forearm_l"):
        rec = reconstruct(P[keep], fit=moved, view_dir=vd[keep])
    assert "forearm_l" in rec.skipped and len(rec.faces) > 1000


def without_left_arm(gap):
    """`capsule_body` with its left arm ``gap`` from the torso, 5 mm pixels, reconstructed by
    `proposed` from the exact fit without the arm (a limb the fit missed): P, L, fit, rec."""
    P, L, _, vd, fit = capsule_body(gap=gap, pixel=0.005)
    part = BodyFit(sections={k: s for k, s in fit.sections.items() if k not in ("upper_arm_l", "forearm_l")},
                   joints=fit.joints)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(P, "proposed", fit=part, view_dir=vd)
    return P, L, fit, rec


def test_points_of_a_limb_the_fit_missed_are_denoised_with_their_far_part():
    # the left arm 8.5 cm from the torso and missing from the fit: most of its forearm lies in no
    # section and is meshed as a far part; its points are denoised with that part's own points
    P, L, fit, rec = without_left_arm(0.085)
    arm = fit.sections["forearm_l"]
    used = np.zeros(len(P), dtype=bool)
    used[rec.point_faces.ravel()] = True
    far = (L == SECTIONS.index("forearm_l")) & used & ~rec.point_sections.any(axis=1)
    assert far.sum() > 500
    before = np.sqrt(np.mean(arm.coords(P[far])[0] ** 2))
    after = np.sqrt(np.mean(arm.coords(rec.vertices[:len(P)][far])[0] ** 2))
    assert after < 0.5 * before   # 0.50 -> 0.20 mm (the noise: 0.5 mm); was not moved
    faces = rec.point_faces[far[rec.point_faces].all(axis=1)]
    tri = rec.vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    agree = np.abs(np.einsum("ij,ij->i", n, model_outward(arm, tri.mean(axis=1)))) > np.cos(np.radians(10))
    assert agree.mean() > 0.9   # 0.98 (0.56 undenoised)


def test_a_cloud_is_denoised_only_when_it_holds_noise_to_take_out():
    # noise-free, the capsule body's fits measure their own error, far under denoise_min_noise
    # (0.04 spacings): its points are meshed as measured. With 1.5 mm of noise on the 10 mm
    # pitch (0.15 spacings) they are moved; so is the noise-free cloud with denoise_min_noise=0.
    for noise, floor in ((0.0, 0.04), (0.0015, 0.04), (0.0, 0.0)):
        P, L, N, vd, fit = capsule_body(noise=noise)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = reconstruct(P, "proposed", ReconParams.from_overrides({"denoise_min_noise": floor}),
                              view_dir=vd, fit=fit)
        used = np.unique(rec.point_faces)
        if noise:
            assert 0.5 * noise < rec.noise < 1.5 * noise
            assert np.median(rec.moved[used]) > 0.2 * noise
        else:
            assert rec.noise < 0.01 * 0.01      # 0.01 spacings
            if floor:
                assert (rec.moved == 0).all() and (rec.vertices[:len(P)] == P).all()
            else:
                assert 0 < rec.moved.max() < 0.5e-3     # the noise-free limit: 0.5 mm


def test_an_unfitted_arm_against_the_trunk_is_meshed_on_its_own_charts_without_air():
    # the left arm 1 cm from the torso and missing from the fit: its points lie within T_d of the
    # trunk and are clustered into it, whose chart (one layer around its axis) leaves them out
    # (a third of them, before); the points no face uses are meshed as parts of their own
    P, L, fit, rec = without_left_arm(0.01)
    used = np.zeros(len(P), dtype=bool)
    used[rec.point_faces.ravel()] = True
    for name in ("upper_arm_l", "forearm_l"):
        on = L == SECTIONS.index(name)
        assert used[on].mean() > 0.97   # 0.99 (0.68 for the whole arm before)
        tri = rec.vertices[rec.point_faces[on[rec.point_faces].all(axis=1)]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        out = np.einsum("ij,ij->i", n, model_outward(fit.sections[name], tri.mean(axis=1)))
        # turned outward: 0.95-0.99. The chords over the upper arm's inner flank, from the front
        # head's image to the rear's, lie on the trunk's chart and face the trunk's way (130 of
        # 2750 faces; kept since the peel measures them across the heads' axis)
        assert np.mean(out > 0) > 0.94
    assert rec.points_unmeshed < 0.01 * len(P)
    tri = rec.vertices[rec.faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    gap = np.min([s.coords(tri.mean(axis=1))[0] for s in fit.sections.values()], axis=0)
    assert area[gap > 0.005].sum() < 0.002 * area.sum()   # nothing in the air between arm and trunk


def test_a_fit_far_from_the_cloud_is_an_error_not_an_empty_mesh(capsules):
    P, _, _, _, fit, _ = capsules
    far = BodyFit(sections={k: s.replace(start=s.start + 5, end=s.end + 5) for k, s in fit.sections.items()},
                  joints={})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ReconError, match="no surface"):
            reconstruct(P, fit=far)


def test_params_reach_the_stages(capsules):
    P, L, N, vd, fit, recs = capsules
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(P, "simple", ReconParams.from_overrides({"t_d": 0.05}), view_dir=vd, fit=fit)
    # a tighter T_d leaves fewer points in several sections
    assert rec.point_sections.sum(axis=1).mean() < recs["simple"].point_sections.sum(axis=1).mean()


# -- the shipped postures, scanned with the paper preset, oracle posture ----------------------------
ARMPIT_CROTCH = [("chest", "upper_arm_l"), ("chest", "upper_arm_r"), ("waist", "thigh_l"),
                 ("waist", "thigh_r"), ("thigh_l", "thigh_r")] + [
    (t, a) for t in ("chest", "waist") for a in ("upper_arm_l", "upper_arm_r", "forearm_l", "forearm_r")]


def _shipped():
    """The shipped postures: tracked in the repository, so an import error or an empty library
    fails here (at collection) instead of leaving the tests below nothing to run."""
    from bodyscan.poses.library import list_bodies

    names = list_bodies()
    assert names, "no shipped postures"
    return names


@pytest.fixture(scope="module")
def scored():
    """Per posture name: scan, reconstructions and scores, computed once and cached."""
    return {}


def _score(name, cache):
    if name in cache:
        return cache[name]
    from bodyscan.benchmarks import metrics as M
    from bodyscan.benchmarks.oracle import fit_from_body
    from bodyscan.poses import load_body
    from bodyscan.simulator.config import preset
    from bodyscan.simulator.scan import scan

    body = load_body(name)
    s = scan(body, preset("paper"))
    fit = fit_from_body(body)
    truth = M.GroundTruth.from_body(body, M.MetricParams(n_samples=1000))
    out = {"scan": s, "body": body}
    for key, method, over in (("simple", "simple", {}), ("proposed", "proposed", {}),
                              ("limited", "proposed", {"max_edge_factor": 4})):
        out[key] = _reconstruct_and_score(s, truth, fit, method, over)
    cache[name] = out
    return out


def _reconstruct_and_score(s, truth, fit, method, over=None):
    """Reconstruct scan ``s`` with ``fit`` and score it against ``truth`` (a dict)."""
    from bodyscan.benchmarks import metrics as M

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(s.points, method, ReconParams.from_overrides(over or {}), view_dir=s.view_dir, fit=fit)
    faces = rec.point_faces    # the ground truth is per point: the triangles over the points
    tf = s.gt_face[faces]
    br = M.bridging(rec.vertices, faces, tf, truth, truth.params)
    sec = truth.face_section[tf]
    pair = np.zeros(len(faces), bool)
    for a, b in ARMPIT_CROTCH:
        pair |= (sec == SECTIONS.index(a)).any(axis=1) & (sec == SECTIONS.index(b)).any(axis=1)
    _, area = M.face_normals(rec.vertices, faces)
    return {
        "rec": rec,
        "accuracy": M.section_accuracy(rec.point_sections, s.gt_section),
        "spurious": M.spurious(rec.vertices, faces, tf, truth, truth.params)["spurious_area_fraction"],
        "bridging": br["bridging_area_fraction"],
        "armpit_crotch_bridging": float(area[br["_bridging"] & pair].sum() / area.sum()),
    }


#: Known failures, kept visible: (posture, reason). None at this commit (heavy_standing's armpit
#: bridging, 0.60 %, went with the fold and carving rules of `recon.surface`).
KNOWN: dict = {}

#: Postures whose bridging (oracle posture) is above the issue's 0.5 %, with their ceiling: a 22 cm2
#: cover of the armpit the sensor never saw, its centroid 5.1 mm out (measured 0.60 %).
BRIDGING_ABOVE = {"woman_standing": 0.007}


#: Postures below the issue's 95 % "truth among labels", with their floor: none (the lowest,
#: seated, measured 0.9503, loses most at the bent chest-waist joint and at the hips, joint rule,
#: 0.5 % each; see ``python -m bodyscan.benchmarks.recon_table --bodies seated``).
BELOW_95: dict = {}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN[n], strict=True))
                                  if n in KNOWN else n for n in _shipped()])
def test_shipped_posture_against_ground_truth(name, scored):
    r = _score(name, scored)
    prop, simple, limited = r["proposed"], r["simple"], r["limited"]
    # sections of the points: the issue asks >= 95 % ("truth among labels"; measured 0.950 to 0.982
    # except BELOW_95); 1/m-scored (a seam point in two sections scores 1/2) 0.938 (seated) to 0.970
    assert prop["accuracy"]["section_accuracy_any"] >= BELOW_95.get(name, 0.95)
    assert prop["accuracy"]["section_accuracy"] >= 0.93
    assert prop["accuracy"]["section_accuracy"] > simple["accuracy"]["section_accuracy"]
    # the paper's spurious-patch test
    assert prop["spurious"] < simple["spurious"]
    # no surface across armpits and crotch, little in the air anywhere (hands, chin)
    assert prop["armpit_crotch_bridging"] < 0.005
    assert prop["bridging"] < BRIDGING_ABOVE.get(name, 0.005) and prop["bridging"] < simple["bridging"]
    assert limited["bridging"] < 0.005


def test_shipped_postures_on_average(scored):
    """Means over every shipped posture (measured: truth among labels 0.971, 1/m-scored 0.958,
    bridging 0.18 %)."""
    rows = [_score(n, scored)["proposed"] for n in _shipped()]
    assert np.mean([r["accuracy"]["section_accuracy_any"] for r in rows]) >= 0.965
    assert np.mean([r["accuracy"]["section_accuracy"] for r in rows]) >= 0.95
    assert np.mean([r["bridging"] for r in rows]) < 0.0025


# -- the shipped postures, the whole pipeline as users run it (posture estimated) ----------------
@pytest.fixture(scope="module")
def estimated():
    """Per shipped posture: proposed and simple, posture estimated from the cloud (one fit shared)."""
    from bodyscan.benchmarks import metrics as M
    from bodyscan.poses import load_body
    from bodyscan.recon import estimate_posture
    from bodyscan.simulator.config import preset
    from bodyscan.simulator.scan import scan

    out = {}
    for name in _shipped():
        body = load_body(name)
        s = scan(body, preset("paper"))
        truth = M.GroundTruth.from_body(body, M.MetricParams(n_samples=1000))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = estimate_posture(s.points)
        out[name] = {m: _reconstruct_and_score(s, truth, fit, m) for m in ("simple", "proposed")}
        out[name]["scan"] = s
    return out


def test_estimated_posture_on_the_library(estimated):
    """Regression level of the whole pipeline on every shipped posture (measured at this commit:
    truth among labels mean 0.965, min 0.952 heavy_standing; 1/m-scored min 0.940 heavy_standing;
    bridging mean 0.23 %)."""
    prop = [r["proposed"] for r in estimated.values()]
    assert np.mean([r["accuracy"]["section_accuracy_any"] for r in prop]) >= 0.96
    assert min(r["accuracy"]["section_accuracy_any"] for r in prop) >= 0.95
    assert min(r["accuracy"]["section_accuracy"] for r in prop) >= 0.935
    assert np.mean([r["bridging"] for r in prop]) < 0.0035
    for name, r in estimated.items():   # the paper's claim, posture by posture
        assert r["proposed"]["spurious"] < r["simple"]["spurious"], name


def test_estimated_posture_bridging_meets_the_issue_target(estimated):
    """Issue 5, the pipeline as users run it (posture estimated), on every shipped posture: bridging
    (surface in the air) below 0.5 % of the area (measured 0.07 to 0.39 %)."""
    for name, r in estimated.items():
        assert r["proposed"]["bridging"] < 0.005, name


def test_estimated_posture_meets_the_issue_targets(estimated):
    """Issue 5, the pipeline as users run it (posture estimated), on every shipped posture: truth
    among the point's labels >= 95 % (measured 0.952 heavy_standing, 0.954 squat to 0.979 t_pose;
    tall_walking 0.947 -> 0.976 since it is fitted in the facing its feet show, `feet_forward`; squat
    0.945 -> 0.954 since the flexed hips' plane, `hip_planes`)."""
    for name, r in estimated.items():
        assert r["proposed"]["accuracy"]["section_accuracy_any"] >= 0.95, name


@pytest.mark.parametrize("name", _shipped()[:3])
def test_shipped_posture_mesh_is_valid(name, scored):
    r = _score(name, scored)
    _assert_valid_mesh(r["proposed"]["rec"], r["scan"])


def _assert_valid_mesh(rec, s):
    """Issue 5's validity: no zero-area or duplicate faces, non-manifold edges under 0.5 %, and
    outward orientation (against the true normals at the sampled points, 95 % of the area)."""
    f = rec.faces
    v = rec.vertices[f]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    assert (area > 0).all()
    assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, c = np.unique(e, axis=0, return_counts=True)
    assert (c > 2).mean() < 0.005
    f = rec.point_faces    # the true normals are per point: the triangles over the points
    v = rec.vertices[f]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    outward = np.einsum("ij,ij->i", n, s.gt_normal[f].mean(axis=1)) > 0
    assert 0.5 * np.linalg.norm(n[outward], axis=1).sum() > 0.95 * 0.5 * np.linalg.norm(n, axis=1).sum()


def test_estimated_posture_meshes_are_valid(estimated):
    """The meshes users get (posture estimated) are valid on every shipped posture."""
    for name, r in estimated.items():
        _assert_valid_mesh(r["proposed"]["rec"], r["scan"])


# -- the command ----------------------------------------------------------------------------------
def test_cli_reconstructs_a_cloud_with_a_given_fit(tmp_path, capsys, capsules):
    import json

    import trimesh

    from bodyscan.benchmarks.cli import main

    P, L, N, vd, fit, _ = capsules
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(P).export(cloud)
    fit_json = tmp_path / "fit.json"
    fit_json.write_text(json.dumps(fit.to_dict()))
    out, png = tmp_path / "mesh.ply", tmp_path / "preview.png"
    code = main(["reconstruct", str(cloud), "--out", str(out), "--fit", str(fit_json),
                 "--preview", str(png), "--param", "t_d=0.3"])
    assert code == 0
    m = trimesh.load(out, process=False)
    assert len(m.vertices) > len(P) and len(m.faces) > 1000    # the points, then the curved subdivision's
    assert np.abs(m.vertices[:len(P)] - P).max() < 0.002       # the points (denoised)
    assert png.stat().st_size > 10_000
    said = capsys.readouterr().err
    noise = float(said.split("range noise ")[1].split(" mm")[0])   # 0.5 mm per axis
    assert 0.4 < noise < 0.8 and "denoised (points moved" in said


def test_cli_user_errors_are_one_line(tmp_path, capsys, capsules):
    import trimesh

    from bodyscan.benchmarks.cli import main

    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(capsules[0]).export(cloud)
    for args, msg in [(["--param", "bogus=1"], "unknown parameter"), (["--param", "t_d"], "NAME=VALUE"),
                      (["--fit", str(tmp_path / "none.json")], "no such file")]:
        code = main(["reconstruct", str(cloud), "--out", str(tmp_path / "m.ply"), *args])
        err = capsys.readouterr().err
        assert code == 2 and msg in err and "Traceback" not in err
    code = main(["reconstruct", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "m.ply")])
    assert code == 2
