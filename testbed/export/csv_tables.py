"""``testbed export RUN --format csv [--out DIR]``: the run's tables as plain CSV files, for a program in any
language (an awk, C or MATLAB tracker; examples/awk_tracker/).

DIR (default ``RUN/csv/``) receives ``truth.csv``, ``detections.csv`` (with each detection's measurement covariance
r_xx, r_xy, r_yy), ``tracks.csv`` (the 4x4 covariance as 16 columns ``cov_x_x, cov_x_y, ..., cov_vy_vy``) and
``events.csv`` when the run has events. Field by field in docs/formats.md ("CSV"). The conventions:

* one header line, then one row per object per frame, in the parquet table's row order (frame by frame);
  columns as in the parquet tables (README, "Output files"), in their order;
* ``frame`` counts from 0 (the parquet tables' numbering), ``time`` in seconds; metres, m/s, radians; the
  world frame (x along the road start, y to the left);
* numbers with full precision (Python's shortest round-trip form: reading one back gives the same float64);
  booleans as 1 / 0; a missing number (NaN) as an empty field; text quoted only when it holds a comma or quote.

    write(run, path) -> Path          run: testbed.pipeline.runfolder.RunData; path: the folder
    csv_table(df) -> str              one table as CSV text (the conventions above)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..common.safe_io import make_folder, write_text

STATE = ("x", "y", "vx", "vy")  # the order of the tracks' covariance rows and columns
COV_COLUMNS = tuple(f"cov_{a}_{b}" for a in STATE for b in STATE)  # row-major, as tracks.parquet's cov
FILES = ("truth.csv", "detections.csv", "tracks.csv", "events.csv")


def write(run, path: str | Path) -> Path:
    """Write ``run``'s truth, detections, tracks (and events) as CSV into the folder ``path`` (created if missing;
    a symbolic link there or at a file's name is refused, files are written atomically)."""
    out = make_folder(path, "--out")
    tables = {"truth": run.truth, "detections": run.detections, "tracks": run.tracks}
    if run.events is not None:
        tables["events"] = run.events
    for name, df in tables.items():
        write_text(out / f"{name}.csv", csv_table(df))
    return out


def csv_table(df: pd.DataFrame) -> str:
    """``df`` as CSV text: a fixed-size list column ``cov`` (16 floats) spread into :data:`COV_COLUMNS`, booleans as
    1 / 0, NaN as an empty field, floats in their shortest round-trip form."""
    cols = {}
    for name in df.columns:
        col = df[name]
        if name == "cov":
            cov = np.stack(col.to_numpy()) if len(col) else np.zeros((0, 16))
            if cov.shape[1:] != (16,):
                raise ValueError(f"cov: expected 16 numbers a row, got {cov.shape[1:]}")
            cols.update({c: cov[:, k] for k, c in enumerate(COV_COLUMNS)})
        elif col.dtype == bool:
            cols[name] = col.to_numpy().astype(np.int64)
        else:
            cols[name] = col.to_numpy()
    return pd.DataFrame(cols).to_csv(index=False, lineterminator="\n")
