"""The results store of a sweep: one Parquet part per finished job, written atomically, never lost.

Layout of a sweep folder ``DIR``::

    DIR/sweep.yaml           the sweep file of the latest run (a copy)
    DIR/meta.json            run metadata: versions, git commit, engine, start times
    DIR/parts/<job>.parquet  one row per finished job (metrics, or the error and its traceback)
    DIR/results.parquet      all parts in one table: a cache rebuilt from the parts (safe to delete)
    DIR/meshes/<job>.npz     reconstructed meshes kept for pictures (see `ResultStore.put_mesh`)
    DIR/quarantine/          parts that could not be read, set aside (their jobs count as not done)

Every file is written to a temporary name in the same folder, flushed to disk, then renamed over
its final name (``os.replace``, atomic on POSIX): a reader, or a sweep killed at any instant, sees a
job's part either whole or not at all. A part's presence is what "this job is finished" means, so a
restarted sweep skips exactly the jobs whose parts exist. Temporary files left by a killed writer
(``.tmp-*``) are removed when the store is opened for writing.

Job parts are written by the one process that drives the sweep, as results arrive from the engine,
so workers (local processes or a Dask cluster) need no shared file system.

Reading hundreds of one-row Parquet files is slow (milliseconds each), so `ResultStore.read` keeps
``results.parquet``: the union of the parts it has read, each row tagged with its part's size and
modification time. A later read takes the rows whose parts are unchanged from it and reads only
new or rewritten parts. The parts stay the truth; the cache only saves time.
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from pathlib import Path

import numpy as np

#: Columns every part has; the rest are parameters (``scanner.*``, ``recon.*``) and metrics.
BASE_COLUMNS = ("job_id", "scan_id", "body", "seed", "method", "status", "error", "traceback",
                "wall_s", "worker", "finished_at")

_SIG = "_part_signature"   # column of results.parquet: the part's "size:mtime_ns"
_JOB_ID = re.compile(r"^[0-9a-zA-Z_-]{1,128}$")


class StoreWarning(UserWarning):
    """A damaged part was set aside."""


class ResultStore:
    """Results of one sweep folder.

    Parameters
    ----------
    root : str or Path
        The sweep folder (created by `open_for_writing`).
    """

    def __init__(self, root):
        self.root = Path(root)
        self.parts = self.root / "parts"
        self.meshes = self.root / "meshes"
        self.quarantine = self.root / "quarantine"

    # -- writing ------------------------------------------------------------------------------

    def open_for_writing(self) -> "ResultStore":
        """Create the folders and remove temporary files left by a killed writer; returns self."""
        for folder in (self.root, self.parts, self.meshes):
            folder.mkdir(parents=True, exist_ok=True)
            for tmp in folder.glob(".tmp-*"):
                tmp.unlink(missing_ok=True)
        return self

    def put(self, row: dict) -> Path:
        """Write one job's row as ``parts/<job_id>.parquet``, atomically.

        Parameters
        ----------
        row : dict
            Must hold ``job_id``; values are scalars (numbers, strings, bools, None); anything
            else (lists, dicts, arrays) is stored as a JSON string.
        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        job_id = str(row.get("job_id", ""))
        if not _JOB_ID.match(job_id):
            raise ValueError(f"store: bad job id {job_id!r}")
        clean = {str(k): _scalar(v) for k, v in row.items()}
        table = pa.Table.from_pylist([clean])
        return _atomic_write(self.parts / f"{job_id}.parquet",
                             lambda path: pq.write_table(table, path))

    def put_mesh(self, job_id: str, mesh: dict) -> Path:
        """Keep a reconstructed mesh for pictures, as ``meshes/<job_id>.npz`` (atomic).

        Parameters
        ----------
        mesh : dict of str to array
            ``vertices`` (n, 3) float, ``faces`` (m, 3) int, ``face_section`` (m,) int,
            ``spurious`` (m,) bool, ``bridging`` (m,) bool, and ``closeups``: a dict
            {name: (center (3,), radius)} stored as JSON.
        """
        arrays = {k: np.asarray(v) for k, v in mesh.items() if k != "closeups"}
        closeups = {k: [list(map(float, c)), float(r)] for k, (c, r) in
                    (mesh.get("closeups") or {}).items()}
        arrays["closeups_json"] = np.array(json.dumps(closeups))
        if "vertices" in arrays:
            arrays["vertices"] = arrays["vertices"].astype(np.float32)
        return _atomic_write(self.meshes / f"{job_id}.npz",
                             lambda path: np.savez_compressed(path, **arrays))

    def drop_mesh(self, job_id: str) -> None:
        """Forget a kept mesh (no error when there is none)."""
        (self.meshes / f"{job_id}.npz").unlink(missing_ok=True)

    def write_json(self, name: str, data: dict) -> Path:
        """Write ``DIR/name`` as JSON, atomically."""
        from bodyscan._io import dumps

        text = dumps(data, indent=2, sort_keys=True)   # strict: NaN becomes null
        return _atomic_write(self.root / name, lambda path: Path(path).write_text(text))

    def write_text(self, name: str, text: str) -> Path:
        """Write ``DIR/name``, atomically."""
        return _atomic_write(self.root / name, lambda path: Path(path).write_text(text))

    # -- reading ------------------------------------------------------------------------------

    def finished(self, *, include_failed: bool = True) -> set[str]:
        """Ids of the jobs whose parts exist (with ``include_failed=False``, only those that
        succeeded)."""
        if not self.parts.is_dir() or not self._listing():
            return set()
        try:
            table = self.read(columns=["job_id", "status"])   # sets damaged parts aside
        except FileNotFoundError:                             # every part was damaged
            return set()
        if include_failed:
            return set(table["job_id"]) if "job_id" in table.columns else set()
        return set(table.loc[table["status"] == "ok", "job_id"])

    def read(self, columns=None, *, compact: bool = True):
        """All rows as a `pandas.DataFrame` (columns are the union over parts; missing is NaN).

        Parameters
        ----------
        columns : list of str, optional
            Keep only these columns (those that exist).
        compact : bool
            Refresh ``results.parquet`` when parts were read that it did not hold.

        Raises
        ------
        FileNotFoundError
            ``DIR`` holds no results.
        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        listing = self._listing()
        if not listing:
            raise FileNotFoundError(f"{self.root}: no sweep results here (expected "
                                    f"{self.parts}/*.parquet; run `bodyscan sweep` first)")
        tables, have = [], set()
        cached = self._read_cache()
        if cached is not None:
            ids = cached.column("job_id").to_pylist()
            sigs = cached.column(_SIG).to_pylist()
            keep = [listing.get(i) == sig for i, sig in zip(ids, sigs)]
            cached = cached.filter(pa.array(keep))
            have = {i for i, k in zip(ids, keep) if k}
            tables.append(cached)
        new = [stem for stem in listing if stem not in have]
        for stem in list(new):
            table = self._read_part(stem)
            if table is None:
                new.remove(stem)
                continue
            tables.append(table.append_column(_SIG, pa.array([listing[stem]], pa.string())))
        if not tables:
            raise FileNotFoundError(f"{self.root}: no readable sweep results here (every part was set "
                                    f"aside in {self.quarantine}; run `bodyscan sweep` again)")
        table = pa.concat_tables(tables, promote_options="permissive")
        if compact and (new or len(table) != (cached.num_rows if cached is not None else -1)):
            try:
                _atomic_write(self.root / "results.parquet",
                              lambda path: pq.write_table(table, path))
            except (OSError, ValueError):   # a read-only folder: read without the cache
                pass
        frame = table.drop_columns([_SIG]).to_pandas()
        if columns is not None:
            frame = frame[[c for c in columns if c in frame.columns]]
        return frame.sort_values("job_id", kind="stable").reset_index(drop=True) \
            if "job_id" in frame.columns else frame

    def _read_part(self, stem: str):
        """The table of part ``stem``, or None after moving an unreadable part to quarantine/."""
        import pyarrow.parquet as pq

        path = self.parts / f"{stem}.parquet"
        try:
            table = pq.ParquetFile(path).read()
            ids = table.column("job_id").to_pylist() if "job_id" in table.column_names else []
            if ids != [stem]:
                raise ValueError(f"holds job ids {ids[:3]}, expected [{stem!r}]")
            return table
        except FileNotFoundError:      # removed meanwhile
            return None
        except Exception as exc:       # damaged: truncated, not Parquet, wrong content
            self.quarantine.mkdir(parents=True, exist_ok=True)
            target = self.quarantine / path.name
            try:
                os.replace(path, target)
            except OSError:
                target = path           # a read-only store: skip the part, leave it
            warnings.warn(f"{path}: unreadable result part ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:160]}) set aside as {target}; its job "
                          "counts as not done", StoreWarning, stacklevel=3)
            return None

    def quarantined(self) -> list[str]:
        """Names of the parts set aside as unreadable."""
        return sorted(p.name for p in self.quarantine.glob("*.parquet")) if self.quarantine.is_dir() else []

    def _listing(self) -> dict:
        """{job id: "size:mtime_ns"} of the finished parts."""
        if not self.parts.is_dir():
            return {}
        out = {}
        with os.scandir(self.parts) as entries:
            for entry in entries:
                if entry.name.endswith(".parquet") and not entry.name.startswith("."):
                    st = entry.stat()
                    out[entry.name[:-len(".parquet")]] = f"{st.st_size}:{st.st_mtime_ns}"
        return out

    def _read_cache(self):
        import pyarrow.parquet as pq

        path = self.root / "results.parquet"
        try:
            table = pq.ParquetFile(path).read()
        except (OSError, ValueError):   # missing or damaged: rebuilt from the parts
            return None
        return table if {_SIG, "job_id"} <= set(table.column_names) else None

    def mesh_ids(self) -> set[str]:
        """Ids of the jobs whose meshes are kept."""
        return {p.stem for p in self.meshes.glob("[!.]*.npz")} if self.meshes.is_dir() else set()

    def get_mesh(self, job_id: str) -> dict:
        """A kept mesh, as `put_mesh` took it (``closeups`` back as a dict)."""
        with np.load(self.meshes / f"{job_id}.npz") as data:
            mesh = {k: data[k] for k in data.files if k != "closeups_json"}
            text = str(data["closeups_json"]) if "closeups_json" in data.files else "{}"
        closeups = json.loads(text)
        mesh["closeups"] = {k: (np.asarray(c), float(r)) for k, (c, r) in closeups.items()}
        return mesh

    def read_json(self, name: str) -> dict:
        path = self.root / name
        return json.loads(path.read_text()) if path.is_file() else {}


def _scalar(value):
    """A Parquet-friendly scalar: numbers, strings, bools and None as they are, the rest as JSON."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, np.ndarray) and value.ndim == 0:
        return _scalar(value.item())
    return json.dumps(value, sort_keys=True, default=_json_default)


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


def _atomic_write(final: Path, write) -> Path:
    """Call ``write(tmp_path)``, fsync, then rename over ``final`` (`bodyscan._io.atomic_write`).

    The temporary name keeps ``final``'s suffix (``np.savez`` would add ``.npz`` otherwise)."""
    from bodyscan._io import atomic_write

    return atomic_write(final, write, error=_write_error())


def _write_error():
    from . import BenchError
    return BenchError
