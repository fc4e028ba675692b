"""TableLog: rows appended frame by frame across chunk boundaries read back exactly as appended."""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from roadtrack.testbed.pipeline import tables
from roadtrack.testbed.pipeline.tables import TableLog

COLUMNS = dict(frame=np.int64, x=np.float64, status=object, cov=np.float64)


def _frames(rng: np.random.Generator, n_frames: int) -> list[dict]:
    out = []
    for k in range(n_frames):
        m = int(rng.integers(0, 6))  # empty frames included
        out.append(dict(frame=np.full(m, k), x=rng.normal(size=m), status=np.array(["a", "bc"] * 3, object)[:m],
                        cov=rng.normal(size=(m, 4))))
    return out


@pytest.mark.parametrize("chunk_rows", [1, 3, 7, 4096])
def test_rows_read_back_exactly_across_chunks(chunk_rows):
    frames = _frames(np.random.default_rng(0), 40)
    log = TableLog(COLUMNS, chunk_rows=chunk_rows)
    for cols in frames:
        log.append(**cols)
    for name in COLUMNS:
        expected = np.concatenate([f[name] for f in frames])
        got = log.array(name)
        assert got.dtype == np.dtype(COLUMNS[name]) and got.shape == expected.shape
        assert np.array_equal(got, expected)  # bitwise: copies, no arithmetic
    assert log.n_rows == sum(len(f["x"]) for f in frames)
    table = log.table()
    assert table.num_rows == log.n_rows and table.schema.field("cov").type == pa.list_(pa.float64(), 4)
    assert table.column("x").to_numpy().tolist() == log.array("x").tolist()


def test_written_file_holds_every_row_in_bounded_row_groups(tmp_path, monkeypatch):
    monkeypatch.setattr(tables, "ROW_GROUP_ROWS", 10)
    log = TableLog(COLUMNS, chunk_rows=7)
    for cols in _frames(np.random.default_rng(1), 30):
        log.append(**cols)
    log.write(tmp_path / "t.parquet")
    meta = pq.ParquetFile(tmp_path / "t.parquet").metadata
    assert meta.num_rows == log.n_rows and meta.num_row_groups == -(-log.n_rows // 10)
    assert pq.read_table(tmp_path / "t.parquet").equals(log.table())
    # written one row group at a time: the very file the whole table gives
    pq.write_table(log.table(), tmp_path / "whole.parquet", row_group_size=10, use_dictionary=["frame", "status"])
    assert (tmp_path / "t.parquet").read_bytes() == (tmp_path / "whole.parquet").read_bytes()


@pytest.mark.parametrize("chunk_rows", [1, 3, 7, 4096])
def test_a_row_range_is_the_slice_of_the_whole_table(chunk_rows):
    log = TableLog(COLUMNS, chunk_rows=chunk_rows)
    for cols in _frames(np.random.default_rng(2), 40):
        log.append(**cols)
    whole = log.table()
    for start, stop in [(0, log.n_rows), (0, 1), (5, 17), (7, 14), (log.n_rows - 1, log.n_rows)]:
        assert log.table(start, stop).equals(whole.slice(start, stop - start))


def test_empty_logs_keep_their_column_shapes():
    fresh = TableLog(COLUMNS)
    assert fresh.array("cov").shape == (0,) and fresh.table().num_rows == 0
    empty_frames = TableLog(COLUMNS)
    empty_frames.append(frame=np.zeros(0), x=np.zeros(0), status=np.zeros(0, object), cov=np.zeros((0, 4)))
    assert empty_frames.array("cov").shape == (0, 4)
    assert empty_frames.table().schema.field("cov").type == pa.list_(pa.float64(), 4)


def test_malformed_rows_are_rejected():
    log = TableLog(COLUMNS)
    log.append(frame=[0], x=[1.0], status=np.array(["a"], object), cov=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="unequal length"):
        log.append(frame=[1, 1], x=[1.0], status=np.array(["a"], object), cov=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="column cov"):
        log.append(frame=[1], x=[1.0], status=np.array(["a"], object), cov=np.zeros((1, 3)))
    assert log.n_rows == 1
