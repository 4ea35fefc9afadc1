"""`bodyscan fit` and `bodyscan reconstruct`: placeholders until they land."""


def register(sub) -> None:
    """Add recon's commands to ``sub`` (none yet)."""
