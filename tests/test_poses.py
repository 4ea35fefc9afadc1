"""The shipped pose library, its generator, checks, pictures and CLI."""

import builtins
import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from bodyscan.poses import REQUIRED_JOINTS, SECTIONS, Body, BodyError, list_bodies, load_body
from bodyscan.poses.checks import ADJACENT, gaps, interpenetration

BODIES = list_bodies()
#: Bodies in an upright standing posture (arms down, facing -y).
STANDING = [n for n in BODIES if n == "standing" or n.endswith("_standing")]


@pytest.fixture(scope="module", params=BODIES)
def body(request):
    return load_body(request.param)


def _edges(faces):
    """(3F, 2) directed edges of the faces."""
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def _components(n, edges):
    g = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)


def test_library_is_complete_and_small():
    from bodyscan.poses.library import DATA_DIR
    male = {"standing", "arms_close", "a_pose", "t_pose", "arms_raised", "arms_forward", "arm_across",
            "hands_on_hips", "walking", "squat", "seated", "leaning", "knee_raised"}
    assert male <= set(BODIES)
    for shape in ("woman", "child", "heavy", "tall"):
        assert len([n for n in BODIES if n.startswith(shape + "_")]) >= 2, shape
    total = sum(p.stat().st_size for p in DATA_DIR.glob("*.npz"))
    assert total < 8e6, f"the shipped library is {total / 1e6:.1f} MB"


def test_closed_outward_single_component(body):
    f = body.faces
    e = _edges(f)
    # closed and consistently wound: every directed edge appears once and its reverse once
    key = e[:, 0] * len(body.vertices) + e[:, 1]
    rkey = e[:, 1] * len(body.vertices) + e[:, 0]
    assert len(np.unique(key)) == len(key), "an edge is used twice in the same direction"
    assert np.isin(rkey, key).all(), "an edge has no opposite half: the mesh is open"
    n, _ = _components(len(body.vertices), e)
    assert n == 1
    # outward: the signed volume (divergence theorem) is positive and plausible for a person
    v = body.vertices[f]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
    assert 0.015 < volume < 0.2, volume
    assert body.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert 1.2 < body.height < 2.3


def test_sections_in_range_and_each_one_patch(body):
    s = body.vertex_section
    assert s.dtype == np.int8 and s.min() >= 0 and s.max() < len(SECTIONS)
    assert set(np.unique(s)) == set(range(len(SECTIONS))), "every section has vertices"
    e = _edges(body.faces)
    for k, name in enumerate(SECTIONS):
        inside = (s[e[:, 0]] == k) & (s[e[:, 1]] == k)
        _, lab = _components(len(s), e[inside])
        assert len(np.unique(lab[s == k])) == 1, f"{name} is split into several patches"


def test_sections_touch_only_their_neighbours(body):
    s = body.vertex_section
    e = _edges(body.faces)
    pairs = {frozenset((SECTIONS[a], SECTIONS[b])) for a, b in np.unique(s[e], axis=0) if a != b}
    assert pairs == set(ADJACENT)


def test_joints_inside_or_near_the_body(body):
    assert set(REQUIRED_JOINTS) <= set(body.joint_names)
    mesh = body.to_trimesh()
    inside = mesh.contains(body.joints)
    import trimesh
    _, dist, _ = trimesh.proximity.closest_point(mesh, body.joints)
    ok = inside | (dist < 0.03)
    assert ok.all(), [n for n, k in zip(body.joint_names, ok) if not k]


def test_joints_lie_in_their_sections(body):
    # each limb joint is nearest to vertices of one of the two sections it joins
    from scipy.spatial import cKDTree
    tree = cKDTree(body.vertices)
    expect = {"elbow": ("upper_arm", "forearm"), "knee": ("thigh", "lower_leg"),
              "wrist": ("forearm",), "ankle": ("lower_leg",)}
    for joint, secs in expect.items():
        for side in "lr":
            _, idx = tree.query(body.joint(f"{joint}_{side}"), k=10)
            names = {SECTIONS[k] for k in body.vertex_section[idx]}
            assert names <= {f"{s}_{side}" for s in secs}, (joint, side, names)


@pytest.mark.parametrize("name", STANDING)
def test_standing_left_is_plus_x_and_head_highest(name):
    b = load_body(name)
    s, v = b.vertex_section, b.vertices
    for left, right in [("upper_arm_l", "upper_arm_r"), ("forearm_l", "forearm_r"),
                        ("thigh_l", "thigh_r"), ("lower_leg_l", "lower_leg_r")]:
        assert (v[s == SECTIONS.index(left), 0] > 0).mean() > 0.99, left
        assert (v[s == SECTIONS.index(right), 0] < 0).mean() > 0.99, right
    assert b.joint("shoulder_l")[0] > 0 > b.joint("shoulder_r")[0]
    assert s[np.argmax(v[:, 2])] == SECTIONS.index("head")
    assert v[s == 0, 2].min() > v[s != 0, 2].mean()
    # upright: the head joint above the pelvis above the knees above the ankles
    z = {n: b.joint(n)[2] for n in ("head", "neck", "chest", "pelvis", "knee_l", "ankle_l")}
    assert z["head"] > z["neck"] > z["chest"] > z["pelvis"] > z["knee_l"] > z["ankle_l"]
    # faces -y: the toes are in front of the ankles
    feet = v[s == SECTIONS.index("lower_leg_l")]
    assert feet[:, 1].min() < b.joint("ankle_l")[1] - 0.1


