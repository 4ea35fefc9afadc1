"""Real scanner conditions: denoising, outlier rejection and head registration on analytic surfaces."""

import numpy as np

from bodyscan.recon.denoise import denoise, reject_outliers

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


def test_denoised_cylinder_lies_within_0_3_sigma_of_the_true_surface():
    sigma = 0.001
    before, after = [], []
    for seed in range(3):   # the RMS over three noise draws
        p, vd, head, true = scanned_cylinder(sigma, seed=seed)
        inner = (true[:, 2] > 0.03) & (true[:, 2] < 0.37)   # the open ends have one-sided fits
        d = denoise(p, np.ones((len(p), 1), bool), PITCH)
        before.append(radial_error(p[inner]))
        after.append(radial_error(d.points[inner]))
        assert 0.3 * sigma < d.scale < 1.5 * sigma      # the scale comes from the data
        assert np.allclose(d.moved, np.linalg.norm(d.points - p, axis=1))
        assert d.moved.max() <= 3.0 * d.scale + 1e-12   # clamped
        assert not d.rejected.any()
    assert np.sqrt(np.mean(np.concatenate(before) ** 2)) > 0.5 * sigma   # the noise was there
    assert np.sqrt(np.mean(np.concatenate(after) ** 2)) < 0.3 * sigma


def test_noise_free_cylinder_is_not_moved():
    p, vd, head, true = scanned_cylinder(0.0)
    d = denoise(p, np.ones((len(p), 1), bool), PITCH)
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
    assert scale < 0.002    # the outliers do not inflate the noise scale
