"""Volume data from a point cloud (paper section 2.2): contour voxels hold points, inside voxels are enclosed.

After Matsuoka et al. as the paper uses it: the voxel size comes from the point density of the
sparsest part of the cloud (the `density_quantile` quantile of the distance from a point to its
`density_k`-th nearest neighbour, times a factor), clamped to [`voxel_min`, `voxel_max`] so that gaps such as the one
between arm and chest stay open. Contour voxels are the voxels holding points; inside voxels are the
empty voxels enclosed by contour voxels. Where the cameras' views of the cloud are known (its
points' view directions), enclosed means what no camera looked
through: behind the surface every camera saw (`recon.views.Views.behind`), the volume between the
front and rear range images. A body turned in the scanner shows its trunk's sides only, its
front and back lying along the lines of sight: no closing encloses gaps that wide, but the space
behind both sides is known. Without such views, the inside voxels are the empty voxels that a 3-D
hole fill finds after a one-voxel morphological closing (which bridges small holes of the scan),
plus those that have contour voxels within `reach` in all four in-plane directions of at least two
of the three axis planes through them (a torso whose sides are missing from a front/back scan is
still enclosed that way). The volume may be
incomplete: it only guides the match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Volume:
    """Voxelized cloud.

    Attributes
    ----------
    origin : (3,) float
        Centre of voxel (0, 0, 0), metres.
    size : float
        Voxel edge, metres.
    contour : (nx, ny, nz) bool
        Voxels holding points.
    inside : (nx, ny, nz) bool
        Voxels enclosed by contour voxels (not contour themselves).
    """

    origin: np.ndarray
    size: float
    contour: np.ndarray
    inside: np.ndarray

    @property
    def shape(self) -> tuple:
        return self.contour.shape

    def index(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) fractional voxel indices of ``points`` (n, 3) metres."""
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.size

    def centres(self, mask: np.ndarray) -> np.ndarray:
        """(m, 3) centres of the voxels where ``mask`` is True, metres."""
        return np.argwhere(mask) * self.size + self.origin

    def weights(self, contour_weight: float, empty_weight: float) -> np.ndarray:
        """(nx, ny, nz) float32 matching weights: ``contour_weight`` on contour voxels, 1 inside,
        ``empty_weight`` elsewhere (paper section 2.3: contour voxels weigh n)."""
        w = np.full(self.shape, empty_weight, dtype=np.float32)
        w[self.inside] = 1.0
        w[self.contour] = contour_weight
        return w


