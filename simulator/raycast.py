"""The one Embree wrapper: a triangle mesh's ray-casting scene, built once and queried many times."""

from __future__ import annotations

import numpy as np


class RayCaster:
    """First-hit and occlusion queries against one triangle mesh, through embreex.

    The Embree scene is built once here; reuse the object for every head and laser angle.
    Embree works in float32: origins and directions are rounded to float32, and hit distances
    come back as float32 (about 1e-7 relative error).

    Parameters
    ----------
    vertices : (V, 3) float
        Mesh vertices, metres.
    faces : (F, 3) int
        Triangles.

    Attributes
    ----------
    n_rays : int
        Rays cast so far (all queries).
    log : list or None
        When a list, every query appends ``(query, origins, directions, max_distance)`` as the
        float32 arrays given to Embree (for benchmarks that replay the same rays).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        try:
            from embreex import mesh_construction, rtcore_scene
        except ImportError as exc:  # embreex is a core dependency; say so plainly
            raise ImportError("the simulator needs embreex (pip install embreex)") from exc
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self._scene, np.ascontiguousarray(vertices, dtype=np.float32),
            np.ascontiguousarray(faces, dtype=np.int32))
        self.n_faces = len(faces)
        self.n_rays = 0
        self.log: list | None = None

    def _prepare(self, origins, directions):
        o = np.ascontiguousarray(origins, dtype=np.float32).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        if len(d) not in (1, len(o)):
            raise ValueError(f"directions must be (1, 3) or (n, 3) with n = {len(o)}, got {d.shape}")
        return o, d

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest triangle along each ray.

        Parameters
        ----------
        origins : (n, 3) float
        directions : (n, 3) or (1, 3) float
            Unit vectors (a single row is shared by all rays).

        Returns
        -------
        face : (n,) int32
            Index of the first triangle hit, -1 for a miss (Embree's own array, not widened).
        distance : (n,) float32
            Distance along the ray to the hit (undefined where ``face == -1``).
        """
        o, d = self._prepare(origins, directions)
        self.n_rays += len(o)
        if self.log is not None:
            self.log.append(("first_hit", o, d, None))
        if len(o) == 0:
            return np.empty(0, np.int32), np.empty(0, np.float32)
        out = self._scene.run(o, d, output=1)
        return out["primID"], out["tfar"]

    def occluded(self, origins: np.ndarray, directions: np.ndarray,
                 max_distance: np.ndarray | float | None = None) -> np.ndarray:
        """Whether anything lies on each ray before ``max_distance``.

        Parameters
        ----------
        origins : (n, 3) float
        directions : (n, 3) or (1, 3) float
            Need not be unit vectors: distances count in lengths of ``directions``.
        max_distance : (n,) float, float or None
            Search up to this distance (None: unbounded); with unnormalised directions, 1.0 tests
            the segments from ``origins`` to ``origins + directions``.

        Returns
        -------
        blocked : (n,) bool
        """
        o, d = self._prepare(origins, directions)
        self.n_rays += len(o)
        if max_distance is None:
            tfar = None
        elif np.ndim(max_distance) == 0:
            tfar = float(max_distance)
        else:
            tfar = np.ascontiguousarray(max_distance, dtype=np.float32)
        if self.log is not None:
            self.log.append(("occluded", o, d, tfar))
        if len(o) == 0:
            return np.empty(0, bool)
        return self._scene.run(o, d, dists=tfar, query="OCCLUDED") != -1
