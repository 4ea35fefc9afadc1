"""Curved subdivision (recon.surface.curve) against analytic circles, spheres and cylinders."""

import numpy as np
import pytest
import trimesh

from bodyscan.recon.model import SectionShape
from bodyscan.recon.params import SurfaceParams
from bodyscan.recon.surface import curve as C
from bodyscan.recon.surface import mesh as S
from test_surface import front_rear_cylinder


@pytest.mark.parametrize("a", [0.1, 0.25, 0.4])
def test_midpoint_of_an_arc_lies_on_its_circle(a):
    # ends of an arc of angle 2a on a 5 cm circle, with the circle's normals: the chord's midpoint
    # is r (1 - cos a) inside; the curved one within 3/8 r a^4 (the second-order error)
    r = 0.05
    A = np.array([[r * np.sin(-a), r * np.cos(a), 0.0]])
    B = np.array([[r * np.sin(a), r * np.cos(a), 0.0]])
    mid, n = C.curved_midpoints(A, B, A / r, B / r)
    chord = r * (1 - np.cos(a))
    err = abs(r - np.linalg.norm(mid))
    assert err <= 0.375 * r * a ** 4 * 1.05
    assert err < chord / 8
    assert np.allclose(n, [[0, 1, 0]])
    # concave: normals turned inward, the midpoint moves the other way, onto the circle again
    mid_in, _ = C.curved_midpoints(A, B, -A / r, -B / r)
    assert np.allclose(mid_in, mid)


def test_sphere_subdivided_stays_closed_and_on_the_sphere():
    # a UV sphere's edges are long at the equator and short at the poles: with a limit between,
    # faces get split on 0-3 edges; neighbours must share every midpoint (no cracks)
    r = 0.1
    sphere = trimesh.creation.uv_sphere(radius=r, count=[12, 12])
    V, F = sphere.vertices, sphere.faces
    lengths = np.linalg.norm(V[F] - V[F][:, [1, 2, 0]], axis=2)
    limit = float(np.median(lengths))
    V2, F2, data = C.curved_subdivision(V, F, V / r, limit, face_data=np.arange(len(F)))
    assert np.array_equal(V2[:len(V)], V)                          # the input vertices first, kept
    out = trimesh.Trimesh(V2, F2, process=False)
    assert out.is_watertight and out.is_winding_consistent
    assert np.isclose(out.volume, sphere.volume, rtol=0.2) and out.volume > sphere.volume
    assert (np.linalg.norm(V2[F2] - V2[F2][:, [1, 2, 0]], axis=2) <= limit + 1e-12).all()
    flat_err = r - np.linalg.norm(V[F].mean(axis=1), axis=1).min()  # the flat mesh's worst centroid
    assert np.abs(np.linalg.norm(V2[len(V):], axis=1) - r).max() < flat_err / 4
    # each piece keeps the data of the face it came from: areas add up per face
    a0 = trimesh.Trimesh(V, F, process=False).area_faces
    a2 = np.bincount(data, out.area_faces, len(F))
    split = a2 > a0 * (1 + 1e-9)
    assert split.any() and np.allclose(a2[~split], a0[~split])


def test_short_edges_are_left_alone():
    V = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]], dtype=float)
    F = np.array([[0, 1, 2]])
    V2, F2, _ = C.curved_subdivision(V, F, np.tile([0, 0, 1.0], (3, 1)), 0.02)
    assert np.array_equal(V2, V) and np.array_equal(F2, F)
    with pytest.raises(ValueError, match="max_edge"):
        C.curved_subdivision(V, F, np.tile([0, 0, 1.0], (3, 1)), 0.0)


def test_flanks_of_a_scanned_cylinder_come_back_onto_it():
    # a 6 cm cylinder scanned from front and back on 12 mm columns: Delaunay's triangles over the
    # flanks, where the columns are far apart in 3D, are chords several mm inside; curved, every
    # face lies within 1 mm of the cylinder
    R = 0.06
    P, vd = front_rear_cylinder(R, np.arange(-0.054, 0.0541, 0.012), np.arange(0, 0.3, 0.01))
    shape = SectionShape("thigh_l", [0, 0, 0], [0, 0, 0.3], [R, R], [1, 0, 0], closed=(False, False))
    f = S.section_surface(P, shape, SurfaceParams(), view_dir=vd)
    c = P[f].mean(axis=1)
    inward = np.einsum("ij,ij->i", S.face_normals(P, f)[:, :2], c[:, :2]) < 0
    f[inward] = f[inward][:, ::-1]                                   # outward winding
    assert (R - np.hypot(c[:, 0], c[:, 1])).max() > 0.004           # the flat flanks: chords
    V, F, _ = C.curve_surface(P, f, 0.02, vd)
    w = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [2, 1, 1], [1, 2, 1], [1, 1, 2]]) / 1.0
    w /= w.sum(axis=1, keepdims=True)                                # corners, centroid, between
    samples = np.einsum("sj,kjd->ksd", w, V[F]).reshape(-1, 3)
    assert np.abs(np.hypot(samples[:, 0], samples[:, 1]) - R).max() < 0.001
    assert len(F) > len(f)


def test_curve_edge_below_a_spacing_is_refused():
    # every triangle would be split each round (4^8 times the faces): a usage error, not a hang
    from bodyscan.recon import ReconError, ReconParams

    with pytest.raises(ReconError, match="curve_edge=0.5: must be 0 .flat. or at least 1 spacing"):
        ReconParams.from_overrides({"curve_edge": "0.5"})
    assert ReconParams.from_overrides({"curve_edge": "0"}).surface.curve_edge == 0
