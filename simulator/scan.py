"""Scan a posed body like a slit-laser range finder: a point counts only if seen AND lit (paper 4.1).

For each head, a camera ray leaves every pixel (a grid at ``resolution`` spacing on the plane
through the scanner axis) and hits the first surface of the whole posed mesh; that hit is measured
only if a ray from it toward the laser escapes the mesh (cast from the point, offset a hair along
the face normal, up to the laser source for ``perspective``). The laser must light the side of the
surface that the camera sees. Then, all seeded: range noise and outliers along the camera ray, and a
rigid misalignment of each head's points.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from bodyscan._resources import require_memory

from . import ScanError
from .config import Head, ScannerConfig, preset
from .raycast import RayCaster

#: Offset of laser-ray origins along the face normal, as a fraction of the mesh's bounding-box
#: diagonal (40 micrometres for a person): well above float32 hit error, far below any feature.
RAY_OFFSET = 2e-5

#: Camera-ray results a `Scanner` keeps (one per head geometry and resolution), oldest dropped first.
CAMERA_CACHE_SIZE = 16
#: Memory model of a scan (`Scanner.memory_estimate`), bytes: per camera ray of the largest head
#: (origins, Embree's output, the hit selection), per hit kept (the head's rays, then the cloud and
#: its PLY record), and the fraction of a head's bounding-box rays that hit the body (measured on
#: the library: 0.35-0.5).
BYTES_PER_RAY = 60
BYTES_PER_HIT = 220
HIT_FRACTION = 0.6

#: Coordinates larger than this (metres) mean the mesh is not in metres.
MAX_EXTENT_M = 3.0


class ScanWarning(UserWarning):
    """A scan that works but loses data the user may not expect (body partly outside a field)."""


@dataclass(eq=False)
class Scan:
    """A simulated point cloud with per-point sensor data and ground truth.

    Attributes
    ----------
    points : (n, 3) float64
        Measured points, metres (with noise, outliers and misalignment when configured).
    head : (n,) int16
        Index of the head (camera + laser) that measured each point, into ``meta['heads']``.
    view_dir : (n, 3) float32
        Unit vector from the point toward its camera (``parallel``: minus the optical axis;
        ``perspective``: toward the pinhole), misaligned together with the point.
    gt_face : (n,) int64
        Ground truth: index of the triangle of ``body.faces`` the camera ray hit.
    gt_section : (n,) int8
        Ground truth: body section of that face (`poses.SECTIONS`), -1 when the body has none.
    gt_normal : (n, 3) float32
        Ground truth: outward unit normal of that face (never misaligned).
    meta : dict
        ``config`` (dict), ``seed``, ``body``, ``source``, ``version``, ``heads`` (names),
        ``points_per_head``, ``scanner_center`` (3,), ``rays`` (rays cast for this scan; fewer when
        a `Scanner` reuses camera rays); with a misalignment, the ground truth of each head's:
        ``misalign_rotation`` (h, 3, 3) and ``misalign_translation`` (h, 3), metres (a point ``p``
        measured as ``R (p - scanner_center) + scanner_center + t``); when the body reaches beyond
        every head's field (a `ScanWarning` too), ``outside_field``: the fraction of its vertices
        there (cut from the scan: raised hands above a tall body). Nothing time-dependent: same
        inputs, same file.
    """

    points: np.ndarray
    head: np.ndarray
    view_dir: np.ndarray
    gt_face: np.ndarray
    gt_section: np.ndarray
    gt_normal: np.ndarray
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def config(self) -> ScannerConfig:
        """The configuration that produced this scan (from ``meta``)."""
        return ScannerConfig.from_dict(self.meta["config"])


@dataclass
class _HeadRays:
    """Camera rays of one head that hit the mesh, and what the laser test needs of them.

    Cached by `Scanner` across laser angles and imperfections.
    """

    points: np.ndarray      # (m, 3) float64 hit points
    directions: np.ndarray  # (m, 3) or (1, 3) float32 unit camera-ray directions
    face: np.ndarray        # (m,) int64
    normal: np.ndarray      # (m, 3) float32 unit normal of the side the camera sees
    cos_camera: np.ndarray  # (m,) float32 cosine between that normal and the ray back to the camera
    starts: np.ndarray      # (m, 3) float32 laser-ray origins: points + RAY_OFFSET along `normal`
    normal_dot_start: np.ndarray  # (m,) float32, for the perspective laser's facing test


def _as_body(body):
    from bodyscan.poses import Body, validate

    if not isinstance(body, Body):
        import trimesh
        if not isinstance(body, trimesh.Trimesh):
            raise ScanError(f"cannot scan a {type(body).__name__}: give a poses.Body or a trimesh.Trimesh")
        body = Body(name=str(body.metadata.get("name", "mesh")), vertices=np.asarray(body.vertices, np.float64),
                    faces=np.asarray(body.faces, np.int64), source="trimesh.Trimesh")
    validate(body, check_units=False)
    where = body.source or body.name
    extent = float(np.ptp(body.vertices, axis=0).max())
    if extent > MAX_EXTENT_M:
        raise ScanError(f"{where}: the body is {extent:.4g} units across but must be in metres "
                        f"(a person is under {MAX_EXTENT_M:g} m); divide millimetres by 1000")
    return body


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about unit ``axis`` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def head_frame(head: Head, center: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where a head looks.

    Parameters
    ----------
    head : Head
    center : (2,) or (3,) float
        Scanner axis position (x, y), metres.

    Returns
    -------
    image_center : (3,) float
        Where the optical axis crosses the scanner axis, metres.
    axis, up, right : (3,) float
        Optical axis (camera toward body) and the image's up and right unit vectors.
    """
    az, tilt = math.radians(head.azimuth_deg), math.radians(head.tilt_deg)
    horizontal = np.array([-math.sin(az), math.cos(az), 0.0])   # from the camera toward the axis
    z = np.array([0.0, 0.0, 1.0])
    axis = math.cos(tilt) * horizontal + math.sin(tilt) * z
    up = -math.sin(tilt) * horizontal + math.cos(tilt) * z
    right = np.cross(axis, up)
    image_center = np.array([center[0], center[1], head.height], dtype=np.float64)
    return image_center, axis, up, right


