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


def expand_bodies(specs) -> list[str]:
    """Body specs with every folder replaced by its body files (``*.npz``, sorted).

    Parameters
    ----------
    specs : iterable of str
        Library names, body files, or folders of body files (a corpus from `poses sample`);
        empty: every shipped body.

    Returns
    -------
    bodies : list of str
        Library names and file paths, for `load_body`.
    """
    out = []
    for spec in specs:
        path = Path(spec)
        if path.is_dir():
            files = sorted(str(p) for p in path.glob("*.npz"))
            if not files:
                from .body import BodyError
                raise BodyError(f"{path}: a folder without body files (*.npz)")
            out += files
        else:
            out.append(str(spec))
    return out or list_bodies()
