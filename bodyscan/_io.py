"""Output files, written so that nothing is lost: atomic replacement and checks before the work.

Every file the project writes goes through `atomic_write`: the content is written to a temporary
file in the same folder, flushed and fsynced, then renamed over the final name (``os.replace``,
atomic on POSIX). A reader sees the old file or the complete new one, never a partial one; a
failed write (disk full, a file-size limit, an interrupt) leaves the old file as it was and
removes the temporary file. Two writers racing on one path leave one of the two files, whole.

`check_out` is called by every command on its ``--out`` before any computation, so that a path
that cannot be written is reported in one line before minutes of work.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

#: Prefix of temporary files (a killed writer's leftovers can be found and removed by it).
TMP_PREFIX = ".tmp-"


class OutputError(ValueError):
    """An output path that cannot be written (a user error: one line, exit code 2)."""


def atomic_write(path, write, *, error=OutputError):
    """Write ``path`` through ``write(tmp_path)``, then rename it over ``path``.

    Parameters
    ----------
    path : str or path
        The final file. Its folder must exist.
    write : callable
        ``write(tmp)`` writes the whole content to the path ``tmp`` (a str with the same suffix
        as ``path``, so that writers choosing a format by suffix, or adding one, behave).
    error : type
        Exception raised (one line naming ``path``) when the write fails with an `OSError`.

    Returns
    -------
    Path
        ``path``.
    """
    final = Path(path)
    tmp = final.with_name(f"{TMP_PREFIX}{os.getpid()}-{id(write):x}-{final.name}")
    try:
        write(str(tmp))
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, final)
    except OSError as exc:
        _remove(tmp)
        raise error(f"{final}: cannot write ({exc.strerror or exc}); the previous file, if any, "
                    "is unchanged") from None
    except BaseException:
        _remove(tmp)
        raise
    return final


def _remove(tmp: Path) -> None:
    try:
        tmp.unlink(missing_ok=True)
    except OSError:
        pass


def write_bytes(path, data: bytes, *, error=OutputError) -> Path:
    """Write ``data`` to ``path`` atomically (see `atomic_write`)."""
    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(data)
    return atomic_write(path, write, error=error)


def write_text(path, text: str, *, error=OutputError) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes(path, text.encode("utf-8"), error=error)


def write_json(path, data, *, indent=1, error=OutputError, **kw) -> Path:
    """Write ``data`` as strict JSON (NaN and infinities become null) to ``path`` atomically."""
    return write_text(path, dumps(data, indent=indent, **kw) + "\n", error=error)


def dumps(data, **kw) -> str:
    """Strict JSON text of ``data``: NaN and infinities become ``null``, numpy scalars and arrays
    plain numbers and lists, anything else its ``str``."""
    return json.dumps(strict(data), allow_nan=False, **kw)


def strict(value):
    """``value`` with every non-finite float replaced by None, numpy values by Python ones."""
    if isinstance(value, dict):
        return {str(k) if not isinstance(k, str) else k: strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    tolist = getattr(value, "tolist", None)   # numpy scalars and arrays
    if tolist is not None:
        return strict(tolist())
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    try:
        return strict(float(value))
    except (TypeError, ValueError):
        return str(value)


def check_out(path, *, option: str = "--out", suffixes=(), folder: bool = False, make: bool = True,
              error=OutputError) -> Path:
    """Check an output path before any work; create its folder (or itself, ``folder=True``).

    Parameters
    ----------
    path : str or path
    option : str
        The option's name, for the message.
    suffixes : tuple of str
        Accepted file suffixes (lower case, with the dot); empty: any.
    folder : bool
        ``path`` is an output folder (created), not a file.
    make : bool
        Create the missing folders (else a missing folder is an error).

    Raises
    ------
    error
        The path is a folder where a file is asked (or a file where a folder is), lies under an
        existing file, has the wrong suffix, or its folder cannot be made or written.
    """
    path = Path(path)
    if not str(path).strip():
        raise error(f"{option}: empty path")
    if folder:
        target, parent = path, path
        if path.exists() and not path.is_dir():
            raise error(f"{option} {path}: is a file, not a folder")
    else:
        if path.is_dir() or str(path).endswith(("/", os.sep)):
            raise error(f"{option} {path}: is a folder; give a file name")
        if suffixes and path.suffix.lower() not in suffixes:
            raise error(f"{option} {path}: name it *{' or *'.join(suffixes)}")
        target, parent = path, path.parent
    # the nearest existing ancestor must be a folder we can write into
    probe = parent
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise error(f"{option} {path}: {probe} is a file, not a folder")
    if not parent.exists():
        if not make:
            raise error(f"{option} {path}: folder {parent} does not exist")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise error(f"{option} {path}: cannot make folder {parent} ({exc.strerror or exc})") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise error(f"{option} {path}: folder {parent} is not writable")
    if not folder and target.exists() and not os.access(target, os.W_OK) and not os.access(parent, os.W_OK):
        raise error(f"{option} {path}: not writable")
    return path
