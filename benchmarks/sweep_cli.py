"""Placeholder: subcommands added by a later issue."""


def register(sub) -> None:
    """Add this module's subcommands to ``sub`` (none yet)."""
