"""Test helper: what ideal parallel front (-y) and rear (+y) cameras see of sampled surfaces."""

import numpy as np


def front_rear_zbuffer(P, N, step):
    """Which points of ``P`` (k, 3) (outward unit normals ``N``) the front and rear cameras see on a
    ``step`` grid in x, z: the nearest facing point of each pixel. Returns ``keep`` (k,) bool and
    ``view_dir`` (k, 3), each seen point's direction toward its camera (zero where unseen)."""
    ix, iz = np.floor(P[:, 0] / step).astype(int), np.floor(P[:, 2] / step).astype(int)
    key = (ix - ix.min()) * 100000 + (iz - iz.min())
    keep, vd = np.zeros(len(P), bool), np.zeros_like(P)
    for sign in (1, -1):  # sign 1: the front camera, at -y
        o = np.lexsort((sign * P[:, 1], key))
        first = o[np.r_[True, key[o][1:] != key[o][:-1]]]
        first = first[N[first, 1] * -sign > 0.05]
        keep[first] = True
        vd[first] = (0, -sign, 0)
    return keep, vd


def ellipsoid(a, n):
    """Points (n * 2n, 3) on the axis-aligned ellipsoid of semi-axes ``a`` (3,) at the origin, on
    an n x 2n grid of (polar, azimuth) angles, and their outward unit normals."""
    u, v = np.meshgrid(np.linspace(0, np.pi, n), np.linspace(0, 2 * np.pi, 2 * n))
    d = np.column_stack([np.sin(u.ravel()) * np.cos(v.ravel()), np.sin(u.ravel()) * np.sin(v.ravel()),
                         np.cos(u.ravel())])
    N = d / a
    return d * a, N / np.linalg.norm(N, axis=1, keepdims=True)
