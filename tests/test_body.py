"""The body file format: loading, validation and one-line errors."""

import numpy as np
import pytest
import trimesh

from bodyscan.poses import REQUIRED_JOINTS, SECTIONS, Body, BodyError, load_body, save_body


def _box_body(scale=1.0):
    m = trimesh.creation.box(extents=[0.4, 0.3, 1.7])
    m.apply_translation([0, 0, 0.85])
    m.apply_scale(scale)
    v = np.asarray(m.vertices)
    return Body(name="box", vertices=v, faces=np.asarray(m.faces), vertex_section=np.zeros(len(v), np.int8),
                joint_names=REQUIRED_JOINTS, joints=np.zeros((len(REQUIRED_JOINTS), 3)) + [0, 0, 1])


def test_roundtrip(tmp_path):
    body = _box_body()
    path = save_body(body, tmp_path / "b.npz")
    back = load_body(path)
    np.testing.assert_allclose(back.vertices, body.vertices, atol=1e-6)
    np.testing.assert_array_equal(back.faces, body.faces)
    assert back.joint_names == REQUIRED_JOINTS
    assert back.has_ground_truth
    assert back.height == pytest.approx(1.7, abs=1e-6)


def test_plain_mesh_has_no_ground_truth(tmp_path):
    body = _box_body()
    path = tmp_path / "b.ply"
    body.to_trimesh().export(path)
    back = load_body(path)
    assert not back.has_ground_truth
    with pytest.raises(BodyError, match="no ground truth"):
        back.require_ground_truth("scoring")


@pytest.mark.parametrize("breakage, message", [
    (lambda d: d.pop("faces"), "lacks faces"),
    (lambda d: d.update(vertices=d["vertices"] * 1000), "metres"),
    (lambda d: d["vertices"].__setitem__((0, 0), np.nan), "NaN"),
    (lambda d: d.update(faces=d["faces"] + 10_000), "outside"),
    (lambda d: d.update(vertex_section=np.full(len(d["vertices"]), 11, np.int8)), "vertex_section"),
    (lambda d: d.update(joint_names=d["joint_names"][1:], joints=d["joints"][1:]), "joints missing"),
])
def test_malformed_files_give_one_line_errors(tmp_path, breakage, message):
    body = _box_body()
    d = dict(vertices=body.vertices, faces=body.faces, vertex_section=body.vertex_section,
             joint_names=np.array(body.joint_names), joints=body.joints)
    breakage(d)
    path = tmp_path / "bad.npz"
    np.savez(path, **d)
    with pytest.raises(BodyError, match=message) as err:
        load_body(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_garbage_and_unknown_names(tmp_path):
    path = tmp_path / "junk.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(BodyError, match="not a .npz body file"):
        load_body(path)
    with pytest.raises(BodyError, match="no such file"):
        load_body("no-such-body-anywhere")


def test_cli_reports_bad_body_in_one_line(tmp_path, capsys):
    from bodyscan.benchmarks.cli import main
    path = tmp_path / "junk.npz"
    path.write_bytes(b"not a zip")
    assert main(["scan", str(path), "--out", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "not a .npz body file" in err[-1] and "Traceback" not in "".join(err)
    assert not (tmp_path / "c.ply").exists()


def test_face_section_majority():
    body = _box_body()
    sec = body.vertex_section.copy()
    sec[body.faces[0, 1:]] = 3
    b2 = Body(name="x", vertices=body.vertices, faces=body.faces, vertex_section=sec,
              joint_names=body.joint_names, joints=body.joints)
    assert b2.face_section()[0] == 3
    assert len(SECTIONS) == 11
