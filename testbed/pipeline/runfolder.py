"""A run folder read back: ``read_run(folder)`` gives its tables (pandas DataFrames), scores.json and the scenario
it ran, so a finished run can be scored again, compared or fed to another tool without the testbed's internals."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..config import ConfigError
from .outdir import INCOMPLETE
from ..scenario.spec import Scenario, parse_scenario

TABLES = ("truth", "detections", "tracks", "diagnostics")


@dataclass(frozen=True, eq=False)
class RunData:
    """folder: the run folder. truth, detections, tracks, diagnostics: its tables (README, "Output files").
    scores: scores.json as a dict (scenario, seed, tracker, frames, scores, mot_metrics, timings, config), or {}
    when the run stopped before it. scenario: the Scenario it ran (from scores.json's config), or None.
    incomplete: the run was cut short (INCOMPLETE holds why). events: events.parquet (testbed.scoring.events), or
    None for a run without one (cut short, or written before it existed). sensors: the further sensors' detections
    by sensor name (``detections-<name>.parquet``: frame, time, x, y, z), empty without any."""

    folder: Path
    truth: pd.DataFrame
    detections: pd.DataFrame
    tracks: pd.DataFrame
    diagnostics: pd.DataFrame
    scores: dict = field(default_factory=dict)
    scenario: Scenario | None = None
    incomplete: str | None = None
    events: pd.DataFrame | None = None
    sensors: dict[str, pd.DataFrame] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.scores.get("frames", self.truth["frame"].max() + 1 if len(self.truth) else 0))


def read_run(folder: str | Path) -> RunData:
    """The run in ``folder`` (written by ``testbed run`` or ``run_scenario(..., out_dir=folder)``). ConfigError
    (one line) when it is not a run folder or a table cannot be read."""
    path = Path(folder)
    if not path.is_dir():
        raise ConfigError(str(folder), "no such run folder")
    tables = {}
    for name in TABLES:
        f = path / f"{name}.parquet"
        if not f.is_file():
            raise ConfigError(str(folder), f"not a run folder: no {name}.parquet")
        try:
            tables[name] = pd.read_parquet(f)
        except Exception as err:  # noqa: BLE001 - a damaged file is the folder's error
            raise ConfigError(str(f), f"cannot be read ({type(err).__name__})") from None
    scores, scenario = {}, None
    sj = path / "scores.json"
    if sj.is_file():
        try:
            scores = json.loads(sj.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise ConfigError(str(sj), f"cannot be read ({type(err).__name__})") from None
        if isinstance(scores.get("config"), dict):
            scenario = parse_scenario(scores["config"])
    inc = path / INCOMPLETE
    incomplete = inc.read_text(encoding="utf-8", errors="replace").strip() if inc.is_file() else None
    events = None
    ev = path / "events.parquet"
    if ev.is_file():
        try:
            events = pd.read_parquet(ev)
        except Exception as err:  # noqa: BLE001 - a damaged file is the folder's error
            raise ConfigError(str(ev), f"cannot be read ({type(err).__name__})") from None
    further = {}
    for f in sorted(path.glob("detections-*.parquet")):
        if f.is_symlink() or not f.is_file():  # nothing planted in a run folder is followed
            continue
        try:
            further[f.stem[len("detections-"):]] = pd.read_parquet(f)
        except Exception as err:  # noqa: BLE001 - a damaged file is the folder's error
            raise ConfigError(str(f), f"cannot be read ({type(err).__name__})") from None
    return RunData(path, **tables, scores=scores, scenario=scenario, incomplete=incomplete, events=events,
                   sensors=further)
