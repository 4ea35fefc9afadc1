"""Scores any triangle mesh against a ground-truth body and its scan: spurious and bridging surface,
accuracy and completeness, section labels, posture.

Every metric is computed from plain arrays; `score_mesh` gathers them into one flat dict whose keys
are the columns of the results table (see `METRIC_NAMES`).

Conventions
-----------
- Distances are from points to surfaces (exact closest points on triangles, see `SurfaceIndex`),
  never from points to points, so sampling adds variance but no bias.
- Samples are area-uniform and seeded (`MetricParams.seed`): the same inputs give the same numbers.
- The "true normal" of a reconstructed vertex is the normal of the ground-truth triangle it came
  from: its scan point's ``gt_face`` when the vertex is a scan point, else the triangle of the
  nearest point of the true surface.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from bodyscan._params import check_fields

from . import BenchError

#: Body section names, in label order (same as ``poses.SECTIONS``).
SECTIONS = (
    "head", "chest", "waist",
    "upper_arm_l", "upper_arm_r", "forearm_l", "forearm_r",
    "thigh_l", "thigh_r", "lower_leg_l", "lower_leg_r",
)


@dataclass(frozen=True)
class MetricParams:
    """Settings of the metrics (the paper gives none of them; each choice is documented here).

    Attributes
    ----------
    spurious_angle_deg : float
        A triangle is spurious when its normal is more than this from the true normal (paper 4.2
        compares normals without a number; 30 degrees).
    oriented : bool
        Compare oriented normals (a flipped triangle is spurious). With False, the angle between
        the two lines is used (``|cos|``), for tools whose output winding is arbitrary.
    bridging_distance_m : float
        A triangle is "in the air" (bridging) when its centroid is outside the true body and more
        than this from its surface, metres.
    taus_m : tuple of float
        Distance thresholds of precision / recall / F-score, metres (Tanks and Temples style).
    n_samples : int
        Area-uniform samples drawn on each surface for precision, recall, Chamfer and normal
        consistency.
    seen_radius_m : float
        A true-surface sample counts as "seen by the scanner" when a scan point lies within this
        distance, metres. 15 mm is more than half the widest stripe spacing of the presets (10 mm),
        so a surface the scanner swept is seen everywhere, yet far below the size of the holes
        that matter (occluded armpits, inner thighs, soles: several centimetres).
    exterior_rays : int
        The recalls and Chamfer distance count the body's outer surface: the true triangles that
        a ray from outside reaches, tried along this many directions (`exterior_faces`). A body
        mesh can hold surface no ray from outside reaches (the mouth's cavity behind closed lips,
        skin pressed into skin), which no scanner sees and no reconstruction of the outside
        should hold. 0 counts every triangle.
    seed : int
        Seed of the surface samples.
    backend : {"auto", "open3d", "numpy"}
        Closest-point backend (see `SurfaceIndex`; same answers, Open3D is faster).
    """

    spurious_angle_deg: float = field(default=30.0,
        metadata={"help": "a triangle is spurious when its normal is more than this from the true normal", "unit": "deg", "range": (0.01, 179.99)})
    oriented: bool = field(default=True,
        metadata={"help": "compare oriented normals (a flipped triangle is spurious)", "unit": "", "range": None})
    bridging_distance_m: float = field(default=0.005,
        metadata={"help": "a triangle outside the body farther than this from its surface is bridging", "unit": "m", "range": (0, 1)})
    taus_m: tuple = field(default=(0.005, 0.010),
        metadata={"help": "distance thresholds of precision, recall and F-score", "unit": "m", "range": (1e-05, 1)})
    n_samples: int = field(default=50_000,
        metadata={"help": "area-uniform samples drawn on each surface", "unit": "", "range": (100, 10000000)})
    seen_radius_m: float = field(default=0.015,
        metadata={"help": "a true-surface sample is seen when a scan point lies within this", "unit": "m", "range": (1e-05, 1)})
    exterior_rays: int = field(default=128,
        metadata={"help": "rays per true triangle that find the body's outer surface (what some ray from outside reaches; 0: every triangle)", "unit": "", "range": (0, 100000)})
    seed: int = field(default=0,
        metadata={"help": "seed of the surface samples", "unit": "", "range": (0, None)})
    backend: str = field(default="auto",
        metadata={"help": "closest-point backend: auto, open3d or numpy (same answers)", "unit": "", "range": None})

    def __post_init__(self):
        check_fields(self, BenchError)
        if self.backend not in ("auto", "open3d", "numpy"):
            raise BenchError(f"backend must be auto, open3d or numpy, got {self.backend!r}")
        if not 0 < self.spurious_angle_deg < 180:
            raise BenchError(f"spurious_angle_deg must be in (0, 180) degrees, got {self.spurious_angle_deg}")
        if self.bridging_distance_m < 0 or self.seen_radius_m <= 0:
            raise BenchError("bridging_distance_m must be >= 0 and seen_radius_m > 0 (metres)")
        if self.n_samples < 100:
            raise BenchError(f"n_samples must be at least 100, got {self.n_samples}")
        if not self.taus_m or min(self.taus_m) <= 0:
            raise BenchError(f"taus_m must be positive distances in metres, got {self.taus_m}")
        object.__setattr__(self, "taus_m", tuple(float(t) for t in self.taus_m))

    def as_columns(self) -> dict:
        """The settings as flat ``metric_<name>`` columns."""
        return {f"metric_{k}": (json.dumps(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def tau_label(tau_m: float) -> str:
    """``0.005 -> '5mm'`` (column suffix)."""
    mm = tau_m * 1000.0
    return f"{mm:g}mm"


# --------------------------------------------------------------------------------------------------
# geometry helpers


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (right-hand winding) and areas of triangles.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int

    Returns
    -------
    normals : (F, 3) float
        Unit normals; zero rows for degenerate triangles.
    areas : (F,) float
        Areas, square metres when vertices are in metres.
    """
    t = vertices[faces]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    return normals, 0.5 * norm


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    n : int
        Number of samples.
    seed : int

    Returns
    -------
    points : (n, 3) float
    face_index : (n,) int
        Triangle each sample lies on.
    """
    _, areas = face_normals(vertices, faces)
    total = areas.sum()
    if len(faces) == 0 or not total > 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(areas) / total
    fid = np.minimum(np.searchsorted(cdf, rng.random(n), side="right"), len(faces) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    t = vertices[faces[fid]]
    pts = (1 - s)[:, None] * t[:, 0] + (s * (1 - r2))[:, None] * t[:, 1] + (s * r2)[:, None] * t[:, 2]
    return pts, fid.astype(np.int64)


def closest_point_on_triangles(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Closest point of each triangle to its point (Ericson, Real-Time Collision Detection 5.1.5).

    Parameters
    ----------
    triangles : (m, 3, 3) float
    points : (m, 3) float

    Returns
    -------
    closest : (m, 3) float
    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac = b - a, c - a

    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ap, bp, cp = points - a, points - b, points - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = va + vb + vc
        v, w = vb / s, vc / s                      # inside the face
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # Voronoi regions, lowest priority first (a later assignment wins, as in Ericson's order)
    for m, vv, ww in (
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), 1 - t_bc, t_bc),  # edge BC
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), 0.0, t_ac),                  # edge AC
        ((d6 >= 0) & (d5 <= d6), 0.0, 1.0),                              # vertex C
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), t_ab, 0.0),                  # edge AB
        ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),                              # vertex B
        ((d1 <= 0) & (d2 <= 0), 0.0, 0.0),                               # vertex A
    ):
        v = np.where(m, vv, v)
        w = np.where(m, ww, w)
    bad = ~(np.isfinite(v) & np.isfinite(w))       # degenerate triangle: fall back to its vertices
    if bad.any():
        v[bad], w[bad] = 0.0, 0.0
    return a + v[:, None] * ab + w[:, None] * ac


def split_long_edges(triangles: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Bisect triangles at their longest edge until no edge is longer than ``max_edge``.

    The pieces tile each triangle exactly (same orientation), so the closest point on a triangle is
    the closest point on its pieces.

    Parameters
    ----------
    triangles : (F, 3, 3) float
    max_edge : float

    Returns
    -------
    pieces : (m, 3, 3) float
    owner : (m,) int
        Triangle each piece came from.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    owner = np.arange(len(tri))
    done_t, done_o = [], []
    while len(tri):
        edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)   # edge i joins vertex i and i+1
        longest = edges.argmax(axis=1)
        split = edges[np.arange(len(tri)), longest] > max_edge
        done_t.append(tri[~split])
        done_o.append(owner[~split])
        tri, owner, k = tri[split], owner[split], longest[split]
        t = tri[np.arange(len(tri))[:, None], (k[:, None] + np.arange(3)) % 3]   # longest edge 0-1
        mid = 0.5 * (t[:, 0] + t[:, 1])
        tri = np.concatenate([np.stack([t[:, 0], mid, t[:, 2]], axis=1),
                              np.stack([mid, t[:, 1], t[:, 2]], axis=1)])
        owner = np.concatenate([owner, owner])
    return np.concatenate(done_t), np.concatenate(done_o)


#: Numpy backend: (point, piece) pairs examined at once; a pair costs about 400 bytes.
MAX_PAIRS = 250_000


class _Pieces:
    """Pieces of a mesh's triangles no longer than ``max_edge``, with a k-d tree of centroids."""

    def __init__(self, triangles, max_edge):
        self.tri, self.owner = split_long_edges(triangles, max_edge)
        cent = self.tri.mean(axis=1)
        self.radii = np.linalg.norm(self.tri - cent[:, None], axis=2).max(axis=1)
        self.radius = float(self.radii.max())
        self.tree = cKDTree(cent)

    def closest(self, p, row, piece):
        """Per row of ``p``, the nearest of its candidate pieces: (distance, face, point)."""
        c = closest_point_on_triangles(self.tri[piece], p[row])
        d = np.linalg.norm(c - p[row], axis=1)
        # ``row`` is sorted and holds every row of ``p``: per run of equal rows, the first
        # candidate at the run's smallest distance (no sort needed)
        starts = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
        dmin = np.minimum.reduceat(d, starts)
        at_min = np.flatnonzero(d == np.repeat(dmin, np.diff(np.r_[starts, len(d)])))
        best = at_min[np.r_[True, row[at_min][1:] != row[at_min][:-1]]]
        return d[best], self.owner[piece[best]], c[best]

    def nearest_k(self, p, k):
        """Nearest of the pieces of the k nearest centroids, and whether that is provably exact."""
        k = min(k, self.tree.n)
        dk, idx = self.tree.query(p, k=k)
        dk, idx = dk.reshape(len(p), -1), idx.reshape(len(p), -1)
        # the nearest centroid's piece bounds the distance; examine only pieces that could beat it
        d0 = np.linalg.norm(closest_point_on_triangles(self.tri[idx[:, 0]], p) - p, axis=1)
        row, col = np.nonzero(dk - self.radii[idx] <= d0[:, None])
        d, f, c = self.closest(p, row, idx[row, col])
        return d, f, c, (d + self.radius <= dk[:, -1]) | (k == self.tree.n)

    def within(self, p, bound, max_pairs: int = MAX_PAIRS):
        """Nearest of all pieces that can lie within ``bound`` (n,) of each point: exact.

        Points are taken in batches of at most ``max_pairs`` (point, piece) candidates (but at least
        one point), so that memory stays bounded however far the points lie."""
        reach = bound + self.radius + 1e-12
        counts = np.asarray(self.tree.query_ball_point(p, reach, return_length=True), dtype=np.int64)
        ends = np.searchsorted(np.cumsum(counts), np.arange(1, 1 + counts.sum() // max_pairs) * max_pairs)
        d, f, c = np.empty(len(p)), np.empty(len(p), dtype=np.int64), np.empty((len(p), 3))
        start = 0
        for end in [*np.unique(np.maximum(ends, 1)), len(p)]:
            end = int(min(max(end, start + 1), len(p)))
            if end <= start:
                continue
            lists = self.tree.query_ball_point(p[start:end], reach[start:end])
            cnt = counts[start:end]
            cand = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(cnt.sum()))
            d[start:end], f[start:end], c[start:end] = self.closest(
                p[start:end], np.repeat(np.arange(end - start), cnt), cand)
            start = end
        return d, f, c


#: Numpy backend: a query point farther than this from the surface (metres) keeps the nearest of
#: the pieces of its k nearest centroids, exact to twice a piece's radius (under 1 cm, a tenth of
#: the distance), instead of the searches over more pieces: on a mesh of another body those took
#: 170 s and 3.2 GB (`bodyscan score`), for metrics that saturate at 1 cm.
EXACT_WITHIN = 0.1
#: Memory of scoring per surface sample and per mesh triangle, and the closest-point queries'
#: working set (8192 points x 96 pieces at most, 400 bytes a pair), bytes (`score_mesh`'s guard).
BYTES_PER_SAMPLE, BYTES_PER_FACE, QUERY_BYTES = 600, 400, 8192 * 96 * 400


class SurfaceIndex:
    """Exact closest points on a fixed triangle mesh, for many query points.

    Two interchangeable backends give the same answers (to float32 rounding, ~1e-7 m):

    - ``"open3d"``: Open3D's `RaycastingScene` (a BVH in C++; about 20x faster), used by
      ``"auto"`` when Open3D (the ``peers`` extra) is installed;
    - ``"numpy"``: the triangles are cut into pieces no longer than ``max_edge``
      (`split_long_edges`), whose centroids go in a k-d tree. A query computes the exact closest
      point on the pieces of its ``k`` nearest centroids; the answer is provably exact when its
      distance plus the largest piece radius does not exceed the distance of the k-th centroid
      (no other piece can then be nearer). Queries failing this check (farther from the surface)
      try again with ``4 k`` pieces, and those still failing are answered from every piece, of a
      second cut 8x coarser, whose centroid lies within that bound.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    backend : {"auto", "open3d", "numpy"}
    max_edge : float
        Longest edge of the pieces (numpy backend), same unit as ``vertices``.
    k : int
        Pieces examined per query in the first pass (numpy backend).
    """

    def __init__(self, vertices, faces, *, backend: str = "auto", max_edge: float = 0.008, k: int = 24):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        if len(self.faces) == 0:
            raise BenchError("cannot index a mesh without triangles")
        if backend not in ("auto", "open3d", "numpy"):
            raise BenchError(f"unknown closest-point backend {backend!r} (auto, open3d, numpy)")
        self.normals, self.areas = face_normals(self.vertices, self.faces)
        self._scene = None
        if backend in ("auto", "open3d"):
            try:
                import open3d as o3d
            except ImportError:
                if backend == "open3d":
                    raise BenchError("the open3d backend needs Open3D: pip install 'bodyscan[peers]'") from None
            else:
                self._o3d = o3d
                self._scene = o3d.t.geometry.RaycastingScene()
                self._scene.add_triangles(o3d.core.Tensor(self.vertices.astype(np.float32)),
                                          o3d.core.Tensor(self.faces.astype(np.uint32)))
                self.backend = "open3d"
                return
        self.backend = "numpy"
        tri = self.vertices[self.faces]
        self._fine = _Pieces(tri, max_edge)
        self._coarse = _Pieces(tri, 8 * max_edge)
        self.k = int(k)

    def upper_bound(self, points: np.ndarray) -> np.ndarray:
        """(n,) float: an upper bound of each point's distance to the mesh, cheaper than `query`
        with the numpy backend (the distance to the nearest piece centroid)."""
        if self._scene is not None:
            return self.query(points)[0]
        return self._fine.tree.query(np.asarray(points, dtype=np.float64).reshape(-1, 3), k=1)[0]

    def query(self, points: np.ndarray, chunk: int = 8192
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points of the mesh to ``points`` (n, 3).

        Returns
        -------
        distance : (n,) float
        face_index : (n,) int
            Triangle of the closest point.
        closest : (n, 3) float
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(points)
        if n == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        if self._scene is not None:
            r = self._scene.compute_closest_points(self._o3d.core.Tensor(points.astype(np.float32)), nthreads=1)
            closest = r["points"].numpy().astype(np.float64)
            return (np.linalg.norm(closest - points, axis=1), r["primitive_ids"].numpy().astype(np.int64),
                    closest)
        dist, face, closest = np.empty(n), np.empty(n, dtype=np.int64), np.empty((n, 3))
        for s in range(0, n, chunk):
            p = points[s:s + chunk]
            d, f, c, exact = self._fine.nearest_k(p, self.k)
            redo = np.nonzero(~exact & (d <= EXACT_WITHIN))[0]
            if len(redo):   # farther from the surface: four times the pieces, then all in reach
                d[redo], f[redo], c[redo], exact = self._fine.nearest_k(p[redo], 4 * self.k)
                redo = redo[~exact]
            if len(redo):
                d[redo], f[redo], c[redo] = self._coarse.within(p[redo], d[redo])
            dist[s:s + len(p)], face[s:s + len(p)], closest[s:s + len(p)] = d, f, c
        return dist, face, closest


# --------------------------------------------------------------------------------------------------
# ground truth


def exterior_faces(vertices: np.ndarray, faces: np.ndarray, n_rays: int = 128) -> np.ndarray:
    """Which triangles a ray from outside reaches: the mesh's outer surface.

    From each triangle's centroid (10 micrometres off it, outward), rays go along ``n_rays``
    directions spread evenly over the sphere (a Fibonacci lattice), those more than 5 degrees
    above the triangle's plane on its outer side; a triangle is outer when one of them leaves
    the mesh without a hit (Embree). A pocket no ray leaves (a mouth behind closed lips) and
    surface pressed into other surface are not.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Outward winding.
    n_rays : int
        Directions tried per triangle (0: every triangle is outer).

    Returns
    -------
    outer : (F,) bool
    """
    outer = np.ones(len(faces), dtype=bool)
    if n_rays <= 0 or len(faces) == 0:
        return outer
    from bodyscan.simulator.raycast import RayCaster

    normal, area = face_normals(vertices, faces)
    outer = ~(area > 0)          # degenerate triangles: no outward side to test, kept
    centre = vertices[faces].mean(axis=1) + 1e-5 * normal
    k = np.arange(n_rays) + 0.5
    z = 1 - 2 * k / n_rays
    phi = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.column_stack([np.sqrt(1 - z ** 2) * np.cos(phi), np.sqrt(1 - z ** 2) * np.sin(phi), z])
    caster = RayCaster(vertices, faces)
    for d in dirs:
        todo = np.flatnonzero(~outer & (normal @ d > np.sin(np.radians(5))))
        if len(todo):
            outer[todo[~caster.occluded(centre[todo], d[None])]] = True
    return outer


@dataclass(eq=False)
class GroundTruth:
    """A ground-truth body prepared for scoring (built once per body and reused for every mesh).

    Attributes
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Watertight, outward winding.
    face_section : (F,) int
        Ground-truth section of each triangle (index into `SECTIONS`).
    joints : dict of str to (3,) float
    index : SurfaceIndex
    samples : (m, 3) float
        Area-uniform samples of the true outer surface (`exterior_faces`).
    sample_faces : (m,) int
    params : MetricParams
    exterior : (F,) bool
        The triangles of the outer surface.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_section: np.ndarray
    joints: dict
    index: SurfaceIndex
    samples: np.ndarray
    sample_faces: np.ndarray
    params: MetricParams
    exterior: np.ndarray = None
    name: str = ""
    _mesh: object = field(default=None, repr=False)

    @classmethod
    def from_body(cls, body, params: MetricParams | None = None) -> "GroundTruth":
        """Prepare a `poses.Body` (which must carry ground truth)."""
        body.require_ground_truth("scoring")
        return cls.from_arrays(body.vertices, body.faces, body.face_section(), body.joint_dict(),
                               params, name=body.name)

    @classmethod
    def from_arrays(cls, vertices, faces, face_section=None, joints=None,
                    params: MetricParams | None = None, name: str = "") -> "GroundTruth":
        """Prepare a watertight, outward-wound mesh (V, 3), (F, 3) with optional (F,) sections
        and joints {name: (3,)}."""
        params = params or MetricParams()
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        sec = np.zeros(len(f), np.int64) if face_section is None else np.asarray(face_section, np.int64)
        outer = exterior_faces(v, f, params.exterior_rays)
        samples, sfid = sample_surface(v, f[outer], params.n_samples, params.seed + 1)
        return cls(vertices=v, faces=f, face_section=sec, joints=dict(joints or {}),
                   index=SurfaceIndex(v, f, backend=params.backend), samples=samples,
                   sample_faces=np.flatnonzero(outer)[sfid], params=params, exterior=outer, name=name)

    @property
    def mesh(self):
        """The true mesh as a `trimesh.Trimesh` (for inside tests, by Embree ray parity)."""
        if self._mesh is None:
            import trimesh
            self._mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        return self._mesh

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points inside the true body."""
        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        return np.asarray(self.mesh.contains(points), dtype=bool)

    def seen(self, scan_points: np.ndarray) -> np.ndarray:
        """(m,) bool: which true samples lie within ``seen_radius_m`` of a scan point."""
        if scan_points is None or len(scan_points) == 0:
            return np.zeros(len(self.samples), dtype=bool)
        d, _ = cKDTree(scan_points).query(self.samples, distance_upper_bound=self.params.seen_radius_m)
        return np.isfinite(d)


# --------------------------------------------------------------------------------------------------
# the metrics


def corner_true_faces(vertices: np.ndarray, faces: np.ndarray, truth: GroundTruth, *, scan_points=None,
                      scan_gt_face=None, point_index=None, tol_m: float = 1e-6,
                      inset: float = 1e-3) -> np.ndarray:
    """The ground-truth triangle each corner of each mesh triangle came from.

    A vertex that is a scan point takes the point's ``gt_face``. Any other vertex takes the
    triangle of the nearest point of the true surface, found from the corner moved by ``inset``
    of the way towards its triangle's centroid (but at least 10 micrometres, above float32
    rounding, and at most a quarter of the way): this settles ties where a vertex sits on an edge
    shared by true triangles of different normals (the true mesh scored against itself), and
    moves the query by 0.1 mm for a 10 cm triangle.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    truth : GroundTruth
    scan_points : (n, 3) float, optional
    scan_gt_face : (n,) int, optional
    point_index : (V,) int, optional
        Scan point of each vertex (-1: none). Without it, vertices within ``tol_m`` of a scan
        point are matched to it.
    tol_m : float
    inset : float

    Returns
    -------
    gt_face : (F, 3) int
    """
    V = len(vertices)
    vface = np.full(V, -1, dtype=np.int64)
    if scan_points is not None and scan_gt_face is not None and len(scan_points):
        if point_index is None:
            d, i = cKDTree(scan_points).query(vertices, distance_upper_bound=tol_m)
            point_index = np.where(np.isfinite(d), i, -1)
        point_index = np.asarray(point_index, dtype=np.int64)
        if point_index.shape != (V,):
            raise BenchError(f"point_index must have one entry per vertex ({V}), got {point_index.shape}")
        ok = point_index >= 0
        vface[ok] = np.asarray(scan_gt_face, dtype=np.int64)[point_index[ok]]
    out = vface[faces]
    rest = out < 0
    if rest.any():
        tri = vertices[faces]
        d = tri.mean(axis=1, keepdims=True) - tri
        length = np.linalg.norm(d, axis=2, keepdims=True)
        # at least 10 micrometres (above float32 rounding), at most a quarter of the way
        step = np.minimum(np.maximum(inset * length, 1e-5), 0.25 * length)
        corner = tri + d * np.divide(step, length, out=np.zeros_like(length), where=length > 0)
        out[rest] = truth.index.query(corner[rest])[1]
    return out


def spurious(vertices, faces, true_faces, truth: GroundTruth, params: MetricParams) -> dict:
    """The paper's test (section 4.2): triangles whose normal disagrees with the true one.

    The true normal of a triangle is the (normalised) mean of the normals of the true triangles
    its three vertices came from (``true_faces``, (F, 3), see `corner_true_faces`). Degenerate triangles are never spurious.

    Returns
    -------
    dict with ``spurious_count``, ``spurious_area_fraction`` (oriented or not, per ``params``),
    ``spurious_area_fraction_unoriented`` (flips forgiven) and the per-face mask ``_spurious``.
    """
    n, area = face_normals(vertices, faces)
    tn = truth.index.normals[true_faces].sum(axis=1)
    tl = np.linalg.norm(tn, axis=1)
    tn = np.divide(tn, tl[:, None], out=np.zeros_like(tn), where=tl[:, None] > 0)
    cos = np.einsum("ij,ij->i", n, tn)
    lim = np.cos(np.radians(params.spurious_angle_deg))
    valid = area > 0
    bad_oriented = valid & (cos < lim)
    bad_lines = valid & (np.abs(cos) < lim)
    bad = bad_oriented if params.oriented else bad_lines
    total = area.sum()
    frac = (lambda m: float(area[m].sum() / total) if total > 0 else float("nan"))
    return {"spurious_count": int(bad.sum()), "spurious_area_fraction": frac(bad),
            "spurious_area_fraction_unoriented": frac(bad_lines), "_spurious": bad}


def bridging(vertices, faces, true_faces, truth: GroundTruth, params: MetricParams) -> dict:
    """Surface in the air: triangles whose centroid is outside the true body and farther than
    ``bridging_distance_m`` from its surface (armpit and crotch fills, measured directly).

    Each such triangle is attributed to the sections of the true triangles its vertices came from
    (``true_faces``): the key is the sorted, distinct section names joined by ``+``
    (``"chest+upper_arm_l"``; a single name for a flap on one section).

    Returns
    -------
    dict with ``bridging_area_fraction``, ``bridging_area_cm2``, ``bridging_pairs`` (JSON text of
    ``{key: area in cm^2}``, largest first) and the per-face mask ``_bridging``.
    """
    _, area = face_normals(vertices, faces)
    cent = vertices[faces].mean(axis=1)
    far = np.nonzero(truth.index.upper_bound(cent) > params.bridging_distance_m)[0]
    far = far[truth.index.query(cent[far])[0] > params.bridging_distance_m]
    air = np.zeros(len(faces), dtype=bool)
    air[far] = ~truth.contains(cent[far])
    pairs: dict[str, float] = {}
    if air.any():
        sec = np.sort(truth.face_section[true_faces[air]], axis=1)
        for row, a in zip(sec, area[air]):  # loop over bridging triangles only (few)
            key = "+".join(SECTIONS[s] for s in dict.fromkeys(row.tolist()))
            pairs[key] = pairs.get(key, 0.0) + float(a) * 1e4
    total = area.sum()
    pairs = {k: round(v, 3) for k, v in sorted(pairs.items(), key=lambda kv: -kv[1])}
    return {"bridging_area_fraction": float(area[air].sum() / total) if total > 0 else float("nan"),
            "bridging_area_cm2": float(area[air].sum() * 1e4),
            "bridging_pairs": json.dumps(pairs), "_bridging": air}


def accuracy_completeness(vertices, faces, truth: GroundTruth, params: MetricParams,
                          seen: np.ndarray | None = None) -> dict:
    """Precision, recall, F-score, Chamfer-L1 and normal consistency.

    ``n_samples`` area-uniform samples are drawn on the mesh and on the true surface; each sample's
    exact distance to the other surface is computed.

    - ``precision@T``: fraction of mesh samples within T of the true surface;
    - ``recall_full@T``: fraction of true samples (the outer surface, `exterior_faces`) within T
      of the mesh;
    - ``recall_seen@T``: the same over true samples the scanner saw (``seen``, see
      `GroundTruth.seen`), i.e. what a method could have recovered from the points;
    - ``recall_unseen@T``: the same over the true samples the scanner did not see (what a method
      completed);
    - ``fscore_full@T``, ``fscore_seen@T``: harmonic means of precision and the recall;
    - ``chamfer_l1_mm``: ``(mean d(mesh -> true) + mean d(true -> mesh)) / 2``, in millimetres
      (the mean of the two directions' mean distances, not their sum, and not squared);
    - ``normal_consistency``: mean ``|cos|`` between the normal of a sample's triangle and the
      normal of the closest triangle of the other surface, averaged over both directions (the
      Occupancy Networks convention: orientation is ignored, see spurious for oriented normals).
    """
    out: dict = {}
    taus = params.taus_m
    seen = np.ones(len(truth.samples), dtype=bool) if seen is None else seen
    _, area = face_normals(vertices, faces)
    if len(faces) == 0 or not area.sum() > 0:
        for t in taus:
            lab = tau_label(t)
            out.update({f"precision@{lab}": float("nan"), f"recall_full@{lab}": 0.0,
                        f"recall_seen@{lab}": 0.0, f"recall_unseen@{lab}": 0.0,
                        f"fscore_full@{lab}": 0.0, f"fscore_seen@{lab}": 0.0})
        out.update(chamfer_l1_mm=float("nan"), normal_consistency=float("nan"))
        return out
    mine = SurfaceIndex(vertices, faces, backend=truth.index.backend)
    pts, pfid = sample_surface(vertices, faces, params.n_samples, params.seed + 2)
    d_p, f_p, _ = truth.index.query(pts)                  # mesh -> truth
    d_r, f_r, _ = mine.query(truth.samples)               # truth -> mesh
    for t in taus:
        lab = tau_label(t)
        p = float(np.mean(d_p < t))
        r_full = float(np.mean(d_r < t))
        r_seen = float(np.mean(d_r[seen] < t)) if seen.any() else float("nan")
        r_unseen = float(np.mean(d_r[~seen] < t)) if (~seen).any() else float("nan")
        f = (lambda r: 2 * p * r / (p + r) if p + r > 0 else 0.0)
        out.update({f"precision@{lab}": p, f"recall_full@{lab}": r_full, f"recall_seen@{lab}": r_seen,
                    f"recall_unseen@{lab}": r_unseen,
                    f"fscore_full@{lab}": f(r_full), f"fscore_seen@{lab}": f(r_seen)})
    out["chamfer_l1_mm"] = float(0.5 * (d_p.mean() + d_r.mean()) * 1000.0)
    nc_p = np.abs(np.einsum("ij,ij->i", mine.normals[pfid], truth.index.normals[f_p])).mean()
    nc_r = np.abs(np.einsum("ij,ij->i", truth.index.normals[truth.sample_faces], mine.normals[f_r])).mean()
    out["normal_consistency"] = float(0.5 * (nc_p + nc_r))
    out["seen_fraction"] = float(seen.mean())
    return out


def section_accuracy(point_sections: np.ndarray, gt_section: np.ndarray) -> dict:
    """How well the scan points were labelled with body sections.

    A point with one label scores 1 when it is right; a point with m labels scores 1/m when the
    truth is among them (the chance of being right if one of its labels were picked at random);
    an unlabelled point scores 0. ``section_accuracy`` is the mean score;
    ``section_accuracy_any`` counts a point right whenever the truth is among its labels;
    ``multi_label_fraction`` and ``unlabelled_fraction`` say how often each case happens.

    Points whose true section is unknown (``gt_section < 0``) are left out.

    Parameters
    ----------
    point_sections : (n, 11) bool
    gt_section : (n,) int
    """
    ps = np.asarray(point_sections, dtype=bool)
    gt = np.asarray(gt_section, dtype=np.int64)
    if ps.ndim != 2 or ps.shape[0] != len(gt) or ps.shape[1] != len(SECTIONS):
        raise BenchError(f"point_sections must be ({len(gt)}, {len(SECTIONS)}) bool, got {ps.shape}")
    known = gt >= 0
    ps, gt = ps[known], gt[known]
    if len(gt) == 0:
        return {"section_accuracy": float("nan"), "section_accuracy_any": float("nan"),
                "multi_label_fraction": float("nan"), "unlabelled_fraction": float("nan")}
    m = ps.sum(axis=1)
    hit = ps[np.arange(len(gt)), gt]
    score = np.where(hit, 1.0 / np.maximum(m, 1), 0.0)
    return {"section_accuracy": float(score.mean()), "section_accuracy_any": float(hit.mean()),
            "multi_label_fraction": float(np.mean(m > 1)), "unlabelled_fraction": float(np.mean(m == 0))}


def joint_errors(joints: dict, true_joints: dict) -> dict:
    """Posture error: distances (metres) between estimated and true joints of the same name.

    Returns ``joint_error_median_m``, ``joint_error_max_m`` (NaN when no names are shared) and
    ``joint_error_worst`` (the name of the worst joint).
    """
    names = [k for k in true_joints if k in joints]
    if not names:
        return {"joint_error_median_m": float("nan"), "joint_error_max_m": float("nan"),
                "joint_error_worst": ""}
    err = np.array([np.linalg.norm(np.asarray(joints[k], float) - np.asarray(true_joints[k], float))
                    for k in names])
    return {"joint_error_median_m": float(np.median(err)), "joint_error_max_m": float(err.max()),
            "joint_error_worst": names[int(err.argmax())]}


def head_misregistration(rotation, translation, at) -> dict:
    """The largest rigid offset between two scanner heads, for heads whose points were moved
    ``p -> rotation[h] @ p + translation[h]`` (h heads; a misalignment, after a correction or not).

    Only the heads' relative motion counts: moving every head alike moves the whole body, which no
    scan can see.

    Parameters
    ----------
    rotation : (h, 3, 3) float
    translation : (h, 3) float, metres
    at : (3,) float
        Where the translations are measured (the body's centre), metres.

    Returns
    -------
    dict
        ``deg``: the largest rotation angle between two heads, degrees; ``mm``: the largest
        distance between the positions two heads give the point ``at``, millimetres (NaN for
        fewer than two heads).
    """
    r = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    where = r @ np.asarray(at, dtype=float) + np.asarray(translation, dtype=float).reshape(-1, 3)
    if len(r) < 2:
        return {"deg": float("nan"), "mm": float("nan")}
    a, b = np.triu_indices(len(r), k=1)
    cos = (np.einsum("pij,pij->p", r[a], r[b]) - 1) / 2   # trace(Ra^T Rb)
    return {"deg": float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max()),
            "mm": float(1000 * np.linalg.norm(where[b] - where[a], axis=1).max())}


def is_watertight(faces) -> bool:
    """Whether the mesh ``faces`` (F, 3) is closed and consistently wound: every edge is used by
    exactly two faces, once in each direction (an edge-manifold without boundary)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return False
    a = f.ravel()
    b = f[:, [1, 2, 0]].ravel()
    n = int(f.max()) + 1
    directed = np.unique(a * n + b, return_counts=True)[1]
    undirected = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)[1]
    return bool((directed == 1).all() and (undirected == 2).all())


def score_mesh(vertices, faces, truth: GroundTruth, *, scan_points=None, scan_gt_face=None,
               scan_gt_section=None, point_index=None, point_sections=None, joints=None,
               seen: np.ndarray | None = None, keep_masks: bool = False) -> dict:
    """All metrics of one mesh against a prepared ground truth, as one flat dict.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    truth : GroundTruth
    scan_points, scan_gt_face, scan_gt_section : arrays of the scan, optional
        ``(n, 3)``, ``(n,)``, ``(n,)``; the points give recall_seen and let vertices that are scan
        points use their exact ``gt_face``.
    point_index : (V,) int, optional
        Scan point of each vertex, -1 for none (default: matched by position).
    point_sections : (n, 11) bool, optional
        The method's section labels of the scan points (section accuracy).
    joints : dict of str to (3,), optional
        The method's joint estimates (posture error).
    seen : (m,) bool, optional
        Precomputed ``truth.seen(scan_points)``.
    keep_masks : bool
        Also return the per-face masks ``_spurious`` and ``_bridging`` and the per-face true
        section ``_true_section`` (for pictures).
    """
    from bodyscan._resources import require_memory

    params = truth.params
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    require_memory(2 * params.n_samples * BYTES_PER_SAMPLE + len(faces) * BYTES_PER_FACE + QUERY_BYTES,
                   f"scoring {len(faces):,} triangles with {params.n_samples:,} samples per surface",
                   "lower --metric n_samples or simplify the mesh", error=BenchError)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise BenchError(f"mesh vertices must be (V, 3), got {vertices.shape}")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise BenchError("mesh faces index vertices that do not exist")
    if not np.isfinite(vertices).all():
        raise BenchError("mesh vertices hold NaN or infinite values")
    _, area = face_normals(vertices, faces)
    row: dict = {"n_vertices": int(len(vertices)), "n_faces": int(len(faces)),
                 "mesh_area_m2": float(area.sum()), "watertight": is_watertight(faces)}
    if len(faces):
        tf = corner_true_faces(vertices, faces, truth, scan_points=scan_points, scan_gt_face=scan_gt_face,
                               point_index=point_index)
        row.update(spurious(vertices, faces, tf, truth, params))
        row.update(bridging(vertices, faces, tf, truth, params))
        sec = truth.face_section[tf]   # majority of the corners' true sections (for pictures)
        row["_true_section"] = np.where(sec[:, 1] == sec[:, 2], sec[:, 1], sec[:, 0])
    else:
        row.update(spurious_count=0, spurious_area_fraction=float("nan"),
                   spurious_area_fraction_unoriented=float("nan"), bridging_area_fraction=float("nan"),
                   bridging_area_cm2=0.0, bridging_pairs="{}",
                   _spurious=np.zeros(0, bool), _bridging=np.zeros(0, bool),
                   _true_section=np.zeros(0, np.int64))
    if seen is None and scan_points is not None:
        seen = truth.seen(scan_points)
    row.update(accuracy_completeness(vertices, faces, truth, params, seen))
    if point_sections is not None and scan_gt_section is not None:
        row.update(section_accuracy(point_sections, scan_gt_section))
    else:
        row.update(section_accuracy=float("nan"))
    if joints:
        row.update(joint_errors(joints, truth.joints))
    else:
        row.update(joint_error_median_m=float("nan"), joint_error_max_m=float("nan"))
    if not keep_masks:
        row = {k: v for k, v in row.items() if not k.startswith("_")}
    return row


def metric_names(params: MetricParams | None = None) -> list[str]:
    """The headline metric columns, in table order."""
    params = params or MetricParams()
    names = ["spurious_area_fraction", "spurious_count", "bridging_area_fraction"]
    for t in params.taus_m:
        lab = tau_label(t)
        names += [f"precision@{lab}", f"recall_full@{lab}", f"recall_seen@{lab}",
                  f"recall_unseen@{lab}", f"fscore_seen@{lab}", f"fscore_full@{lab}"]
    return names + ["chamfer_l1_mm", "normal_consistency", "section_accuracy",
                    "joint_error_median_m", "joint_error_max_m"]


#: The headline metric columns with the default settings.
METRIC_NAMES = tuple(metric_names())
