"""The results directory of a campaign: resumable, one atomic file per finished run.

Layout of ``DIR``::

    campaign.toml          the campaign file, byte for byte as it was started
    scenarios.json         the scenario TOML dicts the campaign started with (entry -> dict), so a resumed
                           campaign runs the same scenarios even if the files changed since
    meta.json              campaign name, source file, start time, versions of the starting machine
    runs/<run_id>.parquet  one row per finished run (ok or error), written atomically: temp file, fsync,
                           os.replace, fsync of the folder. A run is finished iff its file exists.
    recordings/<run_id>/   full recordings (run.rrd, truth/detections/tracks.parquet, scores.json) of the
                           runs whose seed index is in record.full_seeds
    results.parquet        every run file in one table, ordered by run_index, deduplicated by run_id;
                           rebuilt at the end of `run`/`resume` and by `report`
    report.md, plots/, summary.csv   written by `testbed campaign report DIR`

A killed campaign (Ctrl-C, SIGKILL, power loss) loses at most the runs that were in flight: it never
leaves a half-written run file that counts as finished, and never writes a run twice.
"""
from __future__ import annotations

import json
import os
import time
import functools
import sys
from pathlib import Path
from typing import Any

from ..config import ConfigError

CAMPAIGN_FILE = "campaign.toml"
SCENARIOS_FILE = "scenarios.json"
META_FILE = "meta.json"
RUNS_DIR = "runs"
RECORDINGS_DIR = "recordings"
RESULTS_FILE = "results.parquet"
SERIES_COLUMN = "series_pos_rmse_m"
# Columns that depend on the machine, the load and the clock, not on the campaign: left out when two
# executions of a campaign are compared (plus every ms_<stage> timing column).
TIMING_COLUMNS = ("wall_s", "worker", "finished_at")


