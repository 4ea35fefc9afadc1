"""Scan a posed body like a slit-laser range finder: a point counts only if seen AND lit (paper 4.1).

For each head, a camera ray leaves every pixel (a grid at ``resolution`` spacing on the plane
through the scanner axis) and hits the first surface of the whole posed mesh; that hit is measured
only if a ray from it toward the laser escapes the mesh (cast from the point, offset a hair along
the face normal, up to the laser source for ``perspective``). The laser must light the side of the
surface that the camera sees. Then, all seeded: range noise and outliers along the camera ray, and a
rigid misalignment of each head's points.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import ScanError
from .config import Head, ScannerConfig, preset
from .raycast import RayCaster

#: Offset of laser-ray origins along the face normal, as a fraction of the mesh's bounding-box
#: diagonal (40 micrometres for a person): well above float32 hit error, far below any feature.
RAY_OFFSET = 2e-5

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
        ``points_per_head``, ``scanner_center`` (3,), ``rays``, ``seconds``.
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
    """Camera rays of one head that hit the mesh (cached across laser angles)."""

    points: np.ndarray      # (m, 3) float64 hit points
    directions: np.ndarray  # (m, 3) or (1, 3) float64 unit camera-ray directions
    face: np.ndarray        # (m,) int64
    n_rays: int             # camera rays cast


def _as_body(body):
    from poses import Body, validate

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
        rel = self.body.vertices - o_img
        if perspective:
            cam = o_img - dist * axis
            rel = self.body.vertices - cam
            depth = rel @ axis
            if depth.min() < 0.05 * dist:
                raise ScanError(f"the body reaches the camera of head {head.name!r} "
                                f"({dist:g} m from the scanner axis): increase camera_distance")
            pu, pv = dist * (rel @ right) / depth, dist * (rel @ up) / depth
        else:
            pu, pv = rel @ right, rel @ up
        in_field = (np.abs(pu) <= head.field_width / 2) & (np.abs(pv) <= head.field_height / 2)
        nw = max(1, int(math.floor(head.field_width / res + 1e-9)))
        nh = max(1, int(math.floor(head.field_height / res + 1e-9)))
        i = np.arange(max(0, math.ceil(pu.min() / res + nw / 2 - 0.5)),
                      min(nw - 1, math.floor(pu.max() / res + nw / 2 - 0.5)) + 1)
        j = np.arange(min(nh - 1, math.floor(pv.max() / res + nh / 2 - 0.5)),
                      max(0, math.ceil(pv.min() / res + nh / 2 - 0.5)) - 1, -1)   # top row first
        u = (i + 0.5 - nw / 2) * res
        w = (j + 0.5 - nh / 2) * res
        uu, ww = np.meshgrid(u, w)
        uu, ww = uu.ravel(), ww.ravel()
        if perspective:
            d = uu[:, None] * right + ww[:, None] * up + dist * axis
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            d32 = d.astype(np.float32)
            o32 = np.broadcast_to(cam.astype(np.float32), d32.shape)
        else:
            start = float((rel @ axis).min()) - 0.01 * max(1.0, float(np.ptp(rel @ axis)))
            o = o_img + start * axis + uu[:, None] * right + ww[:, None] * up
            o32 = o.astype(np.float32)
            d32 = axis.astype(np.float32)[None, :]
        face, t = self.caster.first_hit(o32, d32)
        hit = face >= 0
        o = o32[hit].astype(np.float64)
        d = (d32[hit] if perspective else d32).astype(np.float64)
        points = o + t[hit, None].astype(np.float64) * d
        rays = _HeadRays(points, d, face[hit], len(face))
        self._camera_cache[key] = (rays, in_field)
        return rays, in_field

    # -- laser -------------------------------------------------------------------------------
    def _lit(self, rays: _HeadRays, head: Head, config: ScannerConfig, center: np.ndarray):
        """Mask (m,) of camera hits that the head's laser reaches, and the normals toward the camera."""
        o_img, axis, up, right = head_frame(head, center)
        theta, roll = math.radians(config.laser_angle_deg), math.radians(head.laser_roll_deg)
        side = math.cos(roll) * up + math.sin(roll) * right
        n = self.face_normals[rays.face]
        cos_cam = -np.einsum("ij,ij->i", n, np.broadcast_to(rays.directions, n.shape))
        flip = np.where(cos_cam < 0, -1.0, 1.0)
        n_seen = n * flip[:, None]                      # normal of the side the camera sees
        if config.projection == "perspective":
            source = o_img - config.camera_distance * axis + config.baseline * side
            to_laser = source - rays.points
            reach = np.linalg.norm(to_laser, axis=1)
            to_laser /= reach[:, None]
            cos_laser = np.einsum("ij,ij->i", n_seen, to_laser)
        else:
            to_laser = -math.cos(theta) * axis + math.sin(theta) * side
            reach = None
            cos_laser = n_seen @ to_laser
            to_laser = to_laser[None, :]
        c_min = max(0.0, math.cos(math.radians(config.max_incidence_deg)))
        candidate = (cos_laser > c_min) & (np.abs(cos_cam) > c_min)
        idx = np.flatnonzero(candidate)
        origins = rays.points[idx] + self.ray_offset * n_seen[idx]
        dirs = to_laser[idx] if reach is not None else to_laser
        blocked = self.caster.occluded(origins, dirs, None if reach is None else reach[idx])
        lit = np.zeros(len(candidate), bool)
        lit[idx[~blocked]] = True
        return lit

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
        t0 = time.perf_counter()
        config = preset("paper") if config is None else config
        if not isinstance(config, ScannerConfig):
            raise ScanError(f"config must be a ScannerConfig, got {type(config).__name__}")
        if seed is not None:
            config = config.replace(seed=int(seed))
        rays0 = self.caster.n_rays
        center = self._center(config)
        parts, camera_rays = [], 0
        covered = np.zeros(len(self.body.vertices), bool)
        for h, head in enumerate(config.heads):
            rays, in_field = self._camera(head, config, center)
            camera_rays += rays.n_rays
            covered |= in_field
            lit = self._lit(rays, head, config, center)
            parts.append(self._measure(h, head, rays, lit, config, center))
        where = self.body.source or self.body.name
        if camera_rays == 0 or not covered.any():
            raise ScanError(f"{where}: the body lies outside the field of every head; "
                            "put it at the origin, standing on z = 0 (or set center_on_body)")
        if not covered.all():
            out = self.body.vertices[~covered]
            lo, hi = out.min(axis=0), out.max(axis=0)
            warnings.warn(f"{where}: {100 * (~covered).mean():.1f} % of the body's vertices (x {lo[0]:.2f}.."
                          f"{hi[0]:.2f}, z {lo[2]:.2f}..{hi[2]:.2f} m) lie outside every head's field and are "
                          "not measured: enlarge field_width/field_height or use another head layout",
                          ScanWarning, stacklevel=2)
        counts = [len(p[0]) for p in parts]
        if sum(counts) == 0:
            raise ScanError(f"{where}: no surface point is both seen by a camera and lit by its laser; "
                            "check the heads and the laser angle")
        cat = [np.concatenate(a) for a in zip(*parts)]
        meta = {
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
            "seconds": round(time.perf_counter() - t0, 4),
        }
        return Scan(*cat, meta=meta)

    def _measure(self, h, head, rays, lit, config, center):
        """Arrays of head ``h``'s measured points, with noise, outliers and misalignment."""
        idx = np.flatnonzero(lit)
        m = len(idx)
        ray_dir = rays.directions[idx] if len(rays.directions) > 1 else np.broadcast_to(rays.directions, (m, 3))
        points = rays.points[idx]
        face = rays.face[idx]
        view = -ray_dir
        rng = np.random.default_rng([config.seed, h])
        if config.noise_sigma > 0:
            points = points + rng.normal(0.0, config.noise_sigma, m)[:, None] * ray_dir
        n_out = int(round(config.outlier_fraction * m))
        if n_out and config.outlier_spread > 0:
            which = np.sort(rng.choice(m, n_out, replace=False))
            points = points.copy()
            points[which] += rng.uniform(-config.outlier_spread, config.outlier_spread, n_out)[:, None] * ray_dir[which]
        if config.misalign_deg > 0 or config.misalign_mm > 0:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            shift = rng.normal(size=3)
            shift *= config.misalign_mm / 1000.0 / np.linalg.norm(shift)
            rot = _rotation(axis, math.radians(config.misalign_deg))
            points = (points - center) @ rot.T + center + shift
            view = view @ rot.T
        return (points, np.full(m, h, np.int16), np.ascontiguousarray(view, dtype=np.float32), face,
                self.face_section[face], self.face_normals[face].astype(np.float32))


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


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("bodyscan")
    except Exception:  # not installed: running from a checkout
        return "unknown"
