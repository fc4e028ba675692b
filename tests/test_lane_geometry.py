"""The lane geometry sampled at once (testbed.world.simulation.lane_points) is highway-env's own, to the last bit:
on every lane of every shipped scenario, straight, sine and circular, at both borders and the centre."""
from __future__ import annotations

import numpy as np
import pytest

from roadtrack.testbed.scenario.spec import SCENARIO_DIR, load_scenario
from roadtrack.testbed.world.envsource import make_simulation
from roadtrack.testbed.world.simulation import lane_points

SCENARIOS = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


@pytest.mark.parametrize("name", SCENARIOS)
def test_lane_points_are_highway_envs_positions(name):
    sim = make_simulation(load_scenario(name, {"duration_s": 0.1}))
    kinds = set()
    try:
        for lanes in sim.network.graph.values():
            for lane_list in lanes.values():
                for lane in lane_list:
                    kinds.add(type(lane).__name__)
                    s = np.append(np.arange(0.0, lane.length, 1.0), lane.length)
                    for side in (-0.5, 0.0, 0.5):
                        pts, heads, width = lane_points(lane, s, side)
                        ref = np.array([lane.position(si, side * lane.width_at(si)) for si in s]).reshape(-1, 2)
                        assert np.array_equal(pts, ref), (name, type(lane).__name__, side)
                        assert np.array_equal(heads, [lane.heading_at(si) for si in s])
                        assert np.array_equal(width, [lane.width_at(si) for si in s])
    finally:
        getattr(sim, "close", lambda: None)()
    assert kinds
