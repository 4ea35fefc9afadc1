"""A slit-laser range-finder simulator: scans a posed body mesh with real self-occlusion.

>>> import poses, simulator
>>> body = poses.load_body("standing")
>>> cloud = simulator.scan(body, simulator.preset("paper", k=2))      # parallel, 10 mm, front + rear
>>> simulator.write_cloud(cloud, "standing_k2.ply")                    # doctest: +SKIP
>>> scanner = simulator.Scanner(body)                                  # one Embree scene, many scans
>>> clouds = [scanner.scan(simulator.preset("scanner", k=k)) for k in (1, 2, 3)]
"""


class ScanError(ValueError):
    """A scan request that cannot be carried out (bad mesh, bad configuration)."""


from .config import HEAD_LAYOUTS, PRESETS, Head, ScannerConfig, head_layout, preset  # noqa: E402
from .scan import Scan, Scanner, ScanWarning, scan  # noqa: E402
from .cloud_io import read_scan, write_cloud  # noqa: E402

__all__ = ["ScanError", "ScanWarning", "Head", "ScannerConfig", "head_layout", "HEAD_LAYOUTS",
           "PRESETS", "preset", "Scan", "Scanner", "scan", "write_cloud", "read_scan"]
