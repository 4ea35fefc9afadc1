"""A method of a user's own, outside the package (issue 18): each camera's points triangulated
in its image plane (2D Delaunay), triangles with an edge over ``max_edge`` dropped, each turned
to face its camera. The classic range-image mesh, as a user would write it in twenty lines.

Run as a script it is the same method as an external command: ``python tiny_method.py CLOUD OUT
[MAX_EDGE]`` reads the benchmark's PLY of points and writes a PLY mesh.
"""

import sys

import numpy as np
from scipy.spatial import Delaunay


def reconstruct(points, view_dir, head, *, max_edge=0.03):
    faces = []
    for h in np.unique(head):
        idx = np.flatnonzero(head == h)
        if len(idx) < 3:
            continue
        d = view_dir[idx].mean(axis=0)
        d /= np.linalg.norm(d)
        u = np.cross(d, [0.0, 0.0, 1.0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        tri = idx[Delaunay(np.c_[points[idx] @ u, points[idx] @ w]).simplices]
        t = points[tri]
        edges = np.linalg.norm(t - np.roll(t, 1, axis=1), axis=2).max(axis=1)
        tri = tri[edges <= max_edge]
        n = np.cross(points[tri[:, 1]] - points[tri[:, 0]], points[tri[:, 2]] - points[tri[:, 0]])
        away = np.einsum("ij,j->i", n, d) < 0
        tri[away] = tri[away][:, ::-1]
        faces.append(tri)
    faces = np.vstack(faces) if faces else np.zeros((0, 3), np.int64)
    return points, faces, {"point_index": np.arange(len(points))}


if __name__ == "__main__":
    import trimesh

    cloud, out = sys.argv[1], sys.argv[2]
    ply = trimesh.load(cloud, process=False)
    data = ply.metadata["_ply_raw"]["vertex"]["data"]
    p = np.c_[data["x"], data["y"], data["z"]].astype(np.float64)
    vd = np.c_[data["vx"], data["vy"], data["vz"]].astype(np.float64)
    v, f, _ = reconstruct(p, vd, np.asarray(data["head"]), max_edge=float(sys.argv[3]) if len(sys.argv) > 3 else 0.03)
    trimesh.Trimesh(v, f, process=False).export(out)
