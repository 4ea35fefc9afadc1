"""Placeholder: this command lands with its issue."""


def register(sub) -> None:
    """Add this module's command to ``sub`` (none yet)."""