def timing_columns(columns) -> list[str]:
    return [c for c in columns if c in TIMING_COLUMNS or c.startswith("ms_")]


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a crash leaves either the old file or the new one, whole."""
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _write_table_atomic(table, path: Path) -> None:
    import pyarrow.parquet as pq

    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    pq.write_table(table, tmp)
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


_DISTRIBUTIONS = {"roadtrack": ("roadtrack",), "numpy": ("numpy",), "highway_env": ("highway-env",),
                  "open3d": ("open3d-cpu", "open3d"), "rerun": ("rerun-sdk",)}


@functools.cache
def versions() -> dict[str, str]:
    """Installed versions of roadtrack and the packages that shape its numbers (``v_<name>`` columns)."""
    from importlib import metadata

    out = {"python": ".".join(map(str, sys.version_info[:3]))}
    for name, dists in _DISTRIBUTIONS.items():
        out[name] = ""
        for dist in dists:
            try:
                out[name] = metadata.version(dist)
                break
            except metadata.PackageNotFoundError:
                continue
    return out


def is_campaign_dir(out_dir: str | Path) -> bool:
    return (Path(out_dir) / CAMPAIGN_FILE).is_file()


def create(out_dir: str | Path, campaign_path: str | Path, campaign) -> Path:
    """Start a results directory: copy the campaign file, the scenario dicts and meta data into it."""
    out = Path(out_dir)
    if is_campaign_dir(out):
        raise ConfigError("", f"{out} already holds a campaign: continue it with `testbed campaign resume {out}` "
                          "or choose another --out")
    if out.exists() and any(out.iterdir()):
        raise ConfigError("", f"{out} exists and is not empty: choose another --out")
    (out / RUNS_DIR).mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / SCENARIOS_FILE, (json.dumps(
        {s.entry: s.data for s in campaign.scenarios}, indent=1, default=str) + "\n").encode())
    meta = dict(name=campaign.name, source=str(Path(campaign_path).resolve()), n_runs=campaign.n_runs,
                created=time.strftime("%Y-%m-%dT%H:%M:%S%z"), versions=versions())
    atomic_write_bytes(out / META_FILE, (json.dumps(meta, indent=1) + "\n").encode())
    # the campaign file last: a directory with campaign.toml is a complete, resumable campaign
    atomic_write_bytes(out / CAMPAIGN_FILE, Path(campaign_path).read_bytes())
    return out


def open_campaign(out_dir: str | Path):
    """The :class:`~testbed.campaign.spec.Campaign` of a results directory (as it was started)."""
    from .spec import load_campaign

    out = Path(out_dir)
    if not is_campaign_dir(out):
        raise ConfigError("", f"{out}: not a campaign directory (no {CAMPAIGN_FILE}); start one with "
                          "`testbed campaign run FILE --out DIR`")
    scenario_data = json.loads((out / SCENARIOS_FILE).read_text()) if (out / SCENARIOS_FILE).is_file() else None
    meta = read_meta(out)
    return load_campaign(out / CAMPAIGN_FILE, scenario_data=scenario_data, default_name=meta.get("name"))


def read_meta(out_dir: str | Path) -> dict:
    path = Path(out_dir) / META_FILE
    return json.loads(path.read_text()) if path.is_file() else {}


def run_path(out_dir: str | Path, run_id: str) -> Path:
    return Path(out_dir) / RUNS_DIR / f"{run_id}.parquet"


def recording_dir(out_dir: str | Path, run_id: str) -> Path:
    return Path(out_dir) / RECORDINGS_DIR / run_id


def row_table(row: dict[str, Any]):
    """One run's row as a one-row arrow table with stable types: numbers float64 (int64 for integer
    fields), text as string, the per-frame series as list<double>."""
    import numpy as np
    import pyarrow as pa

    names, arrays = [], []
    for key, value in row.items():
        if key == SERIES_COLUMN:
            arr = pa.array([[float(v) for v in value]], type=pa.list_(pa.float64()))
        elif isinstance(value, (bool, np.bool_)):
            arr = pa.array([bool(value)], type=pa.bool_())
        elif isinstance(value, (int, np.integer)):
            arr = pa.array([int(value)], type=pa.int64())
        elif isinstance(value, (float, np.floating)):
            arr = pa.array([float(value)], type=pa.float64())
        elif value is None:
            arr = pa.array([None], type=pa.float64())
        else:
            arr = pa.array([str(value)], type=pa.string())
        names.append(key)
        arrays.append(arr)
    return pa.table(arrays, names=names)


def write_run(out_dir: str | Path, row: dict[str, Any]) -> Path:
    """Write one finished run atomically to ``runs/<run_id>.parquet`` (replacing an earlier attempt)."""
    path = run_path(out_dir, row["run_id"])
    _write_table_atomic(row_table(row), path)
    return path


def finished_runs(out_dir: str | Path) -> dict[str, str]:
    """run_id -> status ("ok" or "error") of every readable run file; removes stale temp files and
    unreadable run files (which cannot come from this store, but a disk can lie)."""
    import pyarrow.parquet as pq

    runs = Path(out_dir) / RUNS_DIR
    out: dict[str, str] = {}
    if not runs.is_dir():
        return out
    for path in sorted(runs.iterdir()):
        if path.name.startswith("."):
            if ".tmp-" in path.name:
                path.unlink(missing_ok=True)
            continue
        if path.suffix != ".parquet":
            continue
        try:
            status = pq.read_table(path, columns=["status"]).column("status")[0].as_py()
        except Exception:  # noqa: BLE001 - a damaged file is a missing run
            path.unlink(missing_ok=True)
            continue
        out[path.stem] = status
    return out


def consolidate(out_dir: str | Path):
    """Rebuild ``results.parquet`` from the run files; return it as a pandas DataFrame (None if no run)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    out = Path(out_dir)
    finished_runs(out)  # drop temp / damaged files
    files = sorted((out / RUNS_DIR).glob("*.parquet"))
    if not files:
        return None
    tables = [pq.read_table(p) for p in files]
    table = pa.concat_tables(tables, promote_options="permissive")
    table = table.take(pc.sort_indices(table, sort_keys=[("run_index", "ascending"), ("run_id", "ascending")]))
    df = table.to_pandas()
    df = df.drop_duplicates(subset="run_id", keep="last").reset_index(drop=True)
    _write_table_atomic(pa.Table.from_pandas(df, preserve_index=False), out / RESULTS_FILE)
    return df


def load_results(out_dir: str | Path):
    """The results table of a campaign directory (consolidated afresh from the run files)."""
    df = consolidate(out_dir)
    if df is None:
        import pandas as pd

        return pd.DataFrame()
    return df
