"""Scores reconstructions against ground truth, compares methods, runs sweeps and writes reports."""


class BenchError(ValueError):
    """A benchmark request that cannot be carried out (bad option, missing ground truth...)."""


__all__ = ["BenchError"]
