"""The results store: atomic parts, union of columns, kept meshes, leftovers of a killed writer."""

import json
import os

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from bodyscan.benchmarks.store import ResultStore


def test_rows_round_trip_with_the_union_of_columns(tmp_path):
    store = ResultStore(tmp_path / "s").open_for_writing()
    store.put({"job_id": "a1", "status": "ok", "fscore": 0.9, "n": 3, "flag": True,
               "pairs": {"chest|upper_arm_l": 1.5}, "vec": np.array([1.0, 2.0])})
    store.put({"job_id": "b2", "status": "error", "error": "boom", "traceback": "Trace..."})
    table = store.read()
    assert list(table["job_id"]) == ["a1", "b2"]
    assert table.loc[0, "fscore"] == 0.9 and pd.isna(table.loc[1, "fscore"])
    assert table.loc[1, "error"] == "boom" and table.loc[0, "n"] == 3
    assert json.loads(table.loc[0, "pairs"]) == {"chest|upper_arm_l": 1.5}
    assert json.loads(table.loc[0, "vec"]) == [1.0, 2.0]
    assert store.finished() == {"a1", "b2"}
    assert store.finished(include_failed=False) == {"a1"}


def test_rewriting_a_job_replaces_its_row(tmp_path):
    store = ResultStore(tmp_path).open_for_writing()
    store.put({"job_id": "j", "status": "error"})
    store.put({"job_id": "j", "status": "ok", "x": 1.0})
    table = store.read()
    assert len(table) == 1 and table.loc[0, "status"] == "ok"


def test_writes_are_atomic_and_leftovers_are_cleaned(tmp_path, monkeypatch):
    store = ResultStore(tmp_path).open_for_writing()
    store.put({"job_id": "good", "status": "ok"})

    # a writer that dies half-way leaves at most a temporary file, never a part
    def broken_write(table, path, **kwargs):
        with open(path, "wb") as handle:
            handle.write(b"PAR1 half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(pq, "write_table", broken_write)
    with pytest.raises(KeyboardInterrupt):
        store.put({"job_id": "half", "status": "ok"})
    monkeypatch.undo()
    assert store.finished() == {"good"}
    assert not list(store.parts.glob(".tmp-*"))        # cleaned up by the writer itself
    # a writer killed outright (no cleanup): the leftover is ignored and removed on reopening
    (store.parts / f".tmp-{os.getpid() + 1}-dead.parquet").write_bytes(b"PAR1 junk")
    assert store.finished() == {"good"} and len(store.read()) == 1
    ResultStore(tmp_path).open_for_writing()
    assert not list(store.parts.glob(".tmp-*"))


def test_meshes_round_trip(tmp_path):
    store = ResultStore(tmp_path).open_for_writing()
    mesh = {"vertices": np.random.default_rng(0).random((5, 3)), "faces": np.array([[0, 1, 2]]),
            "face_section": np.array([3], np.int8), "spurious": np.array([True]),
            "closeups": {"armpit_l": (np.array([0.1, 0.0, 1.3]), 0.12)}}
    store.put_mesh("j1", mesh)
    assert store.mesh_ids() == {"j1"}
    back = store.get_mesh("j1")
    assert np.allclose(back["vertices"], mesh["vertices"], atol=1e-6)
    assert back["faces"].tolist() == [[0, 1, 2]] and back["spurious"].tolist() == [True]
    center, radius = back["closeups"]["armpit_l"]
    assert np.allclose(center, [0.1, 0.0, 1.3]) and radius == 0.12
    store.drop_mesh("j1")
    assert store.mesh_ids() == set()


def test_empty_store_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no sweep results"):
        ResultStore(tmp_path / "nothing").read()


def test_bad_job_id_is_rejected(tmp_path):
    store = ResultStore(tmp_path).open_for_writing()
    with pytest.raises(ValueError, match="job id"):
        store.put({"job_id": "../escape", "status": "ok"})


def test_one_file_table_is_a_cache_of_the_parts(tmp_path):
    store = ResultStore(tmp_path).open_for_writing()
    for i in range(5):
        store.put({"job_id": f"j{i}", "status": "ok", "x": float(i)})
    first = store.read()
    cache = tmp_path / "results.parquet"
    assert cache.is_file() and pq.read_table(cache).num_rows == 5
    # a new part and a rewritten part are picked up; the rest comes from the cache
    store.put({"job_id": "j5", "status": "ok", "x": 5.0})
    os.utime(store.parts / "j0.parquet", ns=(1, 1))      # an older part ...
    store.put({"job_id": "j1", "status": "error", "error": "redone"})   # ... and a rewritten one
    table = store.read().set_index("job_id")
    assert len(table) == 6 and table.loc["j1", "status"] == "error" and table.loc["j5", "x"] == 5.0
    assert table.loc["j0", "x"] == 0.0
    assert pq.read_table(cache).num_rows == 6
    # the cache is only a cache: damaged or deleted, the parts give the same table
    cache.write_bytes(b"not parquet")
    pd.testing.assert_frame_equal(store.read(), table.reset_index())
    cache.unlink()
    pd.testing.assert_frame_equal(store.read(compact=False), table.reset_index())
    assert not cache.exists()
    assert len(first) == 5
