"""The cloud reader: xyz and viewing directions from PLY, text and PCD; never ground truth."""

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from bodyscan.recon import ReconError, read_cloud
from bodyscan.recon.cloud import Cloud

ROOT = Path(__file__).resolve().parents[1]


def _cylinder(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, 1.5, n)
    return np.column_stack([0.1 * np.cos(t), 0.1 * np.sin(t), z])


def _write_sim_ply(path, pts, *, ascii=False):
    """A PLY laid out like the simulator's: x y z double, head uchar, vx vy vz float, gt_* fields."""
    n = len(pts)
    props = [("x", "<f8", "double"), ("y", "<f8", "double"), ("z", "<f8", "double"),
             ("head", "u1", "uchar"), ("vx", "<f4", "float"), ("vy", "<f4", "float"),
             ("vz", "<f4", "float"), ("gt_face", "<i4", "int"), ("gt_section", "i1", "char"),
             ("gt_nx", "<f4", "float"), ("gt_ny", "<f4", "float"), ("gt_nz", "<f4", "float")]
    rec = np.zeros(n, dtype=[(a, b) for a, b, _ in props])
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["vy"] = -1.0
    rec["gt_face"] = np.arange(n)
    rec["gt_section"] = 3
    header = ["ply", f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
              'comment bodyscan config {"k": 1, "resolution": 0.01}',
              f"element vertex {n}"] + [f"property {t} {a}" for a, _, t in props] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        if ascii:
            np.savetxt(f, np.column_stack([rec[a] for a, _, _ in props]), fmt="%.9g")
        else:
            f.write(rec.tobytes())


@pytest.mark.parametrize("ascii", [False, True])
def test_simulator_ply_keeps_xyz_and_view_and_drops_ground_truth(tmp_path, ascii):
    pts = _cylinder()
    path = tmp_path / "scan.ply"
    _write_sim_ply(path, pts, ascii=ascii)
    cloud = read_cloud(path)
    assert isinstance(cloud, Cloud)
    np.testing.assert_allclose(cloud.points, pts, atol=1e-6)
    np.testing.assert_allclose(cloud.view_dir, np.tile([0, -1.0, 0], (len(pts), 1)))
    assert cloud.meta["config"] == {"k": 1, "resolution": 0.01}
    # nothing reachable from the object carries ground truth
    assert set(vars(cloud)) == {"points", "view_dir", "meta", "source", "head"}   # head: sensor data
    assert not any(k.startswith("gt_") for k in cloud.meta)


def test_text_and_pcd_and_mesh_ply(tmp_path):
    import trimesh

    pts = _cylinder(500)
    np.savetxt(tmp_path / "a.xyz", pts)
    np.testing.assert_allclose(read_cloud(tmp_path / "a.xyz").points, pts, atol=1e-9)
    np.savetxt(tmp_path / "b.txt", np.column_stack([pts, pts]), header="x y z nx ny nz")
    np.testing.assert_allclose(read_cloud(tmp_path / "b.txt").points, pts, atol=1e-9)
    np.savetxt(tmp_path / "h.csv", pts, delimiter=",", header="x,y,z", comments="")   # a bare header row
    np.testing.assert_allclose(read_cloud(tmp_path / "h.csv").points, pts, atol=1e-9)
    np.savetxt(tmp_path / "e.pts", pts, header=str(len(pts)), comments="")            # a .pts count row
    np.testing.assert_allclose(read_cloud(tmp_path / "e.pts").points, pts, atol=1e-9)
    with open(tmp_path / "c.pcd", "w") as f:
        f.write("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                f"WIDTH {len(pts)}\nHEIGHT 1\nPOINTS {len(pts)}\nDATA ascii\n")
        np.savetxt(f, pts)
    np.testing.assert_allclose(read_cloud(tmp_path / "c.pcd").points, pts, atol=1e-6)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    mesh.export(tmp_path / "d.ply")
    assert len(read_cloud(tmp_path / "d.ply").points) == len(mesh.vertices)


def test_nan_rows_are_dropped_with_a_warning(tmp_path):
    pts = _cylinder(1000)
    pts[::10] = np.nan
    np.savetxt(tmp_path / "n.xyz", pts)
    with pytest.warns(UserWarning, match="dropped 100 points"):
        cloud = read_cloud(tmp_path / "n.xyz")
    assert len(cloud.points) == 900 and np.isfinite(cloud.points).all()


@pytest.mark.parametrize("content, message", [
    (None, "only 50 points"), ("mm", "millimetres"), ("junk", "line 2 is not a row of numbers"),
    ("empty", "no points"), ("header", "no points"), ("word", "line 5 is not a row of numbers: '0 1 abc'"),
    ("short", "line 4 has 2 columns, the rows before it 3")])
def test_bad_clouds_give_one_line_errors(tmp_path, content, message):
    path = tmp_path / "bad.xyz"
    if content is None:
        np.savetxt(path, _cylinder(50))
    elif content == "mm":
        np.savetxt(path, _cylinder(1000) * 1000)
    elif content == "junk":
        path.write_text("hello world\nthis is not a cloud\n")
    elif content == "header":   # a column header and no rows
        path.write_text("x y z\n")
    elif content in ("word", "short"):   # the file's own line is named, comments and header counted
        path.write_text("# a scan\nx y z\n0 0 0\n" + ("1 0 0\n0 1 abc\n" if content == "word" else "0 1\n"))
    else:
        path.write_text("# nothing\n")
    with pytest.raises(ReconError, match=message) as err:
        read_cloud(path)
    assert "\n" not in str(err.value)


def test_missing_file_and_unknown_type(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_cloud(tmp_path / "nope.ply")
    (tmp_path / "x.obj2").write_text("1 2 3\n")
    with pytest.raises(ReconError, match="unknown cloud file type"):
        read_cloud(tmp_path / "x.obj2")
    # a body file given where a scan is wanted: the message says how to scan it
    (tmp_path / "body.npz").write_bytes(b"PK")
    with pytest.raises(ReconError, match="a body file is scanned first: bodyscan scan .*body.npz --out CLOUD.ply"):
        read_cloud(tmp_path / "body.npz")


def test_recon_never_names_ground_truth_fields():
    pattern = re.compile(r"gt_(face|section|normal)")
    offenders = [p.name for p in (ROOT / "recon").rglob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_reads_a_simulator_scan(tmp_path):
    from bodyscan import poses, simulator

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scan = simulator.scan(poses.load_body("standing"), simulator.preset("paper"))
    path = simulator.write_cloud(scan, tmp_path / "s.ply")
    cloud = read_cloud(path)
    np.testing.assert_allclose(cloud.points, scan.points, atol=1e-9)
    # each point's direction toward its camera and its head, as the scan recorded them
    np.testing.assert_allclose(cloud.view_dir, scan.view_dir, atol=1e-7)
    assert np.array_equal(cloud.head, scan.head) and set(np.unique(cloud.head)) == {0, 1}
