"""bodyscan: a benchmark suite for human-body surface reconstruction from range scans.

The stages live in subpackages, and data flows one way through them:
`bodyscan.poses` -> `bodyscan.simulator` -> `bodyscan.recon` -> `bodyscan.benchmarks`.
The few functions a script needs are here, imported lazily so ``import bodyscan`` stays light:

>>> import bodyscan
>>> body = bodyscan.load_body("standing")                     # doctest: +SKIP
>>> cloud = bodyscan.scan(body, bodyscan.preset("paper", k=1), seed=0)   # doctest: +SKIP
>>> rec = bodyscan.reconstruct(cloud.points, "proposed", view_dir=cloud.view_dir)   # doctest: +SKIP
>>> row = bodyscan.score(rec.vertices, rec.faces, body, cloud)    # doctest: +SKIP
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
