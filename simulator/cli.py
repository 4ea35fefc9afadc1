"""`bodyscan scan`: placeholder until the simulator lands."""


def register(sub) -> None:
    """Add the ``scan`` command to ``sub`` (none yet)."""