@pytest.mark.parametrize("name", STANDING)
def test_neck_hands_and_feet_belong_to_head_forearms_and_lower_legs(name):
    b = load_body(name)
    s, v = b.vertex_section, b.vertices
    above_neck = v[:, 2] > b.joint("neck")[2] + 0.03
    assert (s[above_neck] == SECTIONS.index("head")).all()
    for side in "lr":
        feet = v[:, 2] < b.joint(f"ankle_{side}")[2] - 0.02
        feet &= np.sign(v[:, 0]) == (1 if side == "l" else -1)
        assert (s[feet] == SECTIONS.index(f"lower_leg_{side}")).all()
        elbow, wrist = b.joint(f"elbow_{side}"), b.joint(f"wrist_{side}")
        axis = (wrist - elbow) / np.linalg.norm(wrist - elbow)
        along = (v - wrist) @ axis
        off_axis = np.linalg.norm(v - wrist - along[:, None] * axis, axis=1)
        hand = (along > 0.02) & (along < 0.2) & (off_axis < 0.045)
        assert hand.sum() > 200
        assert (s[hand] == SECTIONS.index(f"forearm_{side}")).all()


def _crossing_edges(b: Body) -> int:
    """Edges of one section that pass through a face of a section it does not adjoin.

    Independent of `poses.checks`: each candidate edge is cast as a ray segment (embree) and its
    hits at less than the edge's length on faces not sharing its vertices are counted.
    """
    import trimesh
    from scipy.spatial import cKDTree
    v, f, s = b.vertices, b.faces, b.vertex_section
    fs = b.face_section()
    e = np.unique(np.sort(_edges(f), axis=1), axis=0)
    e = e[s[e[:, 0]] == s[e[:, 1]]]
    # only edges within 5 cm of a vertex of a section they do not adjoin
    keep = np.zeros(len(e), dtype=bool)
    for k, name in enumerate(SECTIONS):
        far = [j for j, o in enumerate(SECTIONS) if o != name and frozenset((name, o)) not in ADJACENT]
        mine = s[e[:, 0]] == k
        d, _ = cKDTree(v[np.isin(s, far)]).query(v[e[mine, 0]], distance_upper_bound=0.05)
        keep[np.flatnonzero(mine)[np.isfinite(d)]] = True
    e = e[keep]
    if len(e) == 0:
        return 0
    mesh = trimesh.Trimesh(v, f, process=False)
    d = v[e[:, 1]] - v[e[:, 0]]
    length = np.linalg.norm(d, axis=1)
    tri, ray, loc = mesh.ray.intersects_id(v[e[:, 0]], d / length[:, None], multiple_hits=True,
                                           return_locations=True)
    t = np.linalg.norm(loc - v[e[ray, 0]], axis=1)
    shares = (f[tri] == e[ray, 0:1]).any(1) | (f[tri] == e[ray, 1:2]).any(1)
    a = s[e[ray, 0]]
    b_ = fs[tri]
    apart = np.array([x != y and frozenset((SECTIONS[x], SECTIONS[y])) not in ADJACENT
                      for x, y in zip(a, b_)], dtype=bool)
    return int((~shares & (t < length[ray]) & apart).sum())


def test_no_interpenetration(body):
    assert _crossing_edges(body) == 0
    assert not interpenetration(body).any()


def _push_hand_into_thigh(b: Body) -> Body:
    v = b.vertices.copy()
    hand = (b.vertex_section == SECTIONS.index("forearm_l")) & (v[:, 2] < b.joint("wrist_l")[2])
    v[hand] += b.joint("hip_l") * [1, 0, 0] - b.joint("wrist_l") * [1, 0, 0]
    return Body("pushed", v, b.faces, b.vertex_section, b.joint_names, b.joints)


def test_interpenetration_is_detected():
    b = _push_hand_into_thigh(load_body("standing"))
    assert _crossing_edges(b) > 0
    assert interpenetration(b).sum() > 20
    assert gaps(b)["hand_hip"] < 0.002


def test_gaps_where_parts_come_close():
    g = gaps(load_body("arms_close"))
    assert 0.01 <= g["arm_torso"] <= 0.03
    assert 0.01 <= g["hand_hip"] <= 0.03
    assert g["nonadjacent"] >= 0.01
    g = gaps(load_body("hands_on_hips"))
    assert 0.01 <= g["hand_hip"] <= 0.05
    g = gaps(load_body("standing"))
    assert g["hand_hip"] > 0.04 and g["thigh_thigh"] > 0.01