def voxel_size(points: np.ndarray, voxel_min: float, voxel_max: float, *, k: int = 6,
               quantile: float = 0.95, factor: float = 1.5, max_samples: int = 20000,
               seed: int = 0) -> float:
    """Voxel edge from the density of the sparsest part of the cloud, clamped, metres.

    Parameters
    ----------
    points : (n, 3) float, metres
    voxel_min, voxel_max : float
        Limits, metres.
    k : int
        The density is measured by the distance to the k-th nearest neighbour.
    quantile : float
        Which quantile of those distances is "the sparsest part" (the largest ones are outliers).
    factor : float
        Voxel edge = ``factor`` times that distance (so that contours close over the sparsest part).
    max_samples : int
        Points sampled (with ``seed``) to measure the density.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(seed)
    sample = points if len(points) <= max_samples else points[rng.choice(len(points), max_samples, replace=False)]
    # density of the sample measured against the full cloud
    d, _ = cKDTree(points).query(sample, k=k + 1)
    spacing = factor * float(np.quantile(d[:, -1], quantile))
    return float(np.clip(spacing, voxel_min, voxel_max))


def voxelize(points: np.ndarray, size: float, *, reach: float = 0.4, min_planes: int = 1, pad: int = 3,
             offset: float = 0.0, behind=None) -> Volume:
    """Contour and inside voxels of ``points`` (n, 3) metres at edge ``size`` metres.

    Parameters
    ----------
    points : (n, 3) float, metres
    size : float
        Voxel edge, metres.
    reach : float
        Metres: how far to look for enclosing contour voxels in the in-plane test.
    pad : int
        Empty voxels around the cloud's bounding box.
    offset : float
        The lattice shifted by this fraction of a voxel along every axis (the same points, another
        discretization: `recon.posture.fit.estimate_posture`'s ``fit_regrid``).
    behind : callable, optional
        ``behind(at (m, 3)) -> (m,) bool``: whether positions lie behind the surface every camera
        saw (`recon.views.Views.behind`). Given, the inside voxels are those (the volume between
        the views) and ``reach`` is not used.
    """
    from scipy import ndimage

    points = np.asarray(points, dtype=np.float64)
    lo = points.min(axis=0) - (pad + offset) * size
    shape = tuple(int(s) for s in np.floor((points.max(axis=0) - lo) / size) + pad + 1)
    require_voxels(shape, size)
    idx = np.floor((points - lo) / size).astype(np.int64)
    contour = np.zeros(shape, dtype=bool)
    contour[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    if behind is not None:
        # what no camera looked through: behind the surface every camera saw
        filled = np.zeros(int(np.prod(shape)), dtype=bool)
        for a in range(0, filled.size, CHUNK):
            at = np.column_stack(np.unravel_index(np.arange(a, min(a + CHUNK, filled.size)), shape))
            filled[a:a + CHUNK] = behind(at * size + lo + 0.5 * size)
        filled = filled.reshape(shape)
    else:
        closed = ndimage.binary_closing(contour, structure=np.ones((3, 3, 3), bool), border_value=0)
        filled = ndimage.binary_fill_holes(closed)
        # where the shell has gaps (sides seen at grazing angles): a voxel is also inside when, in at
        # least two of the three axis planes through it, contour voxels lie within `reach` in all four
        # in-plane directions
        steps = max(1, int(round(reach / size)))
        blocked = [_blocked_both_ways(closed, ax, steps) for ax in range(3)]
        planes = (blocked[0] & blocked[1]).astype(np.int8) + (blocked[0] & blocked[2]) + (blocked[1] & blocked[2])
        filled |= planes >= min_planes
    inside = filled & ~contour
    return Volume(origin=lo + 0.5 * size, size=float(size), contour=contour, inside=inside)


#: Voxels whose centres `voxelize` hands to ``behind`` at once (bounds its memory).
CHUNK = 1 << 18

#: Peak bytes per voxel of `voxelize` and the volume match that follows (the inside test's
#: int64 running maxima and minima along each axis dominate; measured, see `require_voxels`).
BYTES_PER_VOXEL = 80


def require_voxels(shape, size: float) -> None:
    """Refuse (`ReconError`, one line) a voxel grid of ``shape`` that cannot fit in memory."""
    from bodyscan._resources import require_memory

    from .. import ReconError

    n = float(np.prod(np.asarray(shape, dtype=np.float64)))
    require_memory(n * BYTES_PER_VOXEL, f"a voxel grid of {' x '.join(map(str, shape))} voxels of "
                   f"{1000 * size:g} mm", "raise voxel_min/voxel_max (--param voxel_min=0.01)",
                   error=ReconError)


def _blocked_both_ways(mask: np.ndarray, axis: int, steps: int) -> np.ndarray:
    """True where ``mask`` has a True voxel within ``steps`` voxels on both sides along ``axis``."""
    n = mask.shape[axis]
    shape = [1, 1, 1]
    shape[axis] = n
    pos = np.arange(n).reshape(shape)
    big = np.int32(1 << 30)
    before = np.where(mask, pos, -big)
    before = np.maximum.accumulate(before, axis=axis)
    after = np.where(mask, pos, big)
    after = np.flip(np.minimum.accumulate(np.flip(after, axis=axis), axis=axis), axis=axis)
    return (pos - before <= steps) & (after - pos <= steps)
