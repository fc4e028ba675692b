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
    campaign.lock          locked (``flock``) by the one process that runs or resumes the campaign

No file of the folder is written through a symbolic link: a link at any name the campaign writes (the lock,
a run file, a temporary, a recording, a report file) is refused in one line naming it, before any run
(:func:`refuse_links`), and every writer opens its files with ``O_NOFOLLOW`` (:mod:`testbed.common.safe_io`).

A killed campaign (Ctrl-C, SIGKILL, power loss) loses at most the runs that were in flight: it never
leaves a half-written run file that counts as finished, and never writes a run twice.

Damage (a disk that lies, a hand edit, a partial copy) is reported in one line naming the file:
``campaign.toml``, ``scenarios.json`` or ``meta.json`` missing, unreadable or malformed is a
:class:`~testbed.config.strict.ConfigError` (nothing runs); a damaged run file is a missing run: ``resume``
sets it aside as ``runs/<run_id>.parquet.damaged`` and runs it again, ``report`` leaves it out, each with
a warning line; ``results.parquet`` is derived from the run files and simply rebuilt.
"""
from __future__ import annotations

import contextlib
import functools
import json
import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Iterator

from ..common import safe_io
from ..config import ConfigError

CAMPAIGN_FILE = "campaign.toml"
SCENARIOS_FILE = "scenarios.json"
META_FILE = "meta.json"
RUNS_DIR = "runs"
RECORDINGS_DIR = "recordings"
SENSING_DIR = "sensing"  # the campaign's sensing cache (testbed.sensing.cache): each traffic sensed once
PLOTS_DIR = "plots"
RESULTS_FILE = "results.parquet"
LOCK_FILE = "campaign.lock"
DAMAGED_SUFFIX = ".damaged"
SERIES_COLUMN = "series_pos_rmse_m"
# Columns that depend on the machine, the load and the clock, not on the campaign: left out when two
# executions of a campaign are compared (plus every ms_<stage> timing column).
TIMING_COLUMNS = ("wall_s", "worker", "finished_at")


def timing_columns(columns) -> list[str]:
    return [c for c in columns if c in TIMING_COLUMNS or c.startswith("ms_")]


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a crash leaves either the old file or the new one, whole; a symbolic
    link at ``path`` (or at its temporary's name) is refused, never written through."""
    safe_io.write_bytes(path, data, fsync=True)


