"""bodyscan: a benchmark suite for human-body surface reconstruction from range scans.

The stages live in subpackages, and data flows one way through them:
`bodyscan.poses` -> `bodyscan.simulator` -> `bodyscan.recon` -> `bodyscan.benchmarks`.
The few functions a script needs are here, imported lazily so ``import bodyscan`` stays light:

- ``load_body(name_or_path)``: a posed body with ground truth (`bodyscan.poses.Body`);
  ``list_bodies()``: the names of the shipped library;
- ``preset(name, **overrides)`` and ``scan(body, config, seed=0)``: the simulated slit-laser scan
  (`bodyscan.simulator.Scan`: ``points`` (n, 3) metres, ``view_dir``, ``head``, ground truth);
- ``read_cloud(path)``: a cloud file (PLY, XYZ, PCD) without ground truth;
- ``reconstruct(points, method, params=None, view_dir=None)``: ``proposed`` or ``simple``
  (`bodyscan.recon.Reconstruction`: ``vertices``, ``faces``, ``point_sections``, ``fit``);
- ``score(vertices, faces, body, scan, ...)``: every metric of ``bodyscan bench``, one flat dict.

Example: scan the standing body, rebuild it with the paper's method, score it.

>>> import bodyscan
>>> body = bodyscan.load_body("standing")                                # doctest: +SKIP
>>> cloud = bodyscan.scan(body, bodyscan.preset("paper", k=1), seed=0)   # doctest: +SKIP
>>> rec = bodyscan.reconstruct(cloud.points, "proposed", view_dir=cloud.view_dir)   # doctest: +SKIP
>>> row = bodyscan.score(rec.vertices, rec.faces, body, cloud,
...                      point_sections=rec.point_sections, joints=rec.fit.joints)  # doctest: +SKIP
>>> round(row["spurious_area_fraction"], 3), round(row["fscore_seen@5mm"], 3)       # doctest: +SKIP
(0.022, 0.924)

Your own reconstruction method enters the benchmark as ``module:function``, an entry point of
the group ``bodyscan.methods`` or an external command: see `bodyscan.benchmarks.methods`.
"""

from __future__ import annotations

import importlib

#: Public name -> (module, attribute), resolved on first use.
_API = {
    "load_body": ("bodyscan.poses", "load_body"),
    "list_bodies": ("bodyscan.poses", "list_bodies"),
    "scan": ("bodyscan.simulator", "scan"),
    "preset": ("bodyscan.simulator", "preset"),
    "read_cloud": ("bodyscan.recon", "read_cloud"),
    "reconstruct": ("bodyscan.recon", "reconstruct"),
    "score": ("bodyscan.benchmarks.bench", "score"),
}

__all__ = sorted(_API)


def __getattr__(name: str):
    if name in _API:
        module, attr = _API[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'bodyscan' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
