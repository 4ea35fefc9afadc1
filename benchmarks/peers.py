"""Peer reconstructors to compare against: Open3D Poisson (plain and trimmed), ball pivoting and
alpha shapes, and pymeshlab's screened Poisson (the ``peers`` extra, imported lazily).

Every peer gets the same oriented normals, made from the points the way a real pipeline would:
k-nearest-neighbour PCA (`estimate_normals`), flipped toward the sensor (the scan's ``view_dir``,
which a real scanner knows). A peer returns its own vertices (not scan points), so the metrics
find each vertex's true triangle by the nearest point of the true surface.

Settings (`PeerParams`), each the usual choice for the tool:

- ``poisson``: Open3D screened Poisson, octree depth 9, bounding-box scale 1.1, no linear fit,
  one thread;
- ``poisson-trimmed``: the same, then the vertices whose density (the octree's point support) is
  below the 5 % quantile are removed with their triangles, the usual trim of Poisson's
  extrapolated surface (run right after ``poisson`` on the same points, as in a benchmark, it
  reuses that surface; its time still counts the surface's seconds);
- ``bpa``: Open3D ball pivoting with radii 1.5, 3 and 6 times the mean nearest-neighbour spacing
  (the small ball follows detail, the larger ones close the stripes of a slit-laser scan);
- ``alpha``: Open3D alpha shape with alpha 5 times the mean nearest-neighbour spacing. An alpha
  shape is made of Delaunay tetrahedra smaller than alpha, so it fills limbs thinner than that,
  leaves wider parts (the torso) a partial shell, and joins anything closer than alpha (legs,
  arms at the sides): the classic baseline, not a contender. Its winding is arbitrary, so each
  triangle is flipped to agree with the normals of its vertices;
- ``spsr``: pymeshlab (MeshLab) screened Poisson, depth 9, point weight 4, one thread (with two
  threads on a busy machine one run took 57 s instead of 3.5 s).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from . import BenchError

#: Peer methods, in table order, and the package each needs.
PEERS = {
    "poisson": "open3d",
    "poisson-trimmed": "open3d",
    "bpa": "open3d",
    "alpha": "open3d",
    "spsr": "pymeshlab",
}


@dataclass(frozen=True)
class PeerParams:
    """Settings of the peer reconstructors (see the module docstring)."""

    normal_k: int = field(default=20,  # neighbours of the PCA normal
        metadata={"help": "neighbours of the PCA normal", "unit": "", "range": (3, 1000)})
    poisson_depth: int = field(default=9,  # octree depth (Open3D and pymeshlab)
        metadata={"help": "octree depth of Poisson reconstruction", "unit": "", "range": (1, 14)})
    poisson_scale: float = field(default=1.1,  # bounding-box scale of the octree
        metadata={"help": "bounding-box scale of the octree", "unit": "", "range": (1, 10)})
    trim_quantile: float = field(default=0.05,  # poisson-trimmed: density quantile removed
        metadata={"help": "poisson-trimmed: density quantile removed", "unit": "", "range": (0, 1)})
    bpa_radii: tuple = field(default=(1.5, 3.0, 6.0),  # ball radii, in mean nearest-neighbour spacings
        metadata={"help": "ball-pivoting radii", "unit": "spacings", "range": (0.01, 1000)})
    alpha: float = field(default=5.0,  # alpha, in mean nearest-neighbour spacings
        metadata={"help": "alpha of the alpha shape", "unit": "spacings", "range": (0.01, 1000)})
    spsr_point_weight: float = field(default=4.0,  # pymeshlab screened Poisson interpolation weight
        metadata={"help": "screened Poisson interpolation weight (pymeshlab)", "unit": "", "range": (0, 1000)})
    threads: int = field(default=1,  # stable timings
        metadata={"help": "threads of the peer libraries (1: stable timings)", "unit": "", "range": (1, 256)})

    def __post_init__(self):
        from bodyscan._params import check_fields

        from . import BenchError

        check_fields(self, BenchError)

    def as_columns(self) -> dict:
        return {f"peer_{k}": (",".join(map(str, v)) if isinstance(v, tuple) else v)
                for k, v in asdict(self).items()}


def available_peers() -> list[str]:
    """Peer methods whose package imports here."""
    missing = unavailable_peers()
    return [m for m in PEERS if m not in missing]


def unavailable_peers() -> dict:
    """Peer methods whose package does not import here: {method: why, in one line}."""
    why = {}
    for pkg in sorted(set(PEERS.values())):
        try:
            __import__(pkg)
        except Exception as exc:  # ImportError, or OSError for a missing system library (libusb)
            if isinstance(exc, ModuleNotFoundError) and exc.name == pkg:
                why[pkg] = f"{pkg} is not installed: pip install 'bodyscan[peers]'"
                continue
            hint = " (apt-get install libusb-1.0-0)" if "libusb" in str(exc) else ""
            text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            why[pkg] = f"{pkg} does not import: {text}{hint}"
    return {m: why[pkg] for m, pkg in PEERS.items() if pkg in why}


def _import(method: str):
    pkg = PEERS[method]
    try:
        return __import__(pkg)
    except Exception as exc:
        hint = " (Open3D also needs the system library: apt-get install libusb-1.0-0)" if pkg == "open3d" else ""
        raise BenchError(f"method {method!r} needs {pkg}, which does not import here ({exc}); "
                         f"install the peers extra: pip install 'bodyscan[peers]'{hint}") from None


def mean_spacing(points: np.ndarray) -> float:
    """Mean distance from each point to its nearest neighbour, metres."""
    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].mean())


def estimate_normals(points: np.ndarray, view_dir: np.ndarray | None = None, k: int = 20) -> np.ndarray:
    """Unit normals by PCA of each point's k nearest neighbours, oriented toward the sensor.

    Parameters
    ----------
    points : (n, 3) float, metres
    view_dir : (n, 3) or (3,) float, optional
        Unit vectors from each point toward its camera; a normal is flipped when it points away.
        Without it, normals point away from the vertical axis through the centroid (a guess that
        fails in armpits and between the legs).
    k : int

    Returns
    -------
    normals : (n, 3) float
    """
    k = int(min(k, len(points)))
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vec = np.linalg.eigh(cov)
    n = vec[:, :, 0]                                  # smallest eigenvalue's eigenvector
    if view_dir is None:
        c = points.mean(axis=0)
        toward = points - c
        toward[:, 2] = 0.0
    else:
        toward = np.broadcast_to(np.asarray(view_dir, dtype=np.float64), points.shape)
    flip = np.einsum("ij,ij->i", n, toward) < 0
    n[flip] *= -1
    return n


def reconstruct_peer(method: str, points, view_dir=None, params: PeerParams | None = None
                     ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Reconstruct a surface from points with a peer method.

    Parameters
    ----------
    method : str
        One of `PEERS`.
    points : (n, 3) float, metres
    view_dir : (n, 3) float, optional
        Unit vectors toward the sensor (normal orientation).
    params : PeerParams, optional

    Returns
    -------
    vertices : (V, 3) float
        The peer's own vertices (not the input points).
    faces : (F, 3) int
    times : dict of str to float
        Seconds: ``normals``, ``surface`` (the peer itself, trimming included) and ``total``.

    Raises
    ------
    BenchError
        Unknown method, missing package, or unusable points.
    """
    if method not in PEERS:
        raise BenchError(f"unknown peer method {method!r} (choose from {', '.join(PEERS)})")
    params = params or PeerParams()
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10 or not np.isfinite(p).all():
        raise BenchError(f"points must be a finite (n, 3) array with n >= 10, got shape {p.shape}")
    vd = None if view_dir is None else np.asarray(view_dir, dtype=np.float64)
    if vd is not None and vd.shape not in (p.shape, (3,)):
        raise BenchError(f"view_dir must be (n, 3) or (3,), got {vd.shape}")
    lib = _import(method)
    t0 = time.perf_counter()
    normals = estimate_normals(p, vd, params.normal_k)
    t1 = time.perf_counter()
    reused_s = 0.0
    if method == "spsr":
        v, f = _spsr(lib, p, normals, params)
    else:
        v, f, reused_s = _open3d(lib, method, p, normals, params)
    t2 = time.perf_counter()
    return v, f, {"normals": t1 - t0, "surface": t2 - t1 + reused_s, "total": t2 - t0 + reused_s}


