"""Peer reconstructors on an analytic sphere: normals, surfaces, and clear errors."""

import numpy as np
import pytest
import trimesh

from bodyscan.benchmarks import BenchError
from bodyscan.benchmarks import peers
from bodyscan.benchmarks.metrics import GroundTruth, MetricParams, score_mesh

R = 0.3


@pytest.fixture(scope="module")
def sphere_cloud():
    """Points on a sphere of radius 0.3 m (about 8 mm apart), seen from outside (radial view)."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=R)
    rng = np.random.default_rng(0)
    p = m.vertices + rng.normal(scale=1e-4, size=m.vertices.shape)
    truth = GroundTruth.from_arrays(m.vertices, m.faces, params=MetricParams(n_samples=10_000))
    return p, p / np.linalg.norm(p, axis=1, keepdims=True), truth


def test_pca_normals_are_radial_and_face_the_sensor(sphere_cloud):
    p, view, _ = sphere_cloud
    n = peers.estimate_normals(p, view, k=12)
    radial = p / np.linalg.norm(p, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", n, radial)
    assert cos.min() > 0.99
    # seen from inside (a sensor at the centre), every normal flips
    assert np.einsum("ij,ij->i", peers.estimate_normals(p, -view, k=12), radial).max() < -0.99
    # without a sensor direction: away from the vertical axis through the centroid
    assert np.mean(np.einsum("ij,ij->i", peers.estimate_normals(p, None, k=12), radial) > 0.99) > 0.95


@pytest.fixture(scope="module")
def small_sphere_cloud():
    """A coarse sphere (162 points, 5 cm radius): thinner than 5 point spacings, as alpha needs."""
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    p = np.asarray(m.vertices)
    truth = GroundTruth.from_arrays(m.vertices, m.faces, params=MetricParams(n_samples=10_000))
    return p, p / np.linalg.norm(p, axis=1, keepdims=True), truth


def needs_installed(method):
    """Skip when the peer's package is not installed at all (the peers extra); installed, it must
    import (`available_peers` leaves out a package that is installed but broken: a missing libusb
    for Open3D, say), and the test goes on to use it."""
    import importlib.util

    if importlib.util.find_spec(peers.PEERS[method]) is None:
        pytest.skip(f"{peers.PEERS[method]} is not installed (the peers extra)")
    assert method in peers.available_peers(), peers.unavailable_peers()[method]


@pytest.mark.parametrize("method", list(peers.PEERS))
def test_peer_reconstructs_a_sphere(sphere_cloud, small_sphere_cloud, method):
    needs_installed(method)
    # an alpha shape keeps tetrahedra smaller than alpha: a wide shell gives nothing
    p, view, truth = small_sphere_cloud if method == "alpha" else sphere_cloud
    v, f, times = peers.reconstruct_peer(method, p, view)
    assert v.shape[1] == 3 and f.shape[1] == 3 and len(f) > 100
    assert set(times) == {"normals", "surface", "total"} and times["total"] >= times["surface"]
    row = score_mesh(v, f, truth)
    assert row["precision@10mm"] > 0.95, row
    assert row["recall_full@10mm"] > 0.9, row
    assert row["bridging_area_fraction"] < 0.02, row
    # outward winding: (almost) no triangle points into the sphere
    assert row["spurious_area_fraction"] < 0.05, row


def test_trimmed_poisson_has_fewer_vertices(sphere_cloud):
    needs_installed("poisson-trimmed")
    p, view, _ = sphere_cloud
    full = peers.reconstruct_peer("poisson", p, view)[0]
    trimmed = peers.reconstruct_peer("poisson-trimmed", p, view)[0]
    assert len(trimmed) < len(full)
    assert len(trimmed) == pytest.approx(0.95 * len(full), rel=0.03)


def test_errors_are_clear(sphere_cloud, monkeypatch):
    p, view, _ = sphere_cloud
    with pytest.raises(BenchError, match="unknown peer method"):
        peers.reconstruct_peer("marching", p, view)
    with pytest.raises(BenchError, match=r"\(n, 3\)"):
        peers.reconstruct_peer("bpa", p[:, :2], view)
    monkeypatch.setitem(peers.PEERS, "bpa", "no_such_package_xyz")
    with pytest.raises(BenchError, match=r"pip install 'bodyscan\[peers\]'"):
        peers.reconstruct_peer("bpa", p, view)
    assert "bpa" not in peers.available_peers()
