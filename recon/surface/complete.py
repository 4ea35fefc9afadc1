"""Completion beyond the paper: every seen point in the surface (the hands', the feet's and the far
charts).

`extremity_charts`: the hands and feet of the body model (`recon.posture.extremities`, placed past
the fitted wrists and ankles; their points given by `recon.clustering.cluster.assign_extremities`)
are meshed on charts of their own, joined to the forearm (lower leg) they continue, whose label
their faces carry (a hand is scored as its forearm, a foot as its lower leg). With ``far_view``
each is meshed as the range images its cameras took (`recon.surface.mesh.view_surface`, a height
field per camera that cannot fold over the curled fingers or the arch), the rims between the
images closed by its fitted column; a hand on a scan coarser than ``far_hand_spacing`` around its
column, like a section (its range image joins the fingers across their gaps). A hand's range
images keep triangles up to ``far_max_edge`` of those spacings on a finer scan too: a hand is a
few centimetres across, and longer triangles span its curled fingers and knuckles.

`far_charts`: the points that no fitted section explains (beyond T_d of every section: the points
of a section listed unfitted, a hand or a foot the model has none for) are grouped into connected
parts, and each part of at least ``far_min_points`` points gets a chart of its own, which also
holds the meshed points within ``far_join`` spacings of the part, so that the part's surface joins
its section's. With ``far_view`` the chart is the range image each camera took of the part,
triangulated across its view (`recon.surface.mesh.view_surface`: a height field over its camera's
image, whatever its shape); otherwise (the chart kept for `closed_surface`) an elliptic column
along the part's principal axis (open at the end that joins the body, closed by a cap at the
other), triangulated like a section (`recon.surface.mesh.section_surface`). Then the merge and the
air rules as for any section; the faces carry the section whose axis comes nearest. Smaller parts
are outliers and stay out of the surface. Every point the charts left out, outliers apart, gets
the same charts afterwards (`recon.surface.mesh.left_out_charts`: a limb listed unfitted beside the
trunk, a second layer its chart cannot hold, points the clustering put in no section).

The closed surface (the method ``proposed-closed``) is `recon.surface.closed`.
"""

from __future__ import annotations

import numpy as np

from ..model import SECTIONS, SectionShape


