"""Real scanner conditions: denoising, outlier rejection and head registration on analytic surfaces."""

import numpy as np
import pytest

from bodyscan.recon.clean.denoise import denoise, reject_outliers
from bodyscan.recon.clean.register import _log_rotation, register_heads, register_silhouettes
from bodyscan.recon.geometry import rotvec

R = 0.05        # cylinder radius, metres
PITCH = 0.005   # scan pitch, metres


def scanned_cylinder(sigma=0.0, pitch=PITCH, radius=R, height=0.4, seed=0):
    """A vertical cylinder seen by a front camera (at -y) and a rear one (at +y), parallel
    projection on a ``pitch`` grid in x and z, with Gaussian range noise ``sigma`` along the rays.

    Returns points (n, 3), view_dir (n, 3), head (n,), true points (n, 3).
    """
    x = np.arange(-radius + pitch / 2, radius, pitch)
    z = np.arange(0.0, height, pitch)
    X, Z = np.meshgrid(x, z)
    X, Z = X.ravel(), Z.ravel()
    y = np.sqrt(radius ** 2 - X ** 2)
    true = np.concatenate([np.column_stack([X, -y, Z]), np.column_stack([X, y, Z])])
    head = np.repeat([0, 1], len(X))
    vd = np.where(head[:, None] == 0, [0.0, -1.0, 0.0], [0.0, 1.0, 0.0])
    noise = np.random.default_rng(seed).normal(0.0, sigma, len(true)) if sigma else np.zeros(len(true))
    return true - noise[:, None] * vd, vd, head, true


def radial_error(p, radius=R):
    return np.hypot(p[:, 0], p[:, 1]) - radius


@pytest.mark.parametrize("share", [0.0, 2.0])   # a fit at every point; fits shared in 2-spacing cubes
def test_denoised_cylinder_lies_within_0_3_sigma_of_the_true_surface(share):
    sigma = 0.001
    before, after = [], []
    for seed in range(3):   # the RMS over three noise draws
        p, vd, head, true = scanned_cylinder(sigma, seed=seed)
        inner = (true[:, 2] > 0.03) & (true[:, 2] < 0.37)   # the open ends have one-sided fits
        d = denoise(p, np.ones((len(p), 1), bool), PITCH, share=share)
        before.append(radial_error(p[inner]))
        after.append(radial_error(d.points[inner]))
        assert 0.3 * sigma < d.scale < 1.5 * sigma      # the scale comes from the data
        assert np.allclose(d.moved, np.linalg.norm(d.points - p, axis=1))
        assert d.moved.max() <= 3.0 * d.scale + 1e-12   # clamped
        assert not d.rejected.any()
    assert np.sqrt(np.mean(np.concatenate(before) ** 2)) > 0.5 * sigma   # the noise was there
    assert np.sqrt(np.mean(np.concatenate(after) ** 2)) < 0.3 * sigma


@pytest.mark.parametrize("share", [0.0, 2.0])
def test_noise_free_cylinder_is_not_moved(share):
    p, vd, head, true = scanned_cylinder(0.0)
    d = denoise(p, np.ones((len(p), 1), bool), PITCH, share=share)
    assert d.moved.max() < 1e-4    # 0.1 mm: the noise-free limit is 0.5 mm
    assert not reject_outliers(p, PITCH)[0].any()


def test_each_section_is_fitted_on_its_own_points():
    # two parallel cylinders 2 cm apart: denoised together as one section, the neighbourhoods
    # would straddle the gap; as two sections each stays on its own surface
    p, vd, head, true = scanned_cylinder(0.001)
    q = p + [2 * R + 0.02, 0, 0]
    both = np.concatenate([p, q])
    member = np.zeros((len(both), 2), bool)
    member[:len(p), 0] = member[len(p):, 1] = True
    d = denoise(both, member, PITCH)
    err = np.concatenate([radial_error(d.points[:len(p)]), radial_error(d.points[len(p):] - [2 * R + 0.02, 0, 0])])
    assert np.sqrt(np.mean(err ** 2)) < 0.4 * 0.001


