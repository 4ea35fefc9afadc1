"""Surface reconstruction of a human body from a point cloud, by posture estimation and clustering.

Works on any scanner's cloud: imports nothing from `poses`, `simulator` or `benchmarks`.
"""


class ReconError(ValueError):
    """A cloud or parameter that the reconstruction cannot use."""


__all__ = ["ReconError"]

from .params import ClusterParams, ReconParams, SurfaceParams  # noqa: E402  (after ReconError)
from .pipeline import Reconstruction, reconstruct, write_mesh  # noqa: E402

__all__ += ["ClusterParams", "ReconParams", "SurfaceParams", "Reconstruction", "reconstruct", "write_mesh"]

from .cloud import Cloud, read_cloud  # noqa: E402
from .posture.fit import FitParams, estimate_posture, fit_section  # noqa: E402

__all__ += ["Cloud", "read_cloud", "FitParams", "estimate_posture", "fit_section"]
