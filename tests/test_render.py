"""Offscreen pictures: framing, view conventions, depth order, close-ups, and the matplotlib fallback."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh
from PIL import Image

from bodyscan.benchmarks import render

RED, GREEN, BLUE = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
SIZE = 160  # pixels per view: small and fast


def box(center, extents, color):
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(center)
    return m.vertices, m.faces, np.tile(color, (len(m.faces), 1))


def scene(*parts):
    """Concatenate (vertices, faces, colors) parts into one mesh."""
    vs, fs, cs, offset = [], [], [], 0
    for v, f, c in parts:
        vs.append(v)
        fs.append(f + offset)
        cs.append(c)
        offset += len(v)
    return np.vstack(vs), np.vstack(fs), np.vstack(cs)


def views_of(path, n_views, size=SIZE):
    """The PNG split into its views, each (size, size, 3) uint8 (no title band)."""
    image = np.asarray(Image.open(path).convert("RGB"))
    assert image.shape == (size, n_views * size, 3)
    return [image[:, i * size:(i + 1) * size] for i in range(n_views)]


def mask(view, channel):
    """Pixels where ``channel`` clearly dominates (shading scales colours, so compare channels)."""
    others = [c for c in range(3) if c != channel]
    v = view.astype(int)
    return (v[:, :, channel] > 60) & (v[:, :, channel] > 2 * v[:, :, others].max(axis=2) + 20)


def columns(m):
    cols = np.flatnonzero(m.any(axis=0))
    return cols.min(), cols.max()


@pytest.fixture(params=["pyrender", "matplotlib"])
def backend(request):
    return request.param


# Two boxes side by side along x, the red one at +x (the subject's left), the green one at -x,
# and a blue box in front of the green one (more -y): it hides part of the green one from the front.
LEFT_RED = box((0.3, 0.0, 1.0), (0.2, 0.2, 0.6), RED)
RIGHT_GREEN = box((-0.3, 0.0, 1.0), (0.2, 0.2, 0.6), GREEN)
FRONT_BLUE = box((-0.3, -0.3, 1.0), (0.1, 0.1, 0.1), BLUE)


def test_views_follow_the_body_conventions(tmp_path, backend):
    v, f, c = scene(LEFT_RED, RIGHT_GREEN)
    out = render.render_mesh(v, f, c, tmp_path / "a.png", views=("front", "back", "side"),
                             size=(SIZE, SIZE), backend=backend, legend=False)
    front, back, side = views_of(out, 3)
    # front: looking along +y at a subject facing -y, the subject's left (+x) is on the image right
    assert columns(mask(front, 0))[0] > columns(mask(front, 1))[1]
    # back: mirrored
    assert columns(mask(back, 0))[1] < columns(mask(back, 1))[0]
    # side looks at the subject's left (+x): the red box hides the green one completely
    assert mask(side, 0).sum() > 0.1 * SIZE * SIZE and mask(side, 1).sum() == 0


def test_whole_mesh_is_framed_with_the_documented_margin(tmp_path, backend):
    # front view of the two boxes: x spans [-0.4, 0.4], z spans [0.7, 1.3]; the frame is the
    # larger half-extent (0.4 m) times the margin, square, centred on the bounding box
    v, f, c = scene(LEFT_RED, RIGHT_GREEN)
    out = render.render_mesh(v, f, c, tmp_path / "b.png", views=("front",), size=(SIZE, SIZE),
                             backend=backend, legend=False)
    (front,) = views_of(out, 1)
    half = 0.4 * render._MARGIN
    px = lambda x: (x + half) / (2 * half) * SIZE  # noqa: E731  metres -> pixel column
    lo, hi = columns(mask(front, 0))
    assert abs(lo - px(0.2)) <= 2 and abs(hi + 1 - px(0.4)) <= 2
    rows = np.flatnonzero(mask(front, 0).any(axis=1))
    assert abs((rows.max() + 1 - rows.min()) - 0.6 / (2 * half) * SIZE) <= 3


def test_nearer_faces_hide_farther_ones(tmp_path, backend):
    v, f, c = scene(RIGHT_GREEN, FRONT_BLUE)
    out = render.render_mesh(v, f, c, tmp_path / "c.png", views=("front", "back"),
                             size=(SIZE, SIZE), backend=backend, legend=False)
    front, back = views_of(out, 2)
    assert mask(front, 2).sum() > 0.02 * SIZE * SIZE      # blue in front of green
    assert mask(back, 2).sum() == 0                        # hidden behind green from the back


def test_close_up_frames_the_sphere_and_cuts_away_what_is_in_front(tmp_path, backend):
    # close-up on the green box's front face: the blue box is 0.2 m in front of it, outside a
    # 0.12 m slab, so it must not hide the green box
    v, f, c = scene(RIGHT_GREEN, FRONT_BLUE)
    out = render.render_mesh(v, f, c, tmp_path / "d.png", views=("front",), size=(SIZE, SIZE),
                             close_up=((-0.3, -0.1, 1.0), 0.12), backend=backend,
                             legend=False)
    (front,) = views_of(out, 1)
    assert mask(front, 2).sum() == 0
    # the green box (x in [-0.4, -0.2]) fills columns of x in [-0.4, -0.2] within [-0.42, -0.18]
    lo, hi = columns(mask(front, 1))
    assert abs(lo - (0.02 / 0.24) * SIZE) <= 2 and abs(hi + 1 - (0.22 / 0.24) * SIZE) <= 2


def test_colours_uint8_and_float_agree_and_title_adds_a_band(tmp_path):
    v, f, c = scene(LEFT_RED, RIGHT_GREEN)
    a = render.render_mesh(v, f, c, tmp_path / "f.png", views=("front",), size=(SIZE, SIZE),
                           backend="matplotlib", legend=False)
    b = render.render_mesh(v, f, (c * 255).astype(np.uint8), tmp_path / "u.png",
                           views=("front",), size=(SIZE, SIZE), backend="matplotlib", legend=False)
    assert np.array_equal(np.asarray(Image.open(a)), np.asarray(Image.open(b)))
    t = render.render_mesh(v, f, c, tmp_path / "sub" / "t.png", views=("front", "side"),
                           size=(SIZE, SIZE), title="hello", backend="matplotlib")
    w, h = Image.open(t).size
    assert w == 2 * SIZE and h > SIZE


def test_legend_shows_every_section_colour_under_the_views(tmp_path):
    """The colour key (issue 18): a swatch of every section colour, red and grey, drawn below
    the views, so a reader can tell the sections apart; the view names sit above the views."""
    v, f, c = scene(LEFT_RED, RIGHT_GREEN)
    plain = render.render_mesh(v, f, c, tmp_path / "p.png", views=("front", "side", "back"),
                               size=(SIZE, SIZE), backend="matplotlib", legend=False)
    keyed = render.render_mesh(v, f, c, tmp_path / "k.png", views=("front", "side", "back"),
                               size=(SIZE, SIZE), backend="matplotlib")
    a, b = np.asarray(Image.open(plain).convert("RGB")), np.asarray(Image.open(keyed).convert("RGB"))
    assert b.shape[1] == a.shape[1] and b.shape[0] > a.shape[0]
    key = b[-(b.shape[0] - a.shape[0]) + 8:]           # below the views (and the name band)
    found = {tuple(px) for px in key.reshape(-1, 3)}
    items = render.legend_items()
    assert len(items) == 13
    for _, color in items:
        rgb = tuple(int(round(255 * x)) for x in color)
        assert rgb in found, rgb


def test_fallback_to_matplotlib_when_gl_fails_in_process(tmp_path, monkeypatch):
    def no_gl(width, height):
        raise RuntimeError("no GL here")

    monkeypatch.setattr(render, "_gl_renderer", no_gl)
    monkeypatch.setattr(render, "_FALLBACK_WARNED", False)
    monkeypatch.delenv("BODYSCAN_RENDERER", raising=False)
    v, f, c = scene(LEFT_RED, RIGHT_GREEN)
    with pytest.warns(render.RenderFallbackWarning, match="matplotlib"):
        out = render.render_mesh(v, f, c, tmp_path / "g.png", views=("front",),
                                 size=(SIZE, SIZE), legend=False)
    (front,) = views_of(out, 1)
    assert mask(front, 0).sum() > 0 and mask(front, 1).sum() > 0
    with pytest.raises(RuntimeError, match="no GL"):
        render.render_mesh(v, f, c, tmp_path / "h.png", backend="pyrender")


def test_fallback_with_an_unusable_gl_platform_in_a_fresh_process(tmp_path):
    # a real failure: a platform that needs a display, and no display
    script = textwrap.dedent(f"""
        import numpy as np, trimesh
        from bodyscan.benchmarks import render
        m = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
        render.render_mesh(m.vertices, m.faces, np.full((12, 3), 0.5), {str(tmp_path / 'x.png')!r},
                           size=(64, 64), legend=False)
    """)
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "BODYSCAN_RENDERER")}
    env["PYOPENGL_PLATFORM"] = "glx"
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "RenderFallbackWarning" in proc.stderr and "matplotlib" in proc.stderr
    assert Image.open(tmp_path / "x.png").size == (3 * 64, 64)


def test_gl_matches_matplotlib(tmp_path):
    v, f, c = scene(LEFT_RED, RIGHT_GREEN, FRONT_BLUE)
    a = render.render_mesh(v, f, c, tmp_path / "gl.png", size=(SIZE, SIZE), backend="pyrender",
                           legend=False)
    b = render.render_mesh(v, f, c, tmp_path / "mpl.png", size=(SIZE, SIZE),
                           backend="matplotlib", legend=False)
    for va, vb in zip(views_of(a, 3), views_of(b, 3)):
        for channel in range(3):
            assert (mask(va, channel) != mask(vb, channel)).mean() < 0.02


def test_platform_is_chosen_without_display():
    script = ("import os; from benchmarks import render; "
              "print(render.gl_platform()); import pyrender; print('ok')")
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[0] in ("osmesa", "egl")


def test_section_colours_mark_highlighted_faces_red():
    colors = render.section_face_colors([0, 1, 10, -1, 3], highlight=[False, True, False, False,
                                                                      False])
    assert np.allclose(colors[1], render.HIGHLIGHT_COLOR)
    assert np.allclose(colors[3], render.UNLABELLED_COLOR)
    assert np.allclose(colors[[0, 2, 4]], render.SECTION_COLORS[[0, 10, 3]])
    # no section colour is close to red
    red = np.array([1.0, 0.0, 0.0])
    assert np.linalg.norm(render.SECTION_COLORS - red, axis=1).min() > 0.5


@pytest.mark.parametrize("kwargs, match", [
    (dict(vertices=np.zeros((3, 2))), "vertices"),
    (dict(faces=np.array([[0, 1, 5]])), "indices"),
    (dict(face_colors=np.full((1, 3), 2.0)), "0, 1"),
    (dict(face_colors=np.full((2, 3), 0.5)), "face_colors"),
    (dict(views=("sideways",)), "unknown view"),
    (dict(backend="vulkan"), "backend"),
    (dict(close_up=((0, 0, 0), 0.0)), "radius"),
])
def test_bad_input_is_a_clear_error(tmp_path, kwargs, match):
    args = dict(vertices=np.eye(3), faces=np.array([[0, 1, 2]]), face_colors=np.full((1, 3), 0.5),
                out=tmp_path / "e.png")
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        render.render_mesh(**args)
