"""The run's data as Parquet tables (columns documented in README.md, "Output files").

Rows are copied per frame into preallocated column chunks; ``table()`` wraps the chunks without a copy.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

CHUNK_ROWS = 4096
ROW_GROUP_ROWS = 8192


class TableLog:
    """Columns appended per frame; ``array(name)`` and ``table()`` return the rows appended so far.

    Each column is a list of preallocated chunks of ``chunk_rows`` rows, filled in order: a run of F frames
    allocates O(F / chunk_rows) blocks. Keeping one small array per column per frame instead (thousands of
    small long-lived blocks, allocated between each frame's large freed LiDAR temporaries) fragments the C
    heap: the small blocks pin the freed space so the next frame's large temporaries do not fit in it, and
    a run's RSS grew by 0.5-0.7 MB per frame (benchmarks/bench_memory.py).
    """

    def __init__(self, columns: dict[str, type], chunk_rows: int = CHUNK_ROWS):
        self.columns = columns
        self.chunk_rows = chunk_rows
        self.n_rows = 0
        self._chunks: dict[str, list[np.ndarray]] = {name: [] for name in columns}
        self._row_shapes: dict[str, tuple[int, ...]] = {}  # set by the first append, e.g. (16,) for a covariance

    def append(self, **cols: np.ndarray) -> None:
        n = {len(np.asarray(v)) for v in cols.values()}
        if len(n) != 1:
            raise ValueError(f"columns of unequal length: { {k: len(np.asarray(v)) for k, v in cols.items()} }")
        rows = {name: np.asarray(cols[name], dtype=dtype) for name, dtype in self.columns.items()}
        if not self._row_shapes:
            self._row_shapes = {name: a.shape[1:] for name, a in rows.items()}
        for name, a in rows.items():
            if a.shape[1:] != self._row_shapes[name]:
                raise ValueError(f"column {name}: rows of shape {a.shape[1:]}, earlier {self._row_shapes[name]}")
        m, done = n.pop(), 0
        while done < m:
            if self.n_rows == len(self._chunks[next(iter(self.columns))]) * self.chunk_rows:  # all chunks full
                for name, chunks in self._chunks.items():
                    chunks.append(np.empty((self.chunk_rows, *self._row_shapes[name]), self.columns[name]))
            at = self.n_rows % self.chunk_rows
            take = min(m - done, self.chunk_rows - at)
            for name, a in rows.items():
                self._chunks[name][-1][at : at + take] = a[done : done + take]
            done += take
            self.n_rows += take

    def truncate(self, n_rows: int) -> None:
        """Keep the first ``n_rows`` rows (e.g. the frames completed before an interrupt; ``n_rows`` ≤ ``n_rows``
        now). Chunks past them are released."""
        if not 0 <= n_rows <= self.n_rows:
            raise ValueError(f"cannot truncate {self.n_rows} rows to {n_rows}")
        keep = -(-n_rows // self.chunk_rows)  # chunks holding rows
        for chunks in self._chunks.values():
            del chunks[keep:]
        self.n_rows = n_rows

    def _filled(self, name: str) -> list[np.ndarray]:
        """The chunks of column ``name`` cut to the rows appended (views, no copy)."""
        chunks = self._chunks[name]
        if not chunks:
            return []
        fill = self.n_rows - (len(chunks) - 1) * self.chunk_rows
        return [*chunks[:-1], chunks[-1][:fill]]

    def array(self, name: str) -> np.ndarray:
        """Column ``name`` (a new array): (n_rows,), or (n_rows, width) for a fixed-size list column."""
        if name not in self._row_shapes:  # nothing appended yet
            return np.zeros(0, dtype=self.columns[name])
        parts = self._filled(name)
        return np.concatenate(parts) if parts else np.empty((0, *self._row_shapes[name]), self.columns[name])

    def table(self, start: int = 0, stop: int | None = None) -> pa.Table:
        """Rows ``start:stop`` (default all) as a pyarrow Table, one record batch per chunk they touch (numeric
        columns wrap the chunks, no copy; object columns are converted, so only these rows' strings are built)."""
        stop = self.n_rows if stop is None else stop
        data = {}
        for name in self.columns:
            parts = self._rows(name, start, stop) or [self.array(name)]
            if parts[0].ndim == 2:  # fixed-size list column (e.g. a flattened covariance)
                width = parts[0].shape[1]
                arrays = [pa.FixedSizeListArray.from_arrays(pa.array(p.reshape(-1)), width) for p in parts]
            else:
                arrays = [pa.array(p) for p in parts]
            data[name] = pa.chunked_array(arrays)
        return pa.table(data)

    def _rows(self, name: str, start: int, stop: int) -> list[np.ndarray]:
        """Views of column ``name``'s rows ``start:stop``, one per chunk they touch ([] for no rows)."""
        parts = []
        for i, chunk in enumerate(self._filled(name)):
            lo, hi = max(start - i * self.chunk_rows, 0), min(stop - i * self.chunk_rows, len(chunk))
            if lo < hi:
                parts.append(chunk[lo:hi])
        return parts

    def dictionary_columns(self) -> list[str]:
        """The columns Parquet dictionary-encodes: all but the float ones. Measured floats (positions,
        covariances) hardly repeat, so their dictionary is dropped after its first page anyway, and building it
        took the writer's memory up by 50 MB at one row group of a 16-float covariance column."""
        return [name for name, dtype in self.columns.items() if np.dtype(dtype).kind != "f"]

    def write(self, path: Path) -> None:
        """Write the rows to Parquet in row groups of at most ``ROW_GROUP_ROWS`` rows, one row group at a time:
        the strings of object columns (a long run's diagnostics: about 700,000 names) are converted per row group,
        not for the whole table at once, so a long run's file is written in bounded memory. The file is the one
        ``pq.write_table(self.table(), path, row_group_size=ROW_GROUP_ROWS, use_dictionary=dictionary_columns())``
        writes."""
        options = dict(row_group_size=ROW_GROUP_ROWS, use_dictionary=self.dictionary_columns())
        if self.n_rows == 0:
            pq.write_table(self.table(), path, **options)
            return
        parts = (self.table(start, min(start + ROW_GROUP_ROWS, self.n_rows))
                 for start in range(0, self.n_rows, ROW_GROUP_ROWS))
        first = next(parts)
        with pq.ParquetWriter(path, first.schema, use_dictionary=options["use_dictionary"]) as writer:
            writer.write_table(first, row_group_size=ROW_GROUP_ROWS)
            for part in parts:
                if not part.schema.equals(first.schema):  # e.g. an object column all None in one group
                    break
                writer.write_table(part, row_group_size=ROW_GROUP_ROWS)
            else:
                return
        pq.write_table(self.table(), path, **options)  # the whole table's own types


def truth_log() -> TableLog:
    return TableLog(dict(frame=np.int64, time=np.float64, vehicle_id=np.int64, name=object, is_ego=bool,
                         x=np.float64, y=np.float64, heading=np.float64, vx=np.float64, vy=np.float64,
                         length=np.float64, width=np.float64, height=np.float64, lane=np.int64,
                         crashed=bool, n_points=np.int64, in_range=bool))


def detections_log() -> TableLog:
    return TableLog(dict(frame=np.int64, time=np.float64, x=np.float64, y=np.float64, provenance=np.int64,
                         n_points=np.int64, length=np.float64, width=np.float64, height=np.float64,
                         r_xx=np.float64, r_xy=np.float64, r_yy=np.float64))


def sensor_detections_log() -> TableLog:
    """A further sensor's detections (``detections-<sensor>.parquet``): frame, time, the position each implies
    x, y [m] (its measurement model's ``position_of``) and z (m,) as measured (e.g. range [m], azimuth [rad],
    range-rate [m/s])."""
    return TableLog(dict(frame=np.int64, time=np.float64, x=np.float64, y=np.float64, z=np.float64))


def tracks_log(box: bool = False) -> TableLog:
    """The tracks table; with ``box`` (box tracking) also each track's heading [rad], length and width [m]."""
    cols = dict(frame=np.int64, time=np.float64, track_id=np.int64, status=object, x=np.float64, y=np.float64,
                vx=np.float64, vy=np.float64, score=np.float64, regime=object, cov=np.float64)
    if box:
        cols.update(heading=np.float64, length=np.float64, width=np.float64)
    return TableLog(cols)


def diagnostics_log() -> TableLog:
    """Long format: frame, time, track_id, name (e.g. "nis", "psi_z_0", "mu_1"), value."""
    return TableLog(dict(frame=np.int64, time=np.float64, track_id=np.int64, name=object, value=np.float64))