def _open3d(o3d, method, p, normals, params: PeerParams):
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    TM = o3d.geometry.TriangleMesh
    if method in ("poisson", "poisson-trimmed"):
        v, f, density, reused_s = _poisson(o3d, pcd, p, normals, params)
        if method == "poisson-trimmed":   # as TriangleMesh.remove_vertices_by_mask
            keep = density >= np.quantile(density, params.trim_quantile)
            f = (np.cumsum(keep) - 1)[f[keep[f].all(axis=1)]]
            v = v[keep]
        return v, f, reused_s
    elif method == "bpa":
        s = mean_spacing(p)
        mesh = TM.create_from_point_cloud_ball_pivoting(
            pcd, o3d.utility.DoubleVector([r * s for r in params.bpa_radii]))
    else:  # alpha
        mesh = TM.create_from_point_cloud_alpha_shape(pcd, params.alpha * mean_spacing(p))
        v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)
        return v, _orient_by_normals(v, f, p, normals), 0.0
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64), 0.0


#: The last Open3D Poisson surface: (key, vertices, faces, density, seconds it took). ``poisson``
#: and ``poisson-trimmed`` of one scan solve the same Poisson problem; the second reuses it.
_LAST_POISSON: list = [None]


def _poisson(o3d, pcd, p, normals, params: PeerParams):
    """Open3D's screened Poisson surface of the points: (vertices, faces, density, seconds),
    computed once for the same points, normals and settings (the last one is kept); seconds: the
    time it took when it is reused (0 when computed now), so that each method's time is its own
    cost."""
    import hashlib

    key = hashlib.sha1(np.ascontiguousarray(p).tobytes() + np.ascontiguousarray(normals).tobytes()
                       + repr((params.poisson_depth, params.poisson_scale, params.threads)).encode()
                       ).hexdigest()
    last = _LAST_POISSON[0]
    if last is None or last[0] != key:
        started = time.perf_counter()
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=params.poisson_depth, width=0, scale=params.poisson_scale, linear_fit=False,
            n_threads=params.threads)
        last = (key, np.asarray(mesh.vertices, dtype=np.float64),
                np.asarray(mesh.triangles, dtype=np.int64), np.asarray(density, dtype=np.float64),
                time.perf_counter() - started)
        _LAST_POISSON[0] = last
        return last[1], last[2], last[3], 0.0
    return last[1], last[2], last[3], last[4]


def _orient_by_normals(v, f, points, normals):
    """Flip triangles whose normal disagrees with the mean normal of their vertices' nearest
    points (Open3D's alpha shape leaves the winding arbitrary)."""
    if len(f) == 0:
        return f
    _, idx = cKDTree(points).query(v)
    vn = normals[idx][f].sum(axis=1)
    t = v[f]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    flip = np.einsum("ij,ij->i", fn, vn) < 0
    f = f.copy()
    f[flip] = f[flip][:, ::-1]
    return f


def _spsr(pymeshlab, p, normals, params: PeerParams):
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=p, v_normals_matrix=normals))
    ms.generate_surface_reconstruction_screened_poisson(
        depth=params.poisson_depth, scale=params.poisson_scale, pointweight=params.spsr_point_weight,
        preclean=False, threads=params.threads)
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)
