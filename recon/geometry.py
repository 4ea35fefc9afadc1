"""Small vector helpers of the posture estimation: (..., 3) arrays in, arrays out."""

from __future__ import annotations

import math

import numpy as np


def fibonacci_sphere(n: int, hemisphere: bool = False) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (or the upper hemisphere, z >= 0)."""
    i = np.arange(n) + 0.5
    z = 1 - i / n if hemisphere else 1 - 2 * i / n
    phi = i * np.pi * (3 - np.sqrt(5))
    r = np.sqrt(1 - z ** 2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def cross(a, b) -> np.ndarray:
    """Cross product of (..., 3) arrays (np.cross is slow on small arrays; two (3,) vectors, the
    searches' commonest call, are multiplied as Python floats: the same products)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape == (3,) and b.shape == (3,):
        (a0, a1, a2), (b0, b1, b2) = a.tolist(), b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def perp(d: np.ndarray) -> np.ndarray:
    """(..., 3) a unit vector perpendicular to each unit vector ``d`` (..., 3)."""
    if np.shape(d) == (3,):
        # one vector (the searches' commonest call): the same arithmetic on Python floats
        u = cross(d, (0.0, 0.0, 1.0) if abs(float(d[2])) < 0.9 else (1.0, 0.0, 0.0)).tolist()
        return np.array(u) / math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    ref = np.where(np.abs(d[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    u = cross(d, ref)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def rotvec(v: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of rotation vector ``v`` (Rodrigues)."""
    th = float(np.linalg.norm(v))
    if th < 1e-12:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def unit(v):
    """``v`` (..., 3) scaled to unit length along its last axis."""
    if np.shape(v) == (3,):
        x, y, z = np.asarray(v, dtype=np.float64).tolist()
        return v / math.sqrt(x * x + y * y + z * z)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def tangent_dir(d0: np.ndarray, a: float, b: float, basis=None) -> np.ndarray:
    """Unit direction near ``d0`` moved by angles (a, b) radians in its tangent plane, spanned by
    ``basis`` = (u, w) when given (a search calling this many times about one ``d0``), else by
    ``perp(d0)`` and ``d0 x perp(d0)``."""
    u, w = basis if basis is not None else (perp(d0), cross(d0, perp(d0)))
    t = np.hypot(a, b)
    y = np.pi * (t / np.pi)   # sin(t) / t as np.sinc(t / pi) computes it (eps at 0), without its overhead
    y = y if y != 0 else np.finfo(np.float64).eps
    return unit(d0 * np.cos(t) + (u * a + w * b) * (np.sin(y) / y))


def frames_from_dirs(d: np.ndarray) -> np.ndarray:
    """(m, 3, 3) frames (rows x, y, axis) for unit directions ``d`` (m, 3)."""
    if d.shape == (1, 3):
        u = perp(d[0])
        return np.array([[u, cross(d[0], u), d[0]]])
    u = perp(d)
    return np.stack([u, cross(d, u), d], axis=1)


def turn_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    v = cross(a, b)
    s = float(np.linalg.norm(v))
    if s < 1e-9:
        return np.eye(3)
    return rotvec(v / s * np.arctan2(s, float(a @ b)))