def far_parts(points: np.ndarray, far: np.ndarray, link: float, min_points: int):
    """Connected parts of the ``far`` points.

    Parameters
    ----------
    points : (n, 3) float, metres
    far : (n,) bool
        The points no fitted section explains.
    link : float
        Two far points nearer than this (metres) are in the same part.
    min_points : int
        Smaller parts are left out (outliers).

    Returns
    -------
    list of (k,) int
        Point indices of each part, largest first.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    idx = np.flatnonzero(far)
    if len(idx) < max(min_points, 1):
        return []
    pairs = cKDTree(points[idx]).query_pairs(link, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
    _, lab = connected_components(g, directed=False)
    count = np.bincount(lab)
    order = np.argsort(-count, kind="stable")
    return [idx[lab == c] for c in order if count[c] >= min_points]


def part_shape(part: np.ndarray, joined: np.ndarray, name: str) -> SectionShape:
    """The chart of one far part: an elliptic column along the part's principal axis.

    Parameters
    ----------
    part : (k, 3) float
        The part's points, metres.
    joined : (j, 3) float
        The meshed points it joins (may be empty); the column is open at the end nearer to them
        (they lie on its extension) and closed by a cap at the other.
    name : str
        Section name given to the shape.
    """
    c = part.mean(axis=0)
    q = part - c
    _, vec = np.linalg.eigh(q.T @ q)
    axis, fx = vec[:, 2], vec[:, 1]
    t = q @ axis
    lo, hi = float(t.min()), float(t.max())
    if len(joined) and float(((joined - c) @ axis).mean()) > 0.5 * (lo + hi):
        axis, t, lo, hi = -axis, -t, -hi, -lo      # the joined end is the start
    spread = np.sqrt(np.maximum(np.mean((q @ np.column_stack([fx, np.cross(axis, fx)])) ** 2, axis=0), 0))
    radii = np.maximum(1.7 * spread, 0.005)   # a uniform plate's half-width is 1.73 std
    length = max(hi - lo, 0.01)
    cap = min(float(radii.mean()), 0.5 * length)
    return SectionShape(name=name, start=c + lo * axis, end=c + (lo + length) * axis, radii=radii,
                        frame_x=fx, closed=(not len(joined), True), caps=(cap, cap))


def nearest_axis(part: np.ndarray, sections: dict) -> int:
    """Index (into `SECTIONS`) of the fitted section whose axis segment comes nearest to the
    points ``part`` (k, 3): the section a far part continues (a hand its forearm, past the wrist,
    even when it hangs nearer to a thigh's surface than to the forearm's)."""
    best, out = np.inf, 0
    for j, name in enumerate(SECTIONS):
        if name not in sections:
            continue
        sh = sections[name]
        t = np.clip((part - sh.start) @ sh.axis, 0.0, sh.length)
        d = float(np.linalg.norm(part - sh.start - t[:, None] * sh.axis, axis=1).min())
        if d < best:
            best, out = d, j
    return out


def far_charts(points: np.ndarray, far: np.ndarray, sections: dict, meshed: np.ndarray,
               spacing: float, link: float = 4.0, join: float = 3.0, min_points: int = 5,
               max_edge: float = 4.0, tree=None, alone: bool = False):
    """Charts for the points no fitted section explains (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float, metres
    far : (n,) bool
        Points beyond T_d of every fitted section (hands, feet, a section listed unfitted).
    sections : dict of str to SectionShape
        The fitted sections (`BodyFit.sections`): a part goes to the one whose axis comes
        nearest (`nearest_axis`).
    meshed : (n, 11) bool
        Memberships of the points meshed on the sections' own charts.
    spacing : float
        Median point spacing, metres.
    link, join : float
        Spacings: far points nearer than ``link`` form one part; meshed points within ``join``
        of a part, in its section, join its chart.
    min_points : int
        Parts with fewer points are outliers and stay out.
    max_edge : float
        Spacings: longer triangles are left out of these charts (a hand's or a foot's points are
        few across its features: long triangles there span fingers and toes), but never shorter
        than ``max_edge_min`` (the chart's trim, `recon.surface.mesh.section_surface`: the rims
        the cameras left unseen are as wide on a dense scan).
    tree : scipy.spatial.cKDTree, optional
        Of ``points``, if already built.
    alone : bool
        Also chart the parts with no meshed point within ``join`` spacings (by default left out:
        nothing of the body they continue, a fit off the cloud).

    Returns
    -------
    list of (int, (k,) int, SectionShape, dict, (k',) int)
        Section index, point indices, chart and surface parameter changes of each part (for
        `recon.surface.mesh.reconstruct_surfaces`'s ``extra``), and the part's own points (without
        the joined ones: its solid in `closed_surface`). The parts' points are in no section
        of ``meshed``: not in their section's own chart, and never "inner" in the merge.
    """
    from scipy.spatial import cKDTree

    jobs = []
    tree = cKDTree(points) if tree is None else tree
    for idx in far_parts(points, far, link * spacing, min_points):
        j = nearest_axis(points[idx], sections)
        near = _joined(tree, points, idx, join * spacing)
        if not (alone or meshed[near].any()):   # joined to no meshed point: not the body's (a fit off the cloud)
            continue
        near = near[meshed[near, j]]
        shape = part_shape(points[idx], points[near], SECTIONS[j])
        jobs.append((j, np.union1d(idx, near), shape, {"max_edge_factor": max_edge}, idx))
    return jobs


def _joined(tree, points: np.ndarray, idx: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the points within ``radius`` (metres) of ``points[idx]``."""
    from itertools import chain

    hit = np.zeros(len(points), dtype=bool)
    hit[np.fromiter(chain.from_iterable(tree.query_ball_point(points[idx], radius)), dtype=np.int64)] = True
    return np.flatnonzero(hit)


def extremity_charts(points: np.ndarray, ext: np.ndarray, fit, meshed: np.ndarray, spacing: float,
                     join: float = 3.0, max_edge: float = 4.0, tree=None, hand_spacing: float = 0.0075):
    """Charts of the hands and feet of the body model (`recon.model.EXTREMITIES`).

    Parameters
    ----------
    points : (n, 3) float, metres
    ext : (n,) int
        Each point's extremity (`recon.clustering.cluster.assign_extremities`), -1 for none.
    fit : BodyFit
        With ``extremities``.
    meshed : (n, 11) bool
        Memberships of the points meshed on the sections' own charts.
    spacing : float
        Median point spacing, metres.
    join : float
        Spacings: the meshed points of its section within this of an extremity join its chart.
    max_edge : float
        Spacings: longer triangles are left out (as `far_charts`: a hand's or a foot's points are
        few across its features, long triangles there span fingers and toes).
    tree : scipy.spatial.cKDTree, optional
    hand_spacing : float
        Metres: on scans coarser than this the hands are triangulated around their column
        (``far_view`` off in their parameters): there a hand's range image bridges the gaps
        between its fingers. On finer scans their range images keep triangles up to
        ``max_edge`` of these spacings (as their camera saw them), not ``max_edge_min``: a hand
        is a few centimetres across, and longer triangles span its curled fingers and knuckles.

    Returns
    -------
    list of (int, (k,) int, SectionShape, dict, (k',) int)
        As `far_charts`: the section the extremity is scored as, its points and the joined ones,
        its fitted column (the rim chart of its range images), the surface parameter changes, its
        own points.
    """
    from scipy.spatial import cKDTree

    from ..model import EXTREMITIES

    jobs = []
    tree = cKDTree(points) if tree is None else tree
    for k, (name, (parent, _)) in enumerate(EXTREMITIES.items()):
        idx = np.flatnonzero(ext == k)
        if len(idx) < 3:
            continue
        j = SECTIONS.index(parent)
        near = _joined(tree, points, idx, join * spacing)
        near = near[meshed[near, j]]
        change = {"max_edge_factor": max_edge}
        if name.startswith("hand"):
            if spacing > hand_spacing:
                change["far_view"] = False     # a hand on a coarse scan: around its column
            elif max_edge > 0:
                change["hull_edge_min"] = change["max_edge_min"] = max_edge * hand_spacing
        jobs.append((j, np.union1d(idx, near), fit.extremities[name], change, idx))
    return jobs


def unmeshed_count(n: int, faces: np.ndarray) -> int:
    """Points of ``n`` in no face of ``faces`` (k, 3)."""
    used = np.zeros(n, dtype=bool)
    used[np.asarray(faces, dtype=np.int64).ravel()] = True
    return int(n - used.sum())
