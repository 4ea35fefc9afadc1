"""The whole reconstruction: posture estimation, clustering, per-section surfaces (`reconstruct`)."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import ReconError
from .model import SECTIONS, BodyFit
from .params import ReconParams

METHODS = ("proposed", "proposed-closed", "paper", "simple")

#: Fewer points than this cannot make a body surface.
MIN_POINTS = 100


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """A reconstructed body surface.

    Attributes
    ----------
    vertices : (n + n_new, 3) float
        The mesh vertices, metres: the input points by index (unused points are in no face),
        registered between heads and, for ``proposed`` with ``denoise``, moved onto their
        section's robust surface (or their far part's, for points in no section: `points` keeps
        the input, `moved` says how far); then the vertices the method made (``proposed``'s
        curved subdivision, ``curve_edge``; ``proposed-closed``'s closed surface), whose
        `point_index` is -1.
    faces : (m, 3) int
        Triangles, outward winding.
    face_section : (m,) int8
        Section of each face (index into `recon.model.SECTIONS`).
    point_sections : (n, 11) bool
        Final section memberships of each point (two at the joint seams, none for outliers).
    fit : BodyFit
    times : dict of str to float
        Seconds per stage: the fit's stages prefixed ``fit_``, then ``coords``, ``cluster``,
        ``surface``, ``curve`` (the curved subdivision), ``complete`` (``proposed-closed``) and
        ``total``.
    params : ReconParams
    method : str
    skipped : tuple of str
        Sections skipped for too few points.
    points_unmeshed : int
        Input points in no face of the open surface (left out: outliers, or points no chart took).
    points : (n, 3) float or None
        The input points, metres.
    moved : (n,) float or None
        How far each vertex lies from its input point (registration and denoising), metres.
    outliers : (n,) bool or None
        Points rejected as outliers (before the fit, and in the charts): in no section, no face.
    registration : recon.clean.register.Registration or None
        The correction applied to each head (``register_heads``).
    noise : float or None
        The cloud's measured range noise, metres (`Prepared.noise`). ``proposed`` denoises only a
        cloud whose noise is at least ``denoise_min_noise`` point spacings. None: not measured.
    point_faces : (m', 3) int or None
        The open surface as triangles over the input points alone, before the curved subdivision
        split its long ones (``proposed-closed`` closes these). Per-point data
        (`point_sections`, a scan's ground truth) apply to its vertices directly. None: `faces`.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_section: np.ndarray
    point_sections: np.ndarray
    fit: BodyFit
    times: dict = field(default_factory=dict)
    params: ReconParams | None = None
    method: str = "proposed"
    skipped: tuple = ()
    points_unmeshed: int = 0
    points: np.ndarray | None = None
    moved: np.ndarray | None = None
    outliers: np.ndarray | None = None
    registration: object = None
    point_faces: np.ndarray | None = None
    noise: float | None = None

    @property
    def point_index(self) -> np.ndarray:
        """(V,) int: input point of each mesh vertex, -1 for a vertex made by the method (the
        closed surface's)."""
        i = np.arange(len(self.vertices))
        return np.where(i < len(self.point_sections), i, -1)

    @property
    def point_section(self) -> np.ndarray:
        """(n,) int8: one section per point (the first of its sections), -1 for none."""
        out = self.point_sections.argmax(axis=1).astype(np.int8)
        out[~self.point_sections.any(axis=1)] = -1
        return out

    def to_trimesh(self):
        """The mesh as a `trimesh.Trimesh` (vertex order kept, unused points included)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    def write(self, path) -> Path:
        """Write the mesh as binary PLY with each vertex's input point and sections and a face
        property ``section``; see `write_mesh`."""
        return write_mesh(path, self.vertices, self.faces, self.face_section, self.point_sections,
                          self.point_index)


def write_mesh(path, vertices: np.ndarray, faces: np.ndarray, face_section: np.ndarray,
               point_sections: np.ndarray | None = None, point_index: np.ndarray | None = None) -> Path:
    """Write a binary little-endian PLY: vertex x, y, z (double, so that undenoised vertices are
    the cloud's points exactly), ``point`` (the input point of the vertex, -1 for none) and
    ``sections`` (bit s set: the vertex's point is in section s); face vertex_indices and section.

    The ``point`` property is what lets `bodyscan score` pair the vertices with the cloud's points
    exactly when they moved (denoising) or were added (a closed surface).

    Parameters
    ----------
    path : str or path
    vertices : (n, 3) float, metres
    faces : (m, 3) int
    face_section : (m,) int
    point_sections : (p, 11) bool, optional
        Section memberships of the input points, p <= n (written as zero without).
    point_index : (n,) int, optional
        Input point of each vertex, -1 for none (default: vertex i is point i when i < p).
    """
    path = Path(path)
    v = np.zeros(len(vertices), dtype=[("xyz", "<f8", (3,)), ("point", "<i4"), ("sections", "<u2")])
    v["xyz"] = np.asarray(vertices, dtype=np.float64)
    n_points = 0 if point_sections is None else len(point_sections)
    if point_index is None:
        point_index = np.where(np.arange(len(v)) < n_points, np.arange(len(v)), -1)
    v["point"] = np.asarray(point_index).reshape(len(v))
    if point_sections is not None:
        bits = np.asarray(point_sections, bool).reshape(n_points, -1)
        code = (bits * (1 << np.arange(bits.shape[1]))).sum(axis=1)
        has = v["point"] >= 0
        v["sections"][has] = code[v["point"][has]]
    f = np.asarray(faces)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment bodyscan reconstruction; face section indexes "
        + " ".join(SECTIONS) + "; vertex point: input point (-1 none); vertex sections: bit s set for section s"
        + f"\nelement vertex {len(v)}\nproperty double x\nproperty double y\n"
        f"property double z\nproperty int point\nproperty ushort sections\nelement face {len(f)}\n"
        "property list uchar int vertex_indices\nproperty uchar section\nend_header\n"
    )
    rec = np.zeros(len(f), dtype=[("n", "u1"), ("idx", "<i4", (3,)), ("section", "u1")])
    rec["n"] = 3
    rec["idx"] = f
    rec["section"] = np.asarray(face_section, dtype=np.int64) & 0xFF
    from bodyscan._io import atomic_write

    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(v.tobytes())
            fh.write(rec.tobytes())
    return atomic_write(path, write, error=ReconError)


def check_points(points) -> np.ndarray:
    """``points`` as a (n, 3) float64 array; raise `ReconError` for anything unusable."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReconError(f"points must be an (n, 3) array, got shape {p.shape}")
    if not np.issubdtype(p.dtype, np.number):
        raise ReconError(f"points must be numbers, got {p.dtype}")
    p = p.astype(np.float64)
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise ReconError(f"{int(bad.sum())} points are NaN or infinite; remove them first")
    if len(p) < MIN_POINTS:
        raise ReconError(f"only {len(p)} points; a body surface needs at least {MIN_POINTS}")
    extent = float(np.ptp(p, axis=0).max())
    if extent > 3.0:
        raise ReconError(f"the cloud spans {extent:.4g} units; coordinates must be metres "
                         "(divide millimetres by 1000)")
    if extent < 0.3:
        raise ReconError(f"the cloud spans only {extent:.4g} units; is it a whole body, in metres?")
    return p


def _check_view_dir(view_dir, n):
    if view_dir is None:
        return None
    vd = np.asarray(view_dir, dtype=np.float64)
    if vd.shape not in ((3,), (n, 3)):
        raise ReconError(f"view_dir must be (3,) or ({n}, 3), got shape {vd.shape}")
    if not np.isfinite(vd).all():
        raise ReconError("view_dir holds NaN or infinite values")
    return vd


@dataclass(frozen=True, eq=False)
class Prepared:
    """A cloud made ready for the fit (`prepare`).

    Attributes
    ----------
    points : (n, 3) float
        Every input point, registered between heads when asked, metres.
    view_dir : (n, 3) or (3,) float or None
    keep : (n,) bool
        Points that are not outliers.
    registration : recon.clean.register.Registration or None
    noise : float or None
        The cloud's range noise, metres: the robust scale of its local surface fits
        (`recon.clean.denoise.reject_outliers`); None when neither outliers nor denoising asked.
    """

    points: np.ndarray
    view_dir: np.ndarray | None
    keep: np.ndarray
    registration: object = None
    noise: float | None = None


#: The last `prepare` result, by a digest of its inputs: a benchmark estimates the posture, then
#: reconstructs the same cloud with it (deterministic, so reused as is; speed only).
_PREPARED: dict = {}


def clear_prepared() -> None:
    """Forget the cached `prepare` result, so that the next `reconstruct` starts from the raw
    cloud (a timing of the whole reconstruction, repeated on one cloud, must not reuse it)."""
    _PREPARED.clear()


def prepare(points: np.ndarray, params: ReconParams, view_dir=None, head=None) -> Prepared:
    """Outlier rejection (``outlier_z``), then registration between heads (``register_heads``,
    when ``head`` (n,) is known), on checked points (n, 3)."""
    import hashlib

    digest = hashlib.sha1(repr(params.clean).encode())
    for a in (points, view_dir, head):
        digest.update(b"|" if a is None else np.ascontiguousarray(a).tobytes())
    key = digest.hexdigest()
    if key not in _PREPARED:
        _PREPARED.clear()
        _PREPARED[key] = _prepare(points, params, view_dir, head)
    return _PREPARED[key]


def _prepare(points, params, view_dir, head) -> Prepared:
    from scipy.spatial import cKDTree

    from .surface.mesh import median_spacing

    c = params.clean
    keep = np.ones(len(points), dtype=bool)
    reg = noise = None
    if c.outlier_z > 0 or c.register_heads or c.denoise:
        tree = cKDTree(points)
        spacing = median_spacing(points, tree=tree)
        if c.outlier_z > 0 or c.denoise:   # the noise, measured on the same fits
            from .clean.denoise import reject_outliers

            outlier, noise = reject_outliers(points, spacing, c.outlier_neighbours, c.outlier_z or np.inf,
                                             c.outlier_floor, c.outlier_isolation, tree=tree,
                                             workers=params.surface.workers)
            if c.outlier_z > 0:
                keep = ~outlier
        if c.register_heads and head is not None:
            from .clean.register import register_heads

            reg = register_heads(points[keep], head[keep], spacing)
            if not reg.observable.any() and view_dir is not None and np.ndim(view_dir) == 2:
                from .clean.register import register_silhouettes  # opposite heads: no overlap

                reg = register_silhouettes(points[keep], head[keep], view_dir[keep], spacing)
            points, view_dir = reg.apply(points, head, view_dir)
    return Prepared(points, view_dir, keep, reg, noise)


def _check_head(head, n):
    if head is None:
        return None
    h = np.asarray(head)
    if h.shape != (n,) or not np.issubdtype(h.dtype, np.integer) or (len(h) and h.min() < 0):
        raise ReconError(f"head must be ({n},) non-negative integers (the head that measured each point)")
    return h.astype(np.int64)


def estimate_fit(points, params: ReconParams, view_dir=None, head=None) -> BodyFit:
    """Posture estimation through `recon.estimate_posture` on the `prepare`d points (outliers
    left out, heads registered); raises `ReconError` if unavailable."""
    p = check_points(points)
    vd = _check_view_dir(view_dir, len(p))
    hd = _check_head(head, len(p))
    prep = prepare(p, params, vd, hd)
    return _estimate(prep.points[prep.keep], params, _subset(prep.view_dir, prep.keep),
                     None if hd is None else hd[prep.keep])


def _subset(view_dir, keep):
    return view_dir[keep] if view_dir is not None and np.ndim(view_dir) == 2 else view_dir


def _estimate(points, params: ReconParams, view_dir=None, head=None) -> BodyFit:
    try:
        from .posture.fit import estimate_posture
    except ImportError:
        raise ReconError("posture estimation (recon.posture) is not available in this build; "
                         "pass a fitted model with fit= (or --fit FIT.json)") from None
    fit = estimate_posture(points, view_dir=view_dir, head=head) if params.fit is None else \
        estimate_posture(points, params.fit, view_dir=view_dir, head=head)
    return _extremities(points, fit, params)


def _extremities(points, fit: BodyFit, params: ReconParams, steps: str = "proposed") -> BodyFit:
    """``fit`` with its hands and feet placed (`recon.posture.extremities`) when ``extremities`` is
    on and it has none yet; without them when it is off (or for the simple baseline)."""
    from dataclasses import replace

    on = params.fit is not None and params.fit.extremities and steps != "simple"
    if not on:
        return replace(fit, extremities={}) if fit.extremities else fit
    if fit.extremities or not fit.sections:
        return fit
    from .posture.extremities import place_extremities

    return place_extremities(points, fit)


def reconstruct(points, method: str = "proposed", params: ReconParams | None = None, *,
                view_dir=None, fit: BodyFit | None = None, head=None) -> Reconstruction:
    """Reconstruct a body surface from a point cloud (paper sections 2 and 3).

    Parameters
    ----------
    points : (n, 3) float, metres
        The cloud (+z up).
    method : {"proposed", "proposed-closed", "paper", "simple"}
        ``proposed``: clustering refined by the distance distribution and the multi-section rules;
        ``proposed-closed`` (beyond the paper): ``proposed`` with the unseen surface closed
        (`recon.surface.closed.closed_surface`): watertight, its vertices new (after the input points,
        which it leaves in no face); ``paper``: the same steps with every rule of ours off
        (`recon.params.PAPER`), the paper's method as itself; ``simple``: the paper's baseline,
        T_d threshold only.
    params : ReconParams, optional
        Default: `ReconParams` defaults (the paper's values).
    view_dir : (n, 3) or (3,) float, optional
        Unit directions toward the sensor, for orientation (and the fit).
    fit : BodyFit, optional
        Use this posture instead of estimating it (e.g. an oracle posture).
    head : (n,) int, optional
        Index of the scanner head that measured each point (for ``register_heads``).

    Returns
    -------
    Reconstruction

    Raises
    ------
    ReconError
        Unusable points, method or parameters, or nothing could be reconstructed.
    """
    from .clustering.cluster import cluster_points, section_coordinates
    from .surface.mesh import reconstruct_surfaces

    t_start = time.perf_counter()
    if method not in METHODS:
        raise ReconError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
    params = params if params is not None else ReconParams()
    if not isinstance(params, ReconParams):
        raise ReconError(f"params must be a ReconParams, got {type(params).__name__}")
    steps = "simple" if method == "simple" else "proposed"   # the clustering's and surface's steps
    if method == "paper":  # the proposed steps with the paper's parameters
        params = params.paper()
    raw = check_points(points)
    vd_raw = _check_view_dir(view_dir, len(raw))
    times = {}
    t0 = time.perf_counter()
    hd = _check_head(head, len(raw))
    prep = prepare(raw, params, vd_raw, hd)
    keep = np.flatnonzero(prep.keep)
    p, vd = prep.points[keep], _subset(prep.view_dir, prep.keep)
    times["prepare"] = time.perf_counter() - t0
    if fit is None:
        t0 = time.perf_counter()
        fit = _estimate(p, params, vd, None if hd is None else hd[keep])
        times.update({f"fit_{k}": float(v) for k, v in (fit.times or {}).items()})
        times["fit"] = time.perf_counter() - t0
    elif not isinstance(fit, BodyFit):
        raise ReconError(f"fit must be a BodyFit, got {type(fit).__name__}")
    fit = _extremities(p, fit, params, steps)
    if not fit.sections:
        raise ReconError("the fitted model has no sections: nothing to reconstruct")

    t0 = time.perf_counter()
    widest = max(s.width for s in fit.sections.values())
    coords = section_coordinates(p, fit, margin=params.cluster.t_d * widest + 0.01)
    times["coords"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    from scipy.spatial import cKDTree

    from .surface.mesh import median_spacing

    tree = cKDTree(p)
    member = cluster_points(p, fit, steps, params.cluster, coords=coords, tree=tree)
    times["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    extra = []
    spacing = median_spacing(p, tree=tree)
    ext = np.full(len(p), -1)   # the hand or foot of each point (beyond the paper), -1 for none
    if fit.extremities and steps != "simple":
        from .clustering.cluster import assign_extremities
        from .model import EXTREMITIES

        ext = assign_extremities(p, member, fit, params.cluster.t_d)
        parent = np.array([SECTIONS.index(a) for a, _ in EXTREMITIES.values()])
        member = member.copy()   # labelled as the section they continue, meshed on their own chart
        member[np.flatnonzero(ext >= 0), parent[ext[ext >= 0]]] = True
    # points beyond T_d of every section: labelled (paper 3), not meshed with the sections
    from .clustering.cluster import section_widths, simple_clustering

    far = ~simple_clustering(coords[0], section_widths(fit), params.cluster.t_d).any(axis=1) & (ext < 0)
    sp = params.surface
    meshed = member & ~far[:, None] & (ext < 0)[:, None]
    if sp.far_charts and steps != "simple":  # ... but on charts of their own
        from .surface.complete import far_charts

        extra = far_charts(p, far, fit.sections, meshed, spacing, sp.far_link,
                           sp.far_join, sp.far_min_points, sp.far_max_edge, tree)
    if (ext >= 0).any():
        from .surface.complete import extremity_charts

        extra = extremity_charts(p, ext, fit, meshed, spacing, sp.far_join, sp.far_max_edge, tree,
                                 sp.far_hand_spacing) + extra
    t_mesh = time.perf_counter() - t0
    mesh_points = p
    rejected = np.zeros(len(p), dtype=bool)
    # a surface that denoises (recon.clean.denoise), where there is noise to take out: on a
    # quieter cloud the fits' own error is as large as what they would take out
    noisy = prep.noise is None or prep.noise >= params.clean.denoise_min_noise * spacing
    if steps == "proposed" and params.clean.denoise and noisy:
        from .clean.denoise import denoise
        from .model import EXTREMITIES

        t0 = time.perf_counter()
        c = params.clean
        # feet (labelled as their section) and far parts are denoised with their sections; the
        # points of a far part in no section (a limb the fit missed) with that part's own points;
        # a hand with its own points, in fits within denoise_reach: its surface turns within a
        # finger's width, which a section's wider fits (20 mm) would take for noise
        groups = member | meshed
        parts = np.zeros((len(p), len(extra)), dtype=bool)
        for j, e in enumerate(extra):   # (section, points, chart, changes, own points)
            parts[e[4] if len(e) > 4 else e[1], j] = True
        parts &= ~groups.any(axis=1)[:, None]
        hands = ext[:, None] == np.array([i for i, name in enumerate(EXTREMITIES) if name.startswith("hand")])
        groups &= ~hands.any(axis=1)[:, None]
        radius = [c.denoise_radius] * (groups.shape[1] + parts.shape[1]) + [c.denoise_reach] * hands.shape[1]
        dn = denoise(p, np.hstack([groups, parts, hands]), spacing, c.denoise_neighbours, c.denoise_clamp,
                     c.outlier_z or np.inf, c.outlier_floor, c.outlier_isolation, radius,
                     params.surface.workers, c.denoise_share, c.denoise_error, c.denoise_reach,
                     c.denoise_passes)
        mesh_points, rejected = dn.points, dn.rejected
        meshed = meshed & ~rejected[:, None]
        times["denoise"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        faces, face_section, skipped = reconstruct_surfaces(mesh_points, meshed, fit, params.surface, vd,
                                                            drop_inner=steps == "proposed",
                                                            spacing=spacing, extra=extra, outliers=rejected)
    for w in caught:  # re-issue from here, once each
        warnings.warn(str(w.message), w.category, stacklevel=2)
    times["surface"] = t_mesh + time.perf_counter() - t0
    if len(faces) == 0:
        raise ReconError(f"no surface could be made from {len(p)} points: no section had enough "
                         "clustered points (is the fitted model placed on the cloud?)")
    from .surface.complete import unmeshed_count

    vertices = prep.points.copy()
    vertices[keep] = mesh_points
    moved = np.linalg.norm(vertices - raw, axis=1)
    kept_faces, faces = faces, keep[faces]   # over the kept points; over the input points
    unmeshed = unmeshed_count(len(raw), faces)
    point_faces = faces
    if method == "proposed-closed":  # beyond the paper: the unseen surface closed
        from .surface.closed import closed_surface

        t0 = time.perf_counter()
        sp = params.surface
        view = None if vd is None else (np.broadcast_to(vd, p.shape), None if hd is None else hd[keep])
        solids = [(j, np.flatnonzero(meshed[:, j]), fit.sections[name]) for j, name in enumerate(SECTIONS)
                  if name in fit.sections and name not in skipped] + list(extra)
        cv, cf, face_section = closed_surface(mesh_points, solids, spacing, sp.close_voxel,
                                              sp.close_cell, sp.close_envelope,
                                              sp.close_band, (vertices, faces, face_section),
                                              view, sp.close_carve, sp.close_background,
                                              sp.close_smooth, sp.workers)
        vertices, faces = np.concatenate([vertices, cv]), cf + len(raw)
        times["complete"] = time.perf_counter() - t0
    elif steps == "proposed" and params.surface.curve_edge > 0:   # long triangles follow the body
        from .surface.curve import curve_surface

        t0 = time.perf_counter()
        limit = max(params.surface.curve_edge * spacing, params.surface.curve_min_edge)
        cv, kept_faces, face_section = curve_surface(mesh_points, kept_faces, limit, vd, tree, face_section)
        new = cv[len(keep):]                     # after every input point
        faces = np.concatenate([keep, np.arange(len(raw), len(raw) + len(new))])[kept_faces]
        vertices = np.concatenate([vertices, new])
        times["curve"] = time.perf_counter() - t0
    times["total"] = time.perf_counter() - t_start
    sections = np.zeros((len(raw), member.shape[1]), dtype=bool)
    sections[keep] = member & ~rejected[:, None]
    outliers = ~prep.keep
    outliers[keep[rejected]] = True
    return Reconstruction(vertices=vertices, faces=faces, face_section=face_section,
                          point_sections=sections, fit=fit, times=times, params=params, method=method,
                          skipped=tuple(skipped), points_unmeshed=unmeshed, points=raw, moved=moved,
                          outliers=outliers, registration=prep.registration, point_faces=point_faces,
                          noise=prep.noise)
