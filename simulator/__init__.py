"""A slit-laser range-finder simulator: scans a posed body mesh with real self-occlusion."""


class ScanError(ValueError):
    """A scan request that cannot be carried out (bad mesh, bad configuration)."""


__all__ = ["ScanError"]