def test_a_finger_is_denoised_within_its_own_width():
    # two finger-thin cylinders (8 mm radius) at a 5 mm pitch: a section's fits (40 points within
    # 20 mm, shared over 3-spacing cubes) span a finger's whole width and take its turn for noise
    # (worse than the noise itself); each section's own radius (a hand's: the 12 mm reach) keeps
    # its points near the true surface
    sigma, radius = 0.001, 0.008
    p, vd, head, true = scanned_cylinder(sigma, radius=radius, height=0.08)
    q = p + [0.05, 0, 0]
    both = np.concatenate([p, q])
    member = np.zeros((len(both), 2), bool)
    member[:len(p), 0] = member[len(p):, 1] = True
    d = denoise(both, member, PITCH, radius=[0.02, 0.012])
    inner = (true[:, 2] > 0.015) & (true[:, 2] < 0.065)
    wide = np.sqrt(np.mean(radial_error(d.points[:len(p)][inner], radius) ** 2))
    small = np.sqrt(np.mean(radial_error(d.points[len(p):][inner] - [0.05, 0, 0], radius) ** 2))
    raw = np.sqrt(np.mean(radial_error(p[inner], radius) ** 2))
    assert wide > raw > 0.5 * sigma
    assert small < 0.5 * sigma     # 0.4 sigma (the wide fits: 1.6 sigma)


def test_planted_outliers_are_removed():
    p, vd, head, true = scanned_cylinder(0.001)
    rng = np.random.default_rng(1)
    which = rng.choice(len(p), int(0.005 * len(p)) + 5, replace=False)
    shift = rng.uniform(0.01, 0.05, len(which)) * rng.choice([-1, 1], len(which))
    p = p.copy()
    p[which] -= shift[:, None] * vd[which]   # along the camera ray, 1 to 5 cm
    out, scale = reject_outliers(p, PITCH)
    planted = np.zeros(len(p), bool)
    planted[which] = True
    off = planted & (np.abs(radial_error(p)) > 0.01)   # off the surface by 1 cm or more (near the
    assert off.sum() >= 0.6 * planted.sum()             # silhouettes a shift along the ray is not)
    assert (out & off).sum() >= 0.9 * off.sum()
    assert (out & ~planted).sum() <= 0.001 * len(p)
    assert 0.0005 < scale < 0.002    # about the noise's sigma: the outliers do not inflate it


def two_head_surface(overlap=0.3, n=30000, seed=0):
    """A smooth bumpy closed surface measured by two heads whose fields overlap in a band
    (``|y| < overlap`` of the unit direction), like the upper and lower heads of a tower.

    Returns points (n', 3), head (n',), centre (3,).
    """
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    r = 0.3 * (1 + 0.1 * np.sin(5 * u[:, 0]) * np.cos(4 * u[:, 2]) + 0.05 * np.sin(7 * u[:, 1]))
    p = u * r[:, None] * [1.0, 0.6, 2.5]
    a, b = u[:, 1] < overlap, u[:, 1] > -overlap
    points = np.concatenate([p[a], p[b]])
    head = np.concatenate([np.zeros(a.sum(), int), np.ones(b.sum(), int)])
    return points, head, (points.min(axis=0) + points.max(axis=0)) / 2


def test_planted_misregistration_between_heads_is_recovered():
    p, head, c = two_head_surface()
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    rot, shift = rotvec(np.radians(0.5) * axis), np.array([0.0015, -0.001, 0.0008])
    q = p.copy()
    q[head == 1] = (p[head == 1] - c) @ rot.T + c + shift      # 0.5 degrees and 2 mm
    reg = register_heads(q, head, spacing=0.004)
    angle, mm = reg.offset(0, 1)
    assert abs(angle - 0.5) < 0.1 and abs(mm - 1000 * np.linalg.norm(shift)) < 0.5
    fixed, _ = reg.apply(q, head)
    # what is left between the heads: head 1's points against where head 0's frame puts them
    r1 = reg.rotation[0].T @ reg.rotation[1] @ rot
    assert np.degrees(np.linalg.norm(_log_rotation(r1))) < 0.1
    back = (fixed[head == 1] - c - reg.translation[0]) @ reg.rotation[0] + c   # in head 0's frame
    assert np.sqrt(np.mean(np.sum((back - p[head == 1]) ** 2, axis=1))) < 0.0005


