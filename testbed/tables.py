"""The run's data as Parquet tables (columns documented in README.md, "Output files").

Rows are accumulated per frame as NumPy blocks and concatenated once at the end.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


class TableLog:
    """Column blocks appended per frame; ``table()`` builds a pyarrow Table."""

    def __init__(self, columns: dict[str, type]):
        self.columns = columns
        self.blocks: dict[str, list[np.ndarray]] = {c: [] for c in columns}

    def append(self, **cols: np.ndarray) -> None:
        n = {len(np.asarray(v)) for v in cols.values()}
        if len(n) != 1:
            raise ValueError(f"columns of unequal length: { {k: len(np.asarray(v)) for k, v in cols.items()} }")
        for name, dtype in self.columns.items():
            self.blocks[name].append(np.asarray(cols[name], dtype=dtype))

    def array(self, name: str) -> np.ndarray:
        blocks = self.blocks[name]
        if not blocks:
            return np.zeros(0, dtype=self.columns[name])
        return np.concatenate(blocks)

    def table(self) -> pa.Table:
        data = {}
        for name in self.columns:
            arr = self.array(name)
            if arr.ndim == 2:  # fixed-size list column (e.g. a flattened covariance)
                data[name] = pa.FixedSizeListArray.from_arrays(pa.array(arr.reshape(-1)), arr.shape[1])
            else:
                data[name] = pa.array(arr)
        return pa.table(data)

    def write(self, path: Path) -> None:
        pq.write_table(self.table(), path)


def truth_log() -> TableLog:
    return TableLog(dict(frame=np.int64, time=np.float64, vehicle_id=np.int64, name=object, is_ego=bool,
                         x=np.float64, y=np.float64, heading=np.float64, vx=np.float64, vy=np.float64,
                         length=np.float64, width=np.float64, height=np.float64, lane=np.int64,
                         crashed=bool))


def detections_log() -> TableLog:
    return TableLog(dict(frame=np.int64, time=np.float64, x=np.float64, y=np.float64, provenance=np.int64,
                         n_points=np.int64, length=np.float64, width=np.float64, height=np.float64))


def tracks_log() -> TableLog:
    return TableLog(dict(frame=np.int64, time=np.float64, track_id=np.int64, status=object, x=np.float64,
                         y=np.float64, vx=np.float64, vy=np.float64, score=np.float64, cov=np.float64))