def test_stored_parameters_describe_the_body(body):
    from bodyscan.poses.generate import GENERATOR_VERSION, load_posture, load_shape, shipped
    entry = shipped()[body.name]
    posture = json.loads(str(body.extras["posture"]))
    shape = json.loads(str(body.extras["shape"]))
    assert posture == load_posture(entry["posture"]), "the posture YAML changed since the body was made"
    assert shape == load_shape(entry["shape"]), "the shape YAML changed since the body was made"
    assert str(body.extras["generator_version"]) == GENERATOR_VERSION
    assert str(body.extras["anny_version"])


def test_posture_specs(tmp_path):
    from bodyscan.poses.generate import list_postures, load_posture
    assert {"standing", "arms_close", "squat"} <= set(list_postures())
    p = load_posture("standing")
    assert p["bones"]["upperarm01.L"][1] == -p["bones"]["upperarm01.R"][1]  # mirrored
    path = tmp_path / "mine.yaml"
    path.write_text("both:\n  upperarm01: [1, 2, 3]\nbones:\n  spine01: [4, 5, 6]\n")
    p = load_posture(str(path))
    assert p["name"] == "mine"
    assert p["bones"] == {"upperarm01.L": [1, 2, 3], "upperarm01.R": [1, -2, -3], "spine01": [4, 5, 6]}
    path.write_text("bones:\n  spine01: [4, 5]\n")
    with pytest.raises(BodyError, match="three numbers"):
        load_posture(str(path))
    with pytest.raises(BodyError, match="no such posture"):
        load_posture("no_such_posture")


def test_shape_specs(tmp_path):
    from bodyscan.poses.generate import load_shape
    assert load_shape("average_male")["phenotype"]["gender"] == 0.0
    path = tmp_path / "odd.yaml"
    path.write_text("phenotype: {gender: 2}\n")
    with pytest.raises(BodyError, match="outside"):
        load_shape(str(path))
    path.write_text("phenotype: {girth: 0.5}\n")
    with pytest.raises(BodyError, match="unknown phenotype"):
        load_shape(str(path))


def test_split_long_edges_keeps_a_closed_curved_surface():
    import trimesh
    from bodyscan.poses.generate import refine
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    v0, f0 = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    attr = np.c_[v0[:, 0] > 0, v0[:, 0] <= 0].astype(float)
    v, f, a = refine(v0, f0, attr, 0.03)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert m.edges_unique_length.max() <= 0.03
    # the new vertices lie near the sphere (curved midpoints), much nearer than the chord midpoints
    r = np.linalg.norm(v[len(v0):], axis=1)
    assert np.abs(r - 0.1).max() < 0.002
    assert np.allclose(a.sum(1), 1)


def test_cli_show_writes_a_png(tmp_path):
    from bodyscan.benchmarks.cli import main
    out = tmp_path / "standing.png"
    assert main(["poses", "show", "standing", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 20_000


def test_cli_generate_without_anny_says_so(tmp_path, monkeypatch, capsys):
    import bodyscan.poses.generate as gen
    from bodyscan.benchmarks.cli import main
    real_import = builtins.__import__

    def no_anny(name, *args, **kwargs):
        if name in ("anny", "torch") or name.startswith(("anny.", "torch.")):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_anny)
    monkeypatch.setattr(gen, "_MODELS", {})
    code = main(["poses", "generate", "--pose", "standing", "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2
    assert "bodies" in err and "anny" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()


def test_cli_check(capsys):
    from bodyscan.benchmarks.cli import main
    assert main(["poses", "check", "arms_close"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("arms_close"))
    assert float(row.split()[2]) == pytest.approx(100 * gaps(load_body("arms_close"))["arm_torso"], abs=0.06)


def test_cli_generate_bad_spec(tmp_path, capsys):
    from bodyscan.benchmarks.cli import main
    assert main(["poses", "generate", "--pose", "nope", "--out", str(tmp_path / "x.npz")]) == 2
    assert "no such posture" in capsys.readouterr().err


def test_generator_reproduces_a_shipped_body():
    pytest.importorskip("torch", reason="the generator needs the 'bodies' extra (torch)")
    pytest.importorskip("anny", reason="the generator needs the 'bodies' extra (anny)")
    from bodyscan.poses.generate import regenerate
    shipped = load_body("standing")
    again = regenerate(shipped)
    assert again.faces.shape == shipped.faces.shape
    assert np.array_equal(again.faces, shipped.faces)
    assert np.array_equal(again.vertex_section, shipped.vertex_section)
    assert np.abs(again.vertices - shipped.vertices).max() < 1e-5
    assert np.abs(again.joints - shipped.joints).max() < 1e-5