def ring_of_heads(n_heads=6, half_field=50.0, n=8000, seed=0):
    """The bumpy surface of `two_head_surface` measured by ``n_heads`` heads around the vertical
    axis, each sampling its own points on the side it faces (within ``half_field`` degrees of its
    azimuth), so that each overlaps only its two neighbours, like the towers of a whole-body scanner.

    Returns points (n', 3), head (n',), centre (3,).
    """
    rng = np.random.default_rng(seed)
    parts, heads = [], []
    for h in range(n_heads):
        u = rng.normal(size=(8 * n, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        az = 2 * np.pi * h / n_heads
        facing = u[:, 0] * np.cos(az) + u[:, 1] * np.sin(az)
        u = u[facing > np.cos(np.radians(half_field)) * np.hypot(u[:, 0], u[:, 1])][:n]
        r = 0.3 * (1 + 0.1 * np.sin(5 * u[:, 0]) * np.cos(4 * u[:, 2]) + 0.05 * np.sin(7 * u[:, 1]))
        parts.append(u * r[:, None] * [1.0, 0.6, 2.5])
        heads.append(np.full(len(u), h))
    points, head = np.concatenate(parts), np.concatenate(heads)
    return points, head, (points.min(axis=0) + points.max(axis=0)) / 2


def test_a_ring_of_heads_is_registered_as_one_piece():
    # six heads, each misplaced by 0.5 degrees and 2 mm and overlapping its neighbours over 20
    # degrees of azimuth: the corrections must agree around the ring (head by head, each
    # registered to the others in turn, left 0.8 degrees between some)
    p, head, c = ring_of_heads()
    rng = np.random.default_rng(3)
    q = p.copy()
    motions = []
    for h in range(6):
        axis = rng.normal(size=3)
        rot = rotvec(np.radians(0.5) * axis / np.linalg.norm(axis))
        shift = rng.normal(size=3)
        shift *= 0.002 / np.linalg.norm(shift)
        q[head == h] = (p[head == h] - c) @ rot.T + c + shift
        motions.append((rot, shift))
    reg = register_heads(q, head, spacing=0.006)
    assert (reg.observable == 6).all()
    for a in range(6):
        for b in range(a + 1, 6):
            # what is left between heads a and b: each head's planted motion, then its correction
            ra, rb = reg.rotation[a] @ motions[a][0], reg.rotation[b] @ motions[b][0]
            assert np.degrees(np.linalg.norm(_log_rotation(ra.T @ rb))) < 0.1
            ta = reg.rotation[a] @ motions[a][1] + reg.translation[a]
            tb = reg.rotation[b] @ motions[b][1] + reg.translation[b]
            assert 1000 * np.linalg.norm(ta - tb) < 0.5


def test_heads_that_do_not_overlap_are_left_alone():
    # front and rear heads of a cylinder meet only at the silhouettes, seen edge on
    p, vd, head, true = scanned_cylinder(0.001)
    q = p.copy()
    q[head == 1] += [0.002, 0.0, 0.0]
    reg = register_heads(q, head, spacing=PITCH)
    assert reg.offset(0, 1) == (0.0, 0.0)
    assert (reg.pairs == 0).all()


def test_the_cloud_reader_keeps_the_heads_and_no_ground_truth(tmp_path):
    from bodyscan import simulator
    from bodyscan.recon import read_cloud

    rng = np.random.default_rng(0)
    n = 500
    scan = simulator.Scan(points=rng.uniform(0, 1, (n, 3)), head=np.repeat([0, 1], n // 2).astype(np.int16),
                          view_dir=np.tile(np.float32([0, -1, 0]), (n, 1)), gt_face=np.arange(n),
                          gt_section=np.zeros(n, np.int8), gt_normal=np.zeros((n, 3), np.float32))
    cloud = read_cloud(simulator.write_cloud(scan, tmp_path / "c.ply"))
    assert np.array_equal(cloud.head, scan.head)
    assert not any(k.startswith("gt_") for k in vars(cloud))


def test_opposite_heads_are_registered_by_their_silhouettes():
    # front and rear parallel views of a body-sized cylinder share its outline (the sides and the
    # ends): a rear head moved across the view and turned about it is brought back; along the view
    # it cannot be told from a thicker cylinder, and is left alone
    p, vd, head, true = scanned_cylinder(0.001, radius=0.15, height=1.6)
    c = (p.min(axis=0) + p.max(axis=0)) / 2
    rot, shift = rotvec(np.radians(0.5) * np.array([0.0, 1.0, 0.0])), np.array([0.0015, 0.002, -0.0012])
    q = p.copy()
    q[head == 1] = (p[head == 1] - c) @ rot.T + c + shift
    reg = register_silhouettes(q, head, vd, spacing=PITCH)
    r_rel = reg.rotation[0].T @ reg.rotation[1] @ rot        # what is left of the rotation
    assert np.degrees(np.linalg.norm(_log_rotation(r_rel))) < 0.1
    fixed, _ = reg.apply(q, head)
    back = (fixed[head == 1] - c - reg.translation[0]) @ reg.rotation[0] + c   # in head 0's frame
    left = (back - p[head == 1]).mean(axis=0)
    assert np.all(np.abs(left[[0, 2]]) < 0.0005)              # across the view: recovered
    assert abs(left[1] - shift[1]) < 0.0005                    # along the view: not invented
    assert reg.offset(0, 1)[0] > 0.4
    assert (reg.observable >= 3).all()   # x, z and the turn about y at least (never y: along the views)


def test_heads_sampled_out_of_phase_are_not_moved():
    # an ellipsoid's front and rear halves, the rear sampled on a grid half a cell off the
    # front's, with no offset between the heads: the outlines differ by the sampling alone
    a, b, c = 0.2, 0.15, 0.8
    parts = []
    for phase, side in ((0.0, -1.0), (0.5, 1.0)):
        g = np.arange(-1.0, 1.0, PITCH) + phase * PITCH
        X, Z = (v.ravel() for v in np.meshgrid(g, g))
        inside = (X / a) ** 2 + (Z / c) ** 2 < 1
        X, Z = X[inside], Z[inside]
        parts.append(np.column_stack([X, side * b * np.sqrt(1 - (X / a) ** 2 - (Z / c) ** 2), Z]))
    p = np.concatenate(parts)
    head = np.repeat([0, 1], [len(parts[0]), len(parts[1])])
    vd = np.where(head[:, None] == 0, [0.0, -1.0, 0.0], [0.0, 1.0, 0.0])
    angle, mm = register_silhouettes(p, head, vd, spacing=PITCH).offset(0, 1)
    assert angle < 0.05 and mm < 0.5


def test_silhouettes_need_heads_facing_each_other():
    p, vd, head, true = scanned_cylinder(0.001, radius=0.15, height=1.6)
    q = p.copy()
    q[head == 1] += [0.002, 0.0, 0.0]
    same = np.where(head[:, None] == 0, vd, -vd)                          # both heads on one side
    assert register_silhouettes(q, head, same, PITCH).offset() == (0.0, 0.0)
    side = np.where(head[:, None] == 0, vd, [1.0, 0.0, 0.0])              # at right angles
    assert register_silhouettes(q, head, side, PITCH).offset() == (0.0, 0.0)
    rays = vd + np.random.default_rng(0).normal(0, 0.05, vd.shape)        # perspective-like rays
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    angle, mm = register_silhouettes(q, head, rays, PITCH).offset()
    assert angle < 0.05 and abs(mm - 2.0) < 0.3                           # facing each other: moved back


def test_fit_size_follows_the_noise_within_the_radius():
    from bodyscan.recon.clean.denoise import fit_size

    assert fit_size(0.0, 0.002, 0.15, 40, 0.02) == 40            # noise-free: the neighbours
    assert fit_size(0.001, 0.005, 0.15, 40, 0.02) == 40          # coarse scan: its noise is small
    assert fit_size(0.001, 0.002, 0.15, 40, 0.02) == 67          # 6 (1 / 0.3)^2, rounded up
    assert fit_size(0.002, 0.002, 0.15, 40, 0.02) == 267
    assert fit_size(0.003, 0.002, 0.15, 40, 0.02) == 315         # pi (20 / 2)^2: the radius bounds it
    assert fit_size(0.002, 0.002, 0.0, 40, 0.02) == 40           # off


def test_fine_noisy_scan_gets_wider_fits():
    # 2 mm pitch, 2 mm noise: 40 points span about 7 mm and leave about 0.8 mm of noise; fits
    # widened to the measured noise come nearer the true cylinder
    sigma, pitch = 0.002, 0.002
    p, vd, head, true = scanned_cylinder(sigma, pitch=pitch, height=0.2)
    inner = (true[:, 2] > 0.03) & (true[:, 2] < 0.17)
    member = np.ones((len(p), 1), bool)
    rms = [np.sqrt(np.mean(radial_error(denoise(p, member, pitch, error=e).points[inner]) ** 2))
           for e in (0.0, 0.15)]
    assert rms[1] < 0.8 * rms[0]
    assert rms[1] < 0.3 * sigma


def test_widened_fits_stay_within_their_reach():
    # a wrist-thin cylinder (15 mm radius), 2 mm pitch and noise: fits widened to the noise
    # would reach 20 mm and flatten its curvature; held within 12 mm they come nearer the truth
    sigma, pitch, radius = 0.002, 0.002, 0.015
    p, vd, head, true = scanned_cylinder(sigma, pitch=pitch, radius=radius, height=0.2)
    inner = (true[:, 2] > 0.03) & (true[:, 2] < 0.17)
    member = np.ones((len(p), 1), bool)
    rms = [np.sqrt(np.mean(radial_error(denoise(p, member, pitch, error=0.15, reach=r).points[inner], radius) ** 2))
           for r in (0.02, 0.012)]
    assert rms[1] < 0.9 * rms[0]
    assert rms[1] < 0.3 * sigma


def test_isolated_points_are_those_with_no_other_point_within_the_gap():
    # a 1 mm grid line with one point 2.5 mm past its end and a duplicated point: the bounded
    # search finds what the unbounded one does, at the gap itself and at gap 0
    from scipy.spatial import cKDTree

    from bodyscan.recon.clean.denoise import _isolated

    x = np.concatenate([np.arange(5) * 0.001, [0.0065, 0.002]])
    pts = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    tree = cKDTree(pts)
    assert _isolated(tree, pts, 0.0015).tolist() == [False] * 5 + [True, False]
    assert _isolated(tree, pts, 0.003).tolist() == [False] * 7
    assert _isolated(tree, pts, 0.0).tolist() == [True, True, False, True, True, True, False]
    nearest = tree.query(pts, k=2)[0][:, 1]
    for gap in np.unique(nearest):  # a gap equal to a nearest distance: that point is not isolated
        assert (_isolated(tree, pts, gap) == (nearest > gap)).all()


def test_shared_fits_are_evaluated_the_same_in_chunks(monkeypatch):
    # `LocalFit.at` a few points at a time (chunk boundaries inside the cloud) and all at once
    from bodyscan.recon.clean import denoise as D

    p = scanned_cylinder(0.001)[0]
    member = np.ones((len(p), 1), bool)
    whole = denoise(p, member, PITCH, share=2.0)
    monkeypatch.setattr(D, "AT_CHUNK", 37)
    chunked = denoise(p, member, PITCH, share=2.0)
    assert np.array_equal(whole.points, chunked.points) and whole.scale == chunked.scale


@pytest.mark.parametrize("name", ["standing", "squat"])
def test_a_body_scanned_by_four_towers_is_registered_against_its_planted_misalignment(name):
    """The simulator's eight tower heads, each misplaced by 0.5 degrees and 2 mm, over a library
    body at 10 mm with 1 mm of range noise: the correction leaves under 0.1 degrees and 0.5 mm
    between any two heads (at the body's centre), scored against the truth the scan records."""
    from bodyscan import simulator
    from bodyscan.benchmarks.bench import registration_error, scan_columns
    from bodyscan.poses import load_body
    from bodyscan.recon.params import ReconParams
    from bodyscan.recon.pipeline import prepare

    cfg = simulator.preset("paper", resolution=0.01, noise_sigma=0.001, misalign_deg=0.5, misalign_mm=2.0,
                           heads="four_towers")
    scan = simulator.scan(load_body(name), cfg, seed=0)
    planted = scan_columns(scan)
    assert planted["misregistration_deg"] > 0.5 and planted["misregistration_mm"] > 2.0
    reg = prepare(scan.points, ReconParams.from_overrides({"register_heads": True}), view_dir=scan.view_dir,
                  head=scan.head.astype(np.int64)).registration
    assert (reg.observable == 6).all()
    left = registration_error(scan, reg)
    assert left["registration_error_deg"] < 0.1 and left["registration_error_mm"] < 0.5


def test_a_second_projection_takes_out_more_noise():
    # the scanner preset's case, 2 mm pitch and 1 mm noise: the surfaces fitted again to the moved
    # points come nearer the true cylinder; a noise-free one (fits not widened) is projected once
    pitch = 0.002
    for sigma in (0.001, 0.0):
        p, vd, head, true = scanned_cylinder(sigma, pitch=pitch, height=0.2)
        inner = (true[:, 2] > 0.03) & (true[:, 2] < 0.17)
        member = np.ones((len(p), 1), bool)
        one, two = (denoise(p, member, pitch, error=0.15, passes=k) for k in (1, 2))
        rms = [np.sqrt(np.mean(radial_error(d.points[inner]) ** 2)) for d in (one, two)]
        if sigma:
            assert rms[1] < 0.93 * rms[0] and rms[1] < 0.25 * sigma
            assert one.widened and two.scale == one.scale and (two.rejected == one.rejected).all()
        else:
            assert not one.widened and (two.points == one.points).all()   # projected once
        assert np.allclose(two.moved, np.linalg.norm(two.points - p, axis=1))
    with pytest.raises(ValueError, match="passes"):
        denoise(p, member, pitch, passes=0)
