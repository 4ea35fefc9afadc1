"""The shipped pose library: body files in ``poses/data/``, found by name."""

from __future__ import annotations

from pathlib import Path

#: Folder of the shipped body files.
DATA_DIR = Path(__file__).resolve().parent / "data"


def list_bodies() -> list[str]:
    """Names of the shipped bodies, sorted."""
    return sorted(p.stem for p in DATA_DIR.glob("*.npz"))


def find_body(name: str) -> Path | None:
    """Path of the shipped body called ``name``, or None."""
    path = DATA_DIR / f"{name}.npz"
    return path if path.is_file() else None