def _write_table_atomic(table, path: Path) -> None:
    import pyarrow.parquet as pq

    with safe_io.atomic_path(path, fsync=True) as tmp, safe_io.open_write(tmp) as fh:
        pq.write_table(table, fh)


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
    """Start a results directory: copy the campaign file, the scenario dicts and meta data into it. An
    unusable ``out_dir`` (a file, not creatable, holding other files) is a ConfigError; if writing fails
    half-way, the folder is removed again when this call created it."""
    out = Path(out_dir)
    if out.is_symlink():  # never write the campaign into the folder a link points to
        raise ConfigError("", f"{safe_io.link_error(out)}: choose another --out")
    if is_campaign_dir(out):
        raise ConfigError("", f"{out} already holds a campaign: continue it with `testbed campaign resume {out}` "
                          "or choose another --out")
    if out.exists() and not out.is_dir():
        raise ConfigError("", f"{out} is a file, not a folder: choose another --out")
    if out.exists() and any(out.iterdir()):
        raise ConfigError("", f"{out} exists and is not empty: choose another --out")
    made = not out.exists()
    try:
        (out / RUNS_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError("", f"{out}: cannot create the results folder ({_strerror(err)}): choose another "
                          "--out") from None
    try:
        from ..common.jsonio import json_text

        atomic_write_bytes(out / SCENARIOS_FILE, (json_text(
            {s.entry: s.data for s in campaign.scenarios}, indent=1, default=str) + "\n").encode())
        meta = dict(name=campaign.name, source=str(Path(campaign_path).resolve()), n_runs=campaign.n_runs,
                    created=time.strftime("%Y-%m-%dT%H:%M:%S%z"), versions=versions())
        atomic_write_bytes(out / META_FILE, (json_text(meta, indent=1) + "\n").encode())
        # the campaign file last: a directory with campaign.toml is a complete, resumable campaign
        atomic_write_bytes(out / CAMPAIGN_FILE, Path(campaign_path).read_bytes())
    except BaseException:
        if made:
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise
    return out


def _strerror(err: OSError) -> str:
    return os.strerror(err.errno).lower() if err.errno else str(err)


def _read_text(path: Path, what: str) -> str:
    """The UTF-8 text of a file of a campaign folder; every failure a ConfigError naming the file."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(str(path), f"missing: it holds the {what}; restore it, or start the campaign again "
                          "with `testbed campaign run`") from None
    except OSError as err:
        raise ConfigError(str(path), f"cannot be read ({_strerror(err)})") from None
    if not data.strip():
        raise ConfigError(str(path), f"empty; it should hold the {what}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(str(path), f"not UTF-8 text (byte {err.start}); it should hold the {what}") from None


def _read_json_object(path: Path, what: str) -> dict:
    text = _read_text(path, what)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ConfigError(str(path), f"not valid JSON ({err.msg}, line {err.lineno} column {err.colno}); it "
                          f"should hold the {what}") from None
    if not isinstance(data, dict):
        raise ConfigError(str(path), f"expected a JSON object (the {what}), got {type(data).__name__}")
    return data


def read_meta(out_dir: str | Path) -> dict:
    """``meta.json`` of a campaign folder, checked: a JSON object whose ``name`` (if any) is a string."""
    path = Path(out_dir) / META_FILE
    meta = _read_json_object(path, "campaign name, source and versions")
    if "name" in meta and not isinstance(meta["name"], str):
        raise ConfigError(f"{path}: name", f"expected a string, got {meta['name']!r}")
    return meta


def read_scenarios(out_dir: str | Path, entries: list[str]) -> dict[str, dict]:
    """``scenarios.json`` of a campaign folder: scenario entry -> scenario dict, for every entry of the
    campaign file (checked: each one present and a valid scenario)."""
    from ..scenario.spec import parse_scenario

    path = Path(out_dir) / SCENARIOS_FILE
    data = _read_json_object(path, "scenarios the campaign started with")
    for entry in entries:
        if entry not in data:
            raise ConfigError(str(path), f"has no scenario {entry!r} (the campaign file lists it; this file "
                              f"holds: {', '.join(map(repr, data)) or 'none'})")
        if not isinstance(data[entry], dict):
            raise ConfigError(f"{path}: {entry}", f"expected a scenario (a JSON object), got "
                              f"{type(data[entry]).__name__}")
        try:
            parse_scenario(data[entry])
        except ConfigError as err:
            raise ConfigError(f"{path}: {entry}", str(err)) from None
        except (TypeError, ValueError, AttributeError, ArithmeticError) as err:
            raise ConfigError(f"{path}: {entry}", f"not a valid scenario ({type(err).__name__}: {err})") from None
    return data


def _campaign_entries(out: Path) -> list[str]:
    """The ``scenarios`` list of ``DIR/campaign.toml`` (its other keys are checked by load_campaign)."""
    import tomllib

    path = out / CAMPAIGN_FILE
    try:
        data = tomllib.loads(_read_text(path, "campaign file"))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(str(path), f"not valid TOML ({err})") from None
    entries = data.get("scenarios")
    if not isinstance(entries, list) or not all(isinstance(e, str) for e in entries):
        return []  # load_campaign names what is wrong with it
    return entries


def open_campaign(out_dir: str | Path):
    """The :class:`~testbed.campaign.spec.Campaign` of a results directory (as it was started). A damaged
    folder is a one-line ConfigError naming the file and what is wrong."""
    from .spec import load_campaign

    out = Path(out_dir)
    if not out.is_dir():
        raise ConfigError("", f"{out}: no such campaign folder" if not out.exists() else
                          f"{out}: a file, not a campaign folder")
    if not is_campaign_dir(out):
        if (out / CAMPAIGN_FILE).exists():
            raise ConfigError(str(out / CAMPAIGN_FILE), "cannot be read (not a file)")
        raise ConfigError("", f"{out}: not a campaign directory (no {CAMPAIGN_FILE}); start one with "
                          "`testbed campaign run FILE --out DIR`")
    entries = _campaign_entries(out)
    meta = read_meta(out)
    scenario_data = read_scenarios(out, entries)
    return load_campaign(out / CAMPAIGN_FILE, scenario_data=scenario_data, default_name=meta.get("name"))


# ------------------------------------------------------------------------------------------ the lock


@contextlib.contextmanager
def locked(out_dir: str | Path) -> Iterator[None]:
    """Hold ``DIR/campaign.lock`` (``flock``, exclusive) while running or resuming a campaign; a second
    process gets a ConfigError. The kernel releases the lock when the process ends, even by SIGKILL, so
    a lock is never stale; the file itself stays (its content, the holder's pid, is only for messages).
    A symbolic link at the lock or anywhere the campaign writes is refused (:func:`refuse_links`)."""
    out = Path(out_dir)
    path = out / LOCK_FILE
    fd = safe_io.try_lock(path)
    if fd is None:
        raise ConfigError("", f"{out} is in use by another campaign process (pid {safe_io.lock_holder(path)}); "
                          "wait for it or stop it")
    try:
        refuse_links(out)
        yield
    finally:
        safe_io.unlock(fd)


def _entries(folder: Path) -> list[os.DirEntry]:
    try:
        return sorted(os.scandir(folder), key=lambda e: e.name)
    except (FileNotFoundError, NotADirectoryError):
        return []


def refuse_links(out_dir: str | Path) -> None:
    """ConfigError naming the first symbolic link among the names a campaign writes: the entries of ``DIR``,
    ``runs/``, ``plots/``, ``recordings/`` and each ``recordings/<run_id>/``. Checked up front, so a planted
    link stops the command before any run (the writers refuse links too)."""
    out = Path(out_dir)
    recordings = [Path(e.path) for e in _entries(out / RECORDINGS_DIR) if e.is_dir(follow_symlinks=False)]
    for folder in [out, out / RUNS_DIR, out / PLOTS_DIR, out / RECORDINGS_DIR, out / SENSING_DIR, *recordings]:
        for entry in _entries(folder):
            if entry.is_symlink():
                raise safe_io.link_error(entry.path)


# ------------------------------------------------------------------------------------------ run files


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


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


class DamagedRun(ValueError):
    """A run file that cannot be one of this store's: why, in a few words."""


def _read_run(path: Path):
    """One run file as a one-row arrow table, checked: run_id (= the file name), run_index, status."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not path.is_file():
        raise DamagedRun("not a file")
    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise
    except OSError as err:
        raise DamagedRun(f"cannot be read ({_strerror(err)})") from None
    except (pa.ArrowException, ValueError) as err:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        text = text.split("': ", 1)[-1].split(". ", 1)[0].rstrip(".")  # no "Could not open ... '<path>': "
        raise DamagedRun(f"not a readable parquet file ({text})") from None
    if table.num_rows != 1:
        raise DamagedRun(f"{table.num_rows} rows, a run file has one")
    types = {"run_id": pa.string(), "status": pa.string(), "run_index": pa.int64()}
    for name, tp in types.items():
        if name not in table.column_names or table.schema.field(name).type != tp:
            raise DamagedRun(f"no {tp} column {name!r}")
    run_id, status = table.column("run_id")[0].as_py(), table.column("status")[0].as_py()
    if run_id != path.stem:
        raise DamagedRun(f"holds run {run_id!r}")
    if status not in ("ok", "error"):
        raise DamagedRun(f"status {status!r} (allowed: 'ok', 'error')")
    return table


def _odd_types(tables: dict[str, Any]) -> dict[str, str]:
    """run_id -> why, for the run files whose column types differ from those of most run files (every
    file this store writes has the same types; a null column fits any)."""
    import pyarrow as pa

    seen: dict[str, Counter] = {}
    for table in tables.values():
        for fld in table.schema:
            if fld.type != pa.null():
                seen.setdefault(fld.name, Counter())[fld.type] += 1
    usual = {name: counts.most_common(1)[0][0] for name, counts in seen.items()}
    odd: dict[str, str] = {}
    for run_id, table in tables.items():
        for fld in table.schema:
            if fld.type != pa.null() and fld.type != usual[fld.name]:
                odd[run_id] = f"column {fld.name!r} is {fld.type}, in the other run files {usual[fld.name]}"
                break
    return odd


def _set_aside(path: Path, why: str, clean: bool, warn: Callable[[str], None]) -> None:
    """A damaged run file: with ``clean`` renamed to ``<name>.damaged`` (then run again), else skipped."""
    if not clean:
        warn(f"{path}: {why}; left out (`testbed campaign resume` runs it again)")
        return
    target = path.with_name(path.name + DAMAGED_SUFFIX)
    k = 1
    while target.exists():
        target, k = path.with_name(f"{path.name}{DAMAGED_SUFFIX}{k}"), k + 1
    try:
        path.rename(target)
    except OSError as err:
        raise ConfigError(str(path), f"{why}, and it cannot be set aside ({_strerror(err)}); remove it") from None
    warn(f"{path}: {why}; set aside as {target.name}, the run is run again")


def scan_runs(out_dir: str | Path, clean: bool = False, warn: Callable[[str], None] | None = None) -> dict:
    """run_id -> one-row arrow table of every sound run file of ``DIR/runs``. A damaged one (not parquet,
    truncated, not one row, wrong run, odd column types) gives a warning line and is left out; with
    ``clean`` (only by the process holding the lock) it is also set aside and stale temp files are removed."""
    warn = warn or _warn
    runs = Path(out_dir) / RUNS_DIR
    if not runs.exists():
        return {}
    if not runs.is_dir():
        raise ConfigError(str(runs), "not a folder (it holds one file per finished run); move it away")
    tables: dict[str, Any] = {}
    for path in sorted(runs.iterdir()):
        if path.name.startswith("."):
            if clean and ".tmp-" in path.name:
                path.unlink(missing_ok=True)
            continue
        if path.suffix != ".parquet":
            continue
        try:
            tables[path.stem] = _read_run(path)
        except FileNotFoundError:  # set aside meanwhile by the process that holds the lock
            continue
        except DamagedRun as err:
            _set_aside(path, str(err), clean, warn)
    for run_id, why in _odd_types(tables).items():
        _set_aside(run_path(out_dir, run_id), why, clean, warn)
        del tables[run_id]
    return tables


def finished_runs(out_dir: str | Path, clean: bool = False, warn: Callable[[str], None] | None = None
                  ) -> dict[str, str]:
    """run_id -> status ("ok" or "error") of every sound run file (see :func:`scan_runs`)."""
    return {rid: t.column("status")[0].as_py() for rid, t in scan_runs(out_dir, clean, warn).items()}


def consolidate(out_dir: str | Path, clean: bool = False, warn: Callable[[str], None] | None = None):
    """Rebuild ``results.parquet`` from the sound run files; return it as a pandas DataFrame (None if no
    run). Safe while another process runs the campaign: run files appear whole (atomic renames) and this
    writes only its own temp file and ``results.parquet`` (atomically)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    out = Path(out_dir)
    tables = scan_runs(out, clean, warn)
    if not tables:
        return None
    table = pa.concat_tables(list(tables.values()), promote_options="permissive")
    table = table.take(pc.sort_indices(table, sort_keys=[("run_index", "ascending"), ("run_id", "ascending")]))
    df = table.to_pandas()
    df = df.drop_duplicates(subset="run_id", keep="last").reset_index(drop=True)
    results = out / RESULTS_FILE
    if results.exists() and not results.is_file():
        raise ConfigError(str(results), "not a file; remove it (it is rebuilt from runs/)")
    _write_table_atomic(pa.Table.from_pandas(df, preserve_index=False), results)
    return df


def load_results(out_dir: str | Path, warn: Callable[[str], None] | None = None):
    """The results table of a campaign directory (consolidated afresh from the run files)."""
    df = consolidate(out_dir, warn=warn)
    if df is None:
        import pandas as pd

        return pd.DataFrame()
    return df