class Scanner:
    """A body prepared for scanning: its Embree scene and face data, built once and reused.

    Scanning the same body with several configurations (laser angles, noise) through one
    `Scanner` builds the scene once and casts each head's camera rays once.

    Parameters
    ----------
    body : poses.Body or trimesh.Trimesh
        The posed mesh, metres.
    """

    def __init__(self, body):
        self.body = _as_body(body)
        v, f = self.body.vertices, self.body.faces
        self.caster = RayCaster(v, f)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.face_normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        self.face_normals32 = self.face_normals.astype(np.float32)
        self.face_section = (self.body.face_section() if self.body.has_ground_truth
                             else np.full(len(f), -1, np.int8))
        lo, hi = v.min(axis=0), v.max(axis=0)
        self.bounds = np.array([lo, hi])
        self.ray_offset = RAY_OFFSET * float(np.linalg.norm(hi - lo))
        self._camera_cache: dict = {}

    # -- camera ------------------------------------------------------------------------------
    def _center(self, config: ScannerConfig) -> np.ndarray:
        lo, hi = self.bounds
        xy = (lo[:2] + hi[:2]) / 2 if config.center_on_body else np.zeros(2)
        return np.array([xy[0], xy[1], (lo[2] + hi[2]) / 2])

    def _camera(self, head: Head, config: ScannerConfig, center: np.ndarray) -> tuple[_HeadRays, np.ndarray]:
        """Cast (or fetch) the camera rays of ``head``; also return which vertices (V,) are in its field."""
        perspective = config.projection == "perspective"
        key = (config.projection, config.resolution, config.camera_distance if perspective else None,
               head.azimuth_deg, head.height, head.tilt_deg, head.field_width, head.field_height,
               tuple(center[:2]))
        if key in self._camera_cache:
            return self._camera_cache[key]
        res, dist = config.resolution, config.camera_distance
        o_img, axis, up, right = head_frame(head, center)
        rel, cam, pu, pv, nw, nh, i, j = self._pixels(head, config, center)
        in_field = (np.abs(pu) <= head.field_width / 2) & (np.abs(pv) <= head.field_height / 2)
        # pixel grid, top row first, built in float32 with one (rows, cols, 3) allocation
        u = ((i + 0.5 - nw / 2) * res)[:, None] * right
        w = ((j + 0.5 - nh / 2) * res)[:, None] * up
        if perspective:
            # unnormalised: Embree's distances are then in these units; only hits get normalised
            d32 = ((w + dist * axis).astype(np.float32)[:, None] + u.astype(np.float32)).reshape(-1, 3)
            o32 = np.broadcast_to(cam.astype(np.float32), d32.shape)
        else:
            start = float((rel @ axis).min()) - 0.01 * max(1.0, float(np.ptp(rel @ axis)))
            o32 = ((o_img + start * axis + w).astype(np.float32)[:, None] + u.astype(np.float32)).reshape(-1, 3)
            d32 = axis.astype(np.float32)[None, :]
        face, t = self.caster.first_hit(o32, d32)
        # np.take is much faster than fancy indexing on (n, 3); mode="clip" skips its bounds-checked
        # (and, with out=, buffered) copy: every index here comes from Embree or flatnonzero
        hit = np.flatnonzero(face >= 0)
        face = np.take(face, hit, mode="clip").astype(np.int64)
        t = np.take(t, hit, mode="clip").astype(np.float64)[:, None]
        if perspective:
            d32 = np.take(d32, hit, axis=0, mode="clip")
            points = o32[0] + t * d32
            d32 /= np.sqrt(np.einsum("ij,ij->i", d32, d32))[:, None]
        else:
            points = np.take(o32, hit, axis=0, mode="clip") + t * d32
        normal = np.take(self.face_normals32, face, axis=0, mode="clip")
        cos_camera = -(np.einsum("ij,ij->i", normal, d32) if perspective else normal @ d32[0])
        flip = cos_camera < 0                   # the camera sees the back of the face (open meshes)
        np.negative(normal, out=normal, where=flip[:, None])
        cos_camera = np.abs(cos_camera)
        starts = (points + self.ray_offset * normal).astype(np.float32)
        rays = _HeadRays(points, d32, face, normal, cos_camera, starts, np.einsum("ij,ij->i", normal, starts))
        if len(self._camera_cache) >= CAMERA_CACHE_SIZE:
            self._camera_cache.pop(next(iter(self._camera_cache)))
        self._camera_cache[key] = (rays, in_field)
        return rays, in_field

    def _pixels(self, head: Head, config: ScannerConfig, center: np.ndarray):
        """The body's vertices in ``head``'s image (pu, pv, metres on the plane through the axis)
        and the pixel columns ``i`` and rows ``j`` (top first) covering its bounding box."""
        res, dist = config.resolution, config.camera_distance
        o_img, axis, up, right = head_frame(head, center)
        rel, cam = self.body.vertices - o_img, None
        if config.projection == "perspective":
            cam = o_img - dist * axis
            rel = self.body.vertices - cam
            depth = rel @ axis
            if depth.min() < 0.05 * dist:
                raise ScanError(f"the body reaches the camera of head {head.name!r} "
                                f"({dist:g} m from the scanner axis): increase camera_distance")
            pu, pv = dist * (rel @ right) / depth, dist * (rel @ up) / depth
        else:
            pu, pv = rel @ right, rel @ up
        nw = max(1, int(math.floor(head.field_width / res + 1e-9)))
        nh = max(1, int(math.floor(head.field_height / res + 1e-9)))
        i = np.arange(max(0, math.ceil(pu.min() / res + nw / 2 - 0.5)),
                      min(nw - 1, math.floor(pu.max() / res + nw / 2 - 0.5)) + 1)
        j = np.arange(min(nh - 1, math.floor(pv.max() / res + nh / 2 - 0.5)),
                      max(0, math.ceil(pv.min() / res + nh / 2 - 0.5)) - 1, -1)   # top row first
        return rel, cam, pu, pv, nw, nh, i, j

    def memory_estimate(self, config: ScannerConfig) -> tuple[int, int]:
        """(bytes, camera rays): the estimated peak memory of `scan` with ``config`` above the
        process's size before it, from the camera rays over the body's bounding box in each head."""
        center = self._center(config)
        rays = [self._pixels(h, config, center) for h in config.heads]
        counts = [max(0, len(r[6])) * max(0, len(r[7])) for r in rays]
        total = sum(counts)
        return int(BYTES_PER_RAY * max(counts, default=0) + BYTES_PER_HIT * HIT_FRACTION * total), total

    # -- laser -------------------------------------------------------------------------------
    def _lit(self, rays: _HeadRays, head: Head, config: ScannerConfig, center: np.ndarray) -> np.ndarray:
        """Indices into ``rays`` of the camera hits that the head's laser reaches."""
        o_img, axis, up, right = head_frame(head, center)
        theta, roll = math.radians(config.laser_angle_deg), math.radians(head.laser_roll_deg)
        side = math.cos(roll) * up + math.sin(roll) * right
        # 90 degrees (the default) means no limit; cos(pi/2) is 6e-17, not 0, so test it exactly
        c_min = 0.0 if config.max_incidence_deg >= 90 else math.cos(math.radians(config.max_incidence_deg))
        if config.projection == "perspective":
            # unnormalised rays from each point to the source: the source is at distance 1
            source = (o_img - config.camera_distance * axis + config.baseline * side).astype(np.float32)
            cos_laser = rays.normal @ source - rays.normal_dot_start     # n . (source - start)
            if c_min > 0:
                to_laser = source - rays.starts
                cos_laser /= np.sqrt(np.einsum("ij,ij->i", to_laser, to_laser))
        else:
            to_laser = (-math.cos(theta) * axis + math.sin(theta) * side).astype(np.float32)
            cos_laser = rays.normal @ to_laser
        candidate = cos_laser > c_min
        if c_min > 0:
            candidate &= rays.cos_camera > c_min
        idx = np.flatnonzero(candidate)
        starts = np.take(rays.starts, idx, axis=0, mode="clip")
        if config.projection == "perspective":
            blocked = self.caster.occluded(starts, source - starts, 1.0)
        else:
            blocked = self.caster.occluded(starts, to_laser[None, :])
        return idx[~blocked]

    # -- the scan ----------------------------------------------------------------------------
    def scan(self, config: ScannerConfig | None = None, *, seed: int | None = None) -> Scan:
        """Scan the body with ``config`` (default: the ``paper`` preset).

        Parameters
        ----------
        config : ScannerConfig, optional
        seed : int, optional
            Overrides ``config.seed``.

        Returns
        -------
        scan : Scan
            Points of all heads, head 0 first.

        Raises
        ------
        ScanError
            The body is outside every head's field, or no point is both visible and lit.

        Warns
        -----
        ScanWarning
            The body extends beyond some head's field (those parts are not measured).
        """
        config = preset("paper") if config is None else config
        if not isinstance(config, ScannerConfig):
            raise ScanError(f"config must be a ScannerConfig, got {type(config).__name__}")
        if seed is not None:
            config = config.replace(seed=int(seed))
        need, n_rays = self.memory_estimate(config)
        require_memory(need, f"{len(config.heads)} head(s) x {n_rays / max(1, len(config.heads)):,.0f} camera "
                       f"rays at {1000 * config.resolution:g} mm", "use a coarser resolution", error=ScanError)
        rays0 = self.caster.n_rays
        center = self._center(config)
        heads = []
        covered = np.zeros(len(self.body.vertices), bool)
        for head in config.heads:
            rays, in_field = self._camera(head, config, center)
            covered |= in_field
            heads.append((rays, self._lit(rays, head, config, center)))
        where = self.body.source or self.body.name
        if not covered.any():
            lo, hi = self.bounds
            z0 = min(h.height - h.field_height / 2 for h in config.heads)
            z1 = max(h.height + h.field_height / 2 for h in config.heads)
            raise ScanError(f"{where}: the body (z {lo[2]:.3g}..{hi[2]:.3g}) lies outside the field of every "
                            f"head (z {z0:.3g}..{z1:.3g} m): give it in metres, +z up, standing on z = 0")
        outside = float((~covered).mean())   # the share of the body no head sees (in the metadata)
        if outside:
            out = self.body.vertices[~covered]
            lo, hi = out.min(axis=0), out.max(axis=0)
            warnings.warn(f"{where}: {100 * outside:.1f} % of the body's vertices (x {lo[0]:.2f}.."
                          f"{hi[0]:.2f}, z {lo[2]:.2f}..{hi[2]:.2f} m) lie outside every head's field and are "
                          "not measured: enlarge field_width/field_height or use another head layout",
                          ScanWarning, stacklevel=2)
        counts = [len(idx) for _, idx in heads]
        n = sum(counts)
        if n == 0:
            raise ScanError(f"{where}: no surface point is both seen by a camera and lit by its laser; "
                            "check the heads and the laser angle")
        result = Scan(np.empty((n, 3)), np.empty(n, np.int16), np.empty((n, 3), np.float32),
                      np.empty(n, np.int64), np.empty(n, np.int8), np.empty((n, 3), np.float32))
        ends = np.cumsum(counts)
        planted = [self._measure(h, rays, idx, config, center, result, slice(end - len(idx), end))
                   for h, ((rays, idx), end) in enumerate(zip(heads, ends))]
        result.meta = {
            "format": 1,
            "version": _version(),
            "body": self.body.name,
            "source": self.body.source,
            "seed": config.seed,
            "config": config.to_dict(),
            "heads": [h.name for h in config.heads],
            "points_per_head": counts,
            "scanner_center": [float(c) for c in center],
            "rays": int(self.caster.n_rays - rays0),
        }
        if outside:
            result.meta["outside_field"] = outside
        if config.misalign_deg > 0 or config.misalign_mm > 0:
            result.meta["misalign_rotation"] = [r.tolist() for r, _ in planted]
            result.meta["misalign_translation"] = [t.tolist() for _, t in planted]
        return result

    def _measure(self, h, rays, idx, config, center, out, rows):
        """Write head ``h``'s measured points (camera hits ``idx``) into ``out[rows]``, with imperfections.
        Returns the head's planted misalignment ``(rotation (3, 3), translation (3,))``, the points
        moved as ``rotation @ (p - center) + center + translation`` (identity without one)."""
        m = len(idx)
        points = out.points[rows]
        np.take(rays.points, idx, axis=0, out=points, mode="clip")
        face = out.gt_face[rows]
        np.take(rays.face, idx, out=face, mode="clip")
        np.take(self.face_section, face, out=out.gt_section[rows], mode="clip")
        np.take(self.face_normals32, face, axis=0, out=out.gt_normal[rows], mode="clip")
        out.head[rows] = h
        view = out.view_dir[rows]
        if len(rays.directions) > 1:
            np.take(rays.directions, idx, axis=0, out=view, mode="clip")
            np.negative(view, out=view)
        else:
            view[:] = -rays.directions
        ray_dir = -view.astype(np.float64) if (config.noise_sigma > 0 or config.outlier_fraction > 0) else None
        rng = np.random.default_rng([config.seed, h])
        if config.noise_sigma > 0:
            points += rng.normal(0.0, config.noise_sigma, m)[:, None] * ray_dir
        n_out = int(round(config.outlier_fraction * m))
        if n_out and config.outlier_spread > 0:
            which = np.sort(rng.choice(m, n_out, replace=False))
            shift = rng.uniform(-config.outlier_spread, config.outlier_spread, n_out)[:, None]
            points[which] += shift * ray_dir[which]
        if config.misalign_deg > 0 or config.misalign_mm > 0:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            shift = rng.normal(size=3)
            shift *= config.misalign_mm / 1000.0 / np.linalg.norm(shift)
            rot = _rotation(axis, math.radians(config.misalign_deg))
            points[:] = (points - center) @ rot.T + center + shift
            view[:] = view @ rot.T.astype(np.float32)
            return rot, shift
        return np.eye(3), np.zeros(3)


def scan(body, config: ScannerConfig | None = None, *, seed: int | None = None) -> Scan:
    """Scan ``body`` like a slit-laser range finder (paper 4.1).

    Parameters
    ----------
    body : poses.Body, trimesh.Trimesh or Scanner
        The posed mesh, metres, +z up, facing -y. Pass a `Scanner` to reuse its Embree scene.
    config : ScannerConfig, optional
        Default: ``preset('paper')`` (parallel projection, k = 1, 10 mm, no noise, front and rear).
    seed : int, optional
        Overrides ``config.seed``.

    Returns
    -------
    scan : Scan
    """
    scanner = body if isinstance(body, Scanner) else Scanner(body)
    return scanner.scan(config, seed=seed)


@functools.lru_cache(maxsize=1)
def _version() -> str:
    try:
        from importlib.metadata import version
        return version("bodyscan")
    except Exception:  # not installed: running from a checkout
        return "unknown"
