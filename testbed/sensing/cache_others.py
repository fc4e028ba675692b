"""The further sensors' data in a sensing-cache entry (testbed/sensing/cache.py): one table per sensor, one row per
detection with its frame; data the cache cannot store is refused in one line (a ConfigError naming
``sensing_cache``), never dropped."""
from __future__ import annotations

import numpy as np
import pyarrow as pa

from ..config import ConfigError
from .sensor import SensingContext, Sensor, SensorReading, table_problem


def refuse(name: str, why: str) -> ConfigError:
    """The one-line error for sensor ``name``'s data that the cache cannot store."""
    return ConfigError("sensing_cache", f"cannot store the data of sensor {name!r}: {why}; a sensor's data must be "
                       "a dict of numeric NumPy arrays with one row per detection (testbed/sensing/sensor.py), "
                       "or sense without the cache")


class OtherRows:
    """The further sensors' data tables, appended per frame; ``schema``: per sensor, column -> [dtype, trailing
    shape], fixed by its first frame."""

    def __init__(self, names: list[str]):
        self.columns: dict[str, dict[str, list]] = {n: {} for n in names}
        self.schema: dict[str, dict[str, list]] = {}

    def add(self, frame: int, others: dict[str, SensorReading]) -> None:
        """Append frame ``frame``'s readings; ConfigError (:func:`refuse`) for data the cache cannot store."""
        for name, cols in self.columns.items():
            data = others[name].data
            why = table_problem(data)
            if why is None:
                schema = {c: [a.dtype.str, list(a.shape[1:])] for c, a in data.items()}
                if self.schema.setdefault(name, schema) != schema:
                    why = f"its columns changed from {self.schema[name]} to {schema}"
            if why is not None:
                raise refuse(name, why)
            rows = len(next(iter(data.values()))) if data else 0
            cols.setdefault("frame", []).append(np.full(rows, frame, np.int64))
            for c, a in data.items():
                cols.setdefault(c, []).append(a)

    def tables(self) -> dict[str, pa.Table]:
        """``others-<name>`` -> its table (columns of fixed-size rows flattened, as the detections')."""
        out = {}
        for name, cols in self.columns.items():
            table = {}
            for c, parts in cols.items():
                a = np.concatenate(parts)
                width = int(np.prod(a.shape[1:]))
                table[c] = pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), width) if a.ndim > 1 else a
            out[f"others-{name}"] = pa.table(table) if table else pa.table({"frame": np.zeros(0, np.int64)})
        return out


def others_decoder(sensors: list[Sensor], ctx: SensingContext, tables: dict[str, pa.Table], schema: dict):
    """``decode(truth) -> {name: SensorReading}``: the further sensors' readings of a truth frame decoded from their
    ``tables`` (name -> table) with ``schema`` (:class:`OtherRows`), visibility and P_D computed again from the
    data; ValueError when a table lacks a column of the schema."""
    cols, frames = {}, {}
    for s in sensors:
        t = tables[s.name]
        frames[s.name] = t.column("frame").to_numpy()
        cols[s.name] = {c: _column(t.column(c), dt, shape) for c, (dt, shape) in schema.get(s.name, {}).items()}
    pds = {s.name: s.pd(ctx) if s.pd is not None else None for s in sensors}

    def decode(truth) -> dict[str, SensorReading]:
        out = {}
        for s in sensors:
            a, b = np.searchsorted(frames[s.name], [truth.frame, truth.frame + 1])
            data = {c: v[a:b] for c, v in cols[s.name].items()}
            pd = pds[s.name]
            out[s.name] = SensorReading(data, s.visibility(ctx, truth, data), pd(data) if pd is not None else None)
        return out

    return decode


def _column(col: pa.ChunkedArray, dtype: str, shape: list[int]) -> np.ndarray:
    flat = col.combine_chunks()
    if shape:
        values = flat.values.to_numpy(zero_copy_only=False) if len(flat) else np.zeros(0)
        return values.astype(np.dtype(dtype)).reshape((len(flat), *shape))
    return flat.to_numpy(zero_copy_only=False).astype(np.dtype(dtype))
