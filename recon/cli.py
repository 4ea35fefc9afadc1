"""recon's commands: `bodyscan fit` (posture estimation) and `bodyscan reconstruct` (surfaces)."""


def register(sub) -> None:
    """Add recon's commands to the ``bodyscan`` subparsers ``sub``."""
    from . import fit_cli, reconstruct_cli

    fit_cli.register(sub)
    reconstruct_cli.register(sub)
