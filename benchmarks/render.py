"""Offscreen pictures of triangle meshes with per-face colours: pyrender (OSMesa/EGL), or matplotlib.

`render_mesh` draws a mesh from one or more named views, side by side in one PNG, each with an
orthographic camera framed on the mesh (or on a close-up sphere). Faces are flat-shaded in their own
colour and lit from the camera; both sides of every face are lit, so wrongly oriented triangles stay
visible (their colour, not their shading, tells them apart).

The GL path and its compatibility shim
--------------------------------------
pyrender 0.1.45 is the renderer. Three facts about it, measured here, are handled in one place
(`_import_pyrender`):

- its metadata pins PyOpenGL==3.1.0, which cannot create an OSMesa context; PyOpenGL >= 3.1.7 can.
  pip's resolver cannot override a dependency's pin, so pyrender is installed with ``--no-deps``
  (``pip install --no-deps pyrender==0.1.45``) and its other requirements come from our own
  ``pyproject.toml``;
- it uses ``np.infty`` (removed in numpy 2) in ``Mesh.bounds``, which ``Scene.bounds`` and the
  renderer call; the shim sets ``numpy.infty = numpy.inf`` when it is missing (the one global
  change this module makes, and only when pyrender is imported);
- with ``PYOPENGL_PLATFORM`` unset it opens a window through pyglet, which fails without a display.
  When the variable is unset and there is no ``DISPLAY``/``WAYLAND_DISPLAY``, the shim sets it to
  ``osmesa`` when libOSMesa is installed (Debian: ``libosmesa6``; about 45 ms per 800 x 800 frame
  here), else ``egl`` when libEGL is (Mesa's software renderer: about 90 ms). A platform the user
  set is kept. The variable must be set before PyOpenGL is first imported.

Where no GL context can be created (no library, an unusable platform), `render_mesh` falls back to
matplotlib: the same cameras, triangles projected and drawn far to near (painter's algorithm) with
the same shading. It says so with a `RenderFallbackWarning`, once per process. The picture is the
same in content but slower on big meshes (seconds for 100 thousand faces) and without per-pixel
depth, so interpenetrating triangles can be drawn in the wrong order.
``BODYSCAN_RENDERER=matplotlib`` (or ``backend="matplotlib"``) asks for matplotlib directly.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: View name -> (viewing direction, image-up direction). The subject faces -y, +z is up, left is +x;
#: "front" looks along +y at the subject's front, "side" (= "left") looks at the subject's left.
VIEWS = {
    "front": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "back": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "side": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "top": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
}

#: One colour per body section (label order of ``poses.SECTIONS``), none of them red, so that red
#: can mark spurious triangles. Paired sections (left/right) get related hues.
SECTION_COLORS = np.array([
    (0.93, 0.80, 0.55),  # head: sand
    (0.35, 0.55, 0.85),  # chest: blue
    (0.55, 0.40, 0.75),  # waist: violet
    (0.30, 0.70, 0.45),  # upper_arm_l: green
    (0.60, 0.80, 0.30),  # upper_arm_r: yellow-green
    (0.20, 0.65, 0.70),  # forearm_l: teal
    (0.50, 0.80, 0.80),  # forearm_r: light teal
    (0.95, 0.60, 0.20),  # thigh_l: orange
    (0.85, 0.75, 0.25),  # thigh_r: ochre
    (0.70, 0.50, 0.35),  # lower_leg_l: brown
    (0.80, 0.65, 0.55),  # lower_leg_r: light brown
])
#: Colour of faces marked by ``highlight`` in `section_face_colors` (spurious triangles).
HIGHLIGHT_COLOR = np.array((0.90, 0.05, 0.05))
#: Colour of faces without a section (label outside 0..10).
UNLABELLED_COLOR = np.array((0.65, 0.65, 0.65))

_MARGIN = 1.05          # framing margin around the mesh
_AMBIENT = 0.35         # share of light that does not depend on the face's angle to the camera
_BACKGROUND = (1.0, 1.0, 1.0)


class RenderFallbackWarning(UserWarning):
    """No OpenGL context could be created; pictures are drawn with matplotlib instead."""


# -- public API ---------------------------------------------------------------------------------

def render_mesh(vertices, faces, face_colors, out, *, views=("front", "side", "back"),
                size=(800, 800), close_up=None, title=None, backend: str | None = None,
                legend: bool = True) -> Path:
    """Render a triangle mesh with per-face colours offscreen, views side by side, to a PNG.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions, metres (+z up, the subject faces -y, left is +x).
    faces : (m, 3) int
        Triangles, indices into ``vertices``; winding does not matter (both sides are lit).
    face_colors : (m, 3) or (m, 4) float in [0, 1], or uint8 in [0, 255]
        Colour of each face; an alpha channel is ignored.
    out : str or Path
        PNG file to write; missing parent folders are created.
    views : sequence of str
        View names from `VIEWS`, drawn left to right: ``"front"`` looks along +y at the subject's
        front, ``"side"`` (= ``"left"``) at the subject's left side, ``"back"``, ``"right"``,
        ``"top"``.
    size : (int, int)
        Width and height of each view, pixels; the PNG is ``len(views) * width`` wide (plus a title
        band when ``title`` is given).
    close_up : ((3,) float, float) or None
        ``(center, radius)`` in metres: frame the square of half-side ``radius`` around ``center``
        and show only the slab of depth ``center +- radius`` along each view direction (so a
        close-up of an armpit is not hidden by an arm in front of it). None frames the whole mesh.
    title : str or None
        Text drawn above the views.
    legend : bool
        Draw the colour key under the views: the section colours (`SECTION_COLORS`), red for
        `HIGHLIGHT_COLOR` (spurious or bridging triangles) and grey for no section; and each
        view's name in a band above it, where the mesh cannot hide it. False: the views alone
        (``len(views) * width`` by ``height`` plus the title band), names drawn on them.
    backend : {"auto", "pyrender", "matplotlib"} or None
        ``"auto"`` (default; environment variable ``BODYSCAN_RENDERER`` overrides) uses pyrender
        and falls back to matplotlib with a `RenderFallbackWarning` when no GL context can be made;
        ``"pyrender"`` raises instead of falling back.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ValueError
        Bad shapes, indices out of range, colours out of range, unknown view or backend.
    """
    v, f, colors = _check_mesh(vertices, faces, face_colors)
    views = (views,) if isinstance(views, str) else tuple(views)
    unknown = [name for name in views if name not in VIEWS]
    if not views or unknown:
        raise ValueError(f"render_mesh: unknown view(s) {unknown}; choose from {sorted(VIEWS)}")
    width, height = (int(s) for s in size)
    if width < 16 or height < 16:
        raise ValueError(f"render_mesh: size must be at least 16 x 16 pixels, got {size}")
    if close_up is not None:
        center, radius = close_up
        center = np.asarray(center, dtype=np.float64).reshape(3)
        radius = float(radius)
        if not radius > 0:
            raise ValueError(f"render_mesh: close-up radius must be > 0 metres, got {radius}")
        close_up = (center, radius)
    backend = (backend or os.environ.get("BODYSCAN_RENDERER") or "auto").lower()
    if backend not in ("auto", "pyrender", "matplotlib"):
        raise ValueError(f"render_mesh: unknown backend {backend!r}; "
                         "use auto, pyrender or matplotlib (BODYSCAN_RENDERER)")

    cameras = [_frame(v, name, width / height, close_up) for name in views]
    normals = _face_normals(v, f)
    images = None
    if backend != "matplotlib":
        try:
            renderer = _gl_renderer(width, height)
        except Exception as exc:  # no GL at all: any failure of the library or the platform
            if backend == "pyrender":
                raise
            _warn_fallback(exc)
        else:
            images = [_render_gl(renderer, v, f, colors, normals, cam) for cam in cameras]
    if images is None:
        images = [_render_mpl(v, f, colors, normals, cam, width, height) for cam in cameras]

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    from bodyscan._io import atomic_write

    picture = _compose(images, list(views), title, legend)
    return atomic_write(out, picture.save)


def section_face_colors(face_section, highlight=None) -> np.ndarray:
    """Per-face colours by body section, with highlighted faces (spurious triangles) in red.

    Parameters
    ----------
    face_section : (m,) int
        Section label of each face (index into ``poses.SECTIONS``); other values are drawn grey.
    highlight : (m,) bool or None
        Faces drawn in `HIGHLIGHT_COLOR` whatever their section.

    Returns
    -------
    (m, 3) float
        RGB in [0, 1].
    """
    labels = np.asarray(face_section).astype(np.int64).reshape(-1)
    known = (labels >= 0) & (labels < len(SECTION_COLORS))
    colors = np.where(known[:, None], SECTION_COLORS[np.clip(labels, 0, len(SECTION_COLORS) - 1)],
                      UNLABELLED_COLOR)
    if highlight is not None:
        highlight = np.asarray(highlight, dtype=bool).reshape(-1)
        if highlight.shape != labels.shape:
            raise ValueError(f"section_face_colors: highlight has {highlight.size} entries "
                             f"for {labels.size} faces")
        colors[highlight] = HIGHLIGHT_COLOR
    return colors


def gl_platform() -> str | None:
    """The PyOpenGL platform pyrender will use (``osmesa``, ``egl``...), chosen as described above.

    Returns None when a display is available and no platform is set (pyrender then uses pyglet).
    """
    _choose_platform()
    return os.environ.get("PYOPENGL_PLATFORM")


# -- input checks -------------------------------------------------------------------------------

def _check_mesh(vertices, faces, face_colors):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"render_mesh: vertices must be a non-empty (n, 3) array, got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("render_mesh: vertices contain NaN or infinite values")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"render_mesh: faces must be a non-empty (m, 3) int array, got "
                         f"{f.shape} {f.dtype}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"render_mesh: face indices must be in [0, {len(v) - 1}]")
    c = np.asarray(face_colors)
    if c.ndim != 2 or c.shape[0] != len(f) or c.shape[1] not in (3, 4):
        raise ValueError(f"render_mesh: face_colors must be ({len(f)}, 3) or ({len(f)}, 4), "
                         f"got {c.shape}")
    if np.issubdtype(c.dtype, np.integer):
        if c.min() < 0 or c.max() > 255:
            raise ValueError("render_mesh: integer face_colors must be in [0, 255]")
        c = c / 255.0
    else:
        c = c.astype(np.float64)
        if not (np.isfinite(c).all() and c.min() >= 0 and c.max() <= 1):
            raise ValueError("render_mesh: float face_colors must be in [0, 1] "
                             "(pass uint8 for 0..255)")
    return v, f.astype(np.int64), c[:, :3]


# -- cameras ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Camera:
    """An orthographic camera: looks along ``direction``; the image spans +-``half`` around
    ``center`` along ``right`` and ``up``; only depths (along ``direction``, from ``center``) in
    ``[near, far]`` are drawn."""

    direction: np.ndarray
    right: np.ndarray
    up: np.ndarray
    center: np.ndarray
    half: tuple            # (half width, half height), metres
    near: float
    far: float


def _frame(v: np.ndarray, view: str, aspect: float, close_up) -> _Camera:
    d, up = (np.asarray(a, dtype=np.float64) for a in VIEWS[view])
    right = np.cross(d, up)
    if close_up is None:
        lo, hi = v.min(axis=0), v.max(axis=0)
        center = (lo + hi) / 2
        rel = v - center
        half_w = np.abs(rel @ right).max() * _MARGIN
        half_h = np.abs(rel @ up).max() * _MARGIN
        depth = np.abs(rel @ d).max()
        near, far = -depth * 1.01 - 1e-6, depth * 1.01 + 1e-6
    else:
        center, radius = close_up
        half_w = half_h = radius
        near, far = -radius, radius
    half_w, half_h = max(half_w, 1e-6), max(half_h, 1e-6)
    # widen one side so that the framed region has the image's aspect ratio
    if half_w / half_h < aspect:
        half_w = half_h * aspect
    else:
        half_h = half_w / aspect
    return _Camera(d, right, up, np.asarray(center, dtype=np.float64), (half_w, half_h), near, far)


def _shading(normals: np.ndarray, cam: _Camera) -> np.ndarray:
    """(m,) brightness of each face, lit from the camera; both sides alike."""
    return _AMBIENT + (1 - _AMBIENT) * np.abs(normals @ cam.direction)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


# -- pyrender path ------------------------------------------------------------------------------

_RENDERERS: dict = {}
_FALLBACK_WARNED = False


def _choose_platform() -> None:
    """Set ``PYOPENGL_PLATFORM`` for a machine without display, unless the user set it."""
    if "PYOPENGL_PLATFORM" in os.environ or sys.platform in ("darwin", "win32"):
        return
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    if ctypes.util.find_library("OSMesa"):
        os.environ["PYOPENGL_PLATFORM"] = "osmesa"
    elif ctypes.util.find_library("EGL"):
        os.environ["PYOPENGL_PLATFORM"] = "egl"


def _import_pyrender():
    """Import pyrender with the compatibility shim described in the module docstring."""
    if "OpenGL" not in sys.modules:
        _choose_platform()
    if not hasattr(np, "infty"):   # numpy 2 removed it; pyrender 0.1.45's Mesh.bounds uses it
        np.infty = np.inf
    import pyrender
    return pyrender


def _gl_renderer(width: int, height: int):
    """A cached `pyrender.OffscreenRenderer` of this size (making the context is the slow part)."""
    key = (width, height)
    if key not in _RENDERERS:
        pyrender = _import_pyrender()
        _RENDERERS[key] = pyrender.OffscreenRenderer(width, height)
    return _RENDERERS[key]


def _warn_fallback(exc: BaseException) -> None:
    global _FALLBACK_WARNED
    if _FALLBACK_WARNED:
        return
    _FALLBACK_WARNED = True
    platform = os.environ.get("PYOPENGL_PLATFORM", "unset")
    warnings.warn(
        f"render: no OpenGL context ({type(exc).__name__}: {str(exc)[:200]}; "
        f"PYOPENGL_PLATFORM={platform}); drawing pictures with matplotlib instead. For GL "
        "pictures install libosmesa6 (apt-get install libosmesa6) and "
        "`pip install --no-deps pyrender==0.1.45` with PyOpenGL>=3.1.7",
        RenderFallbackWarning, stacklevel=3)


def _render_gl(renderer, v, f, colors, normals, cam: _Camera) -> np.ndarray:
    """(height, width, 3) uint8 picture of one view with pyrender."""
    pyrender = _import_pyrender()
    # the shading is baked into the colours and drawn unlit (RenderFlags.FLAT), exactly as the
    # matplotlib path does: GL only rasterizes with a depth buffer
    shaded = np.clip(colors * _shading(normals, cam)[:, None], 0, 1)
    rgba = np.concatenate([shaded, np.ones((len(f), 1))], axis=1)
    primitive = pyrender.Primitive(
        positions=v[f].reshape(-1, 3).astype(np.float32),
        color_0=np.repeat(rgba, 3, axis=0).astype(np.float32),
        mode=pyrender.constants.GLTF.TRIANGLES,
        material=pyrender.MetallicRoughnessMaterial(doubleSided=True))
    scene = pyrender.Scene(bg_color=(*_BACKGROUND, 1.0))
    scene.add(pyrender.Mesh([primitive]))
    # camera frame: x = right, y = up, looking along -z = direction; placed before the near plane
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = cam.right, cam.up, -cam.direction
    standoff = max(cam.far - cam.near, 1e-3)
    pose[:3, 3] = cam.center + cam.direction * (cam.near - standoff)
    half_w, half_h = cam.half
    scene.add(pyrender.OrthographicCamera(xmag=half_w, ymag=half_h, znear=standoff,
                                          zfar=standoff + cam.far - cam.near), pose=pose)
    color, _ = renderer.render(scene, flags=pyrender.RenderFlags.FLAT)
    return np.ascontiguousarray(color[:, :, :3])


# -- matplotlib path ----------------------------------------------------------------------------

def _render_mpl(v, f, colors, normals, cam: _Camera, width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8 picture of one view with matplotlib (painter's algorithm)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    rel = v - cam.center
    xy = np.stack([rel @ cam.right, rel @ cam.up], axis=1)
    depth = rel @ cam.direction
    tri_depth = depth[f]
    keep = (tri_depth.min(axis=1) >= cam.near) & (tri_depth.max(axis=1) <= cam.far)
    if cam.far - cam.near < np.ptp(depth):   # a close-up slab: keep faces that reach into it
        keep = (tri_depth.max(axis=1) >= cam.near) & (tri_depth.min(axis=1) <= cam.far)
    order = np.flatnonzero(keep)[np.argsort(-tri_depth[keep].mean(axis=1), kind="stable")]
    shade = _shading(normals[order], cam)[:, None]
    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor=_BACKGROUND)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_facecolor(_BACKGROUND)
    ax.add_collection(PolyCollection(xy[f[order]], facecolors=np.clip(colors[order] * shade, 0, 1),
                                     edgecolors="face", linewidths=0.2, antialiased=False))
    half_w, half_h = cam.half
    ax.set_xlim(-half_w, half_w)
    ax.set_ylim(-half_h, half_h)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


# -- composition --------------------------------------------------------------------------------

def legend_items() -> list:
    """The colour key: [(label, (r, g, b) in [0, 1])], sections in label order, then the
    highlight (spurious or bridging) and no section."""
    from .metrics import SECTIONS

    return ([(name.replace("_", " "), tuple(c)) for name, c in zip(SECTIONS, SECTION_COLORS)]
            + [("spurious or bridging", tuple(HIGHLIGHT_COLOR)), ("no section", tuple(UNLABELLED_COLOR))])


def _compose(images: list, labels: list, title: str | None, legend: bool = True):
    """One PIL image: an optional title band, a band naming each view (above the picture, so
    that the mesh never hides it), the views side by side, and the colour key under them."""
    from PIL import Image, ImageDraw, ImageFont

    height, width = images[0].shape[:2]
    total = width * len(images)
    band = max(24, height // 18) if title else 0
    label_size = max(12, height // 45)
    label_band = label_size + 8 if legend else 0    # without the key: labels on the picture
    font = _font(ImageFont, label_size)
    rows, x, row = [[]], 8, 0                       # legend items flowed into rows
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    for text, color in (legend_items() if legend else []):
        w = label_size + 4 + int(probe.textlength(text, font=font)) + 12
        if x + w > total and rows[-1]:
            rows.append([])
            x = 8
        rows[-1].append((x, text, color))
        x += w
    key_band = (len(rows) * (label_size + 6) + 6) if legend else 0
    canvas = Image.new("RGB", (total, band + label_band + height + key_band), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    top = band + label_band
    for i, (image, label) in enumerate(zip(images, labels)):
        canvas.paste(Image.fromarray(image), (i * width, top))
        draw.text((i * width + 8, band + (3 if legend else 6)), label, fill=(60, 60, 60), font=font)
    if title:
        draw.text((10, band // 6), title, fill=(0, 0, 0), font=_font(ImageFont, int(band * 0.6)))
    for r, items in enumerate(rows if legend else []):
        y = top + height + 4 + r * (label_size + 6)
        for x, text, color in items:
            rgb = tuple(int(round(255 * c)) for c in color)
            draw.rectangle([x, y + 1, x + label_size, y + label_size + 1], fill=rgb, outline=(80, 80, 80))
            draw.text((x + label_size + 4, y), text, fill=(40, 40, 40), font=font)
    return canvas


def _font(ImageFont, size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has a single bitmap size
        return ImageFont.load_default()
