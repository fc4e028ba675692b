"""A recorded KITTI-tracking sequence run through our perception, a tracker and (with labels) the scoring and the
recording: ``replay(folder, ...)``, the run loop of :func:`testbed.pipeline.run.run_scenario` fed with the
sequence's frames (testbed.sensing.kitti.replay_frames) instead of the scenario's traffic.

The settings (beam pattern, sensor height, perception, added clutter, tracker, scoring) come from a scenario:
the one given, else the one an export wrote beside the sequence (``roadtrack_scenario.json``), else the
defaults. The lane map (the perception's region of interest and heading prior, the trackers' road aid) is that
scenario's road, built without its traffic, only when the scenario came with the sequence (it is the road the
scans were taken on) or ``road=True``; a real recording has none.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ..config import ConfigError
from ..scenario.spec import Scenario, apply_overrides, parse_scenario
from ..sensing import kitti, road_map
from ..world.simulation import lane_polylines
from .run import RunResult, run_scenario


@dataclasses.dataclass
class KittiSource:
    """The frames of a sequence for run_scenario (``source``): the road drawn and the frames sensed."""

    sequence: kitti.Sequence
    scn: Scenario
    with_road: bool

    def __post_init__(self):
        self._net = None

    def _network(self):
        if self._net is None and self.with_road:
            from ..world.envsource import make_simulation

            sim = make_simulation(self.scn)
            self._net = sim.network
            close = getattr(sim, "close", None)
            if callable(close):
                close()
        return self._net

    def scene(self):
        net = self._network()
        return (lane_polylines(net) if net is not None else []), np.zeros((0, 7))

    def frames(self, watch=None):
        net = self._network()
        return kitti.replay_frames(self.sequence, self.scn, road_map(net) if net is not None else None)


def replay_scenario(seq: kitti.Sequence, scenario: Scenario | None = None, overrides: dict | None = None
                    ) -> tuple[Scenario, bool]:
    """The scenario a replay of ``seq`` runs with (see the module docstring), its duration set to the sequence's
    scans, and whether its road is the sequence's (it came with it)."""
    carried = scenario is None and seq.scenario_file is not None
    if scenario is None:
        data: dict = {"name": f"kitti-{seq.name}"}
        if carried:
            try:
                data = json.loads(seq.scenario_file.read_text(encoding="utf-8"))
            except (OSError, ValueError) as err:
                raise ConfigError(str(seq.scenario_file), f"cannot be read ({type(err).__name__})") from None
            if not isinstance(data, dict):
                raise ConfigError(str(seq.scenario_file), "not a scenario (a JSON object)")
        data = apply_overrides(data, overrides or {})
        scenario = parse_scenario(data)
    n = len(seq.scans)
    return dataclasses.replace(scenario, duration_s=(n - 1) / scenario.rate_hz), carried


def replay(folder: str | Path, scenario: Scenario | None = None, tracker=None, out_dir: str | Path | None = None,
           record: bool = True, sequence: str | None = None, overrides: dict | None = None, label: str | None = None,
           on_frame=None, road: bool | None = None) -> RunResult:
    """Run the KITTI-tracking sequence in ``folder`` (``sequence``: its name, default the only one) like a live run:
    perception on each scan, ``tracker`` (as run_scenario takes it; default the scenario's), and, with labels,
    scores, events and tables (a sequence without labels is scored against no truth). ``road``: use the
    scenario's road as the lane map (default: when the scenario came with the sequence)."""
    seq = kitti.open_sequence(folder, sequence)
    scn, carried = replay_scenario(seq, scenario, overrides)
    with_road = carried if road is None else road
    return run_scenario(scn, out_dir=out_dir, record=record, tracker=tracker, label=label, on_frame=on_frame,
                        source=KittiSource(seq, scn, with_road))
