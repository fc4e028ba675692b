"""Track-to-track stitching (issue 29.2, ``tracker.stitch_s``): a newly confirmed track takes the label of a confirmed
track deleted within the window when it lies in that track's constant-velocity prediction; counted per run."""
from __future__ import annotations

import json

import numpy as np
import pytest

from roadtrack.testbed import load_scenario, run
from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.tracking.builtin import BuiltinTracker
from roadtrack.testbed.tracking.protocol import Frame
from roadtrack.testbed.tracking.stitch import Stitcher
from roadtrack.trackers import make_tracker

COV = np.diag([0.04, 0.04, 0.25, 0.25])


def _one(i, x, y, vx=20.0):
    return np.array([i]), np.array([[x, y, vx, 0.0]]), COV[None]


def test_a_track_confirmed_where_a_deleted_one_would_be_takes_its_label_once():
    none = (np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros((0, 4, 4)))
    s = Stitcher(2.0)
    assert s.update(0.0, _one(7, 0.0, 0.0), none) == []
    assert s.update(1.0, none, _one(12, 20.3, 8.0)) == []  # the next lane: 8 m across is outside the gate
    assert s.update(1.0, none, _one(13, 20.3, 0.1)) == [13]  # 20 m on at 20 m/s
    assert s.label(np.array([13, 12, 5])).tolist() == [7, 12, 5]
    assert s.update(1.1, none, _one(14, 22.3, 0.0)) == []  # T7's state was used once
    s.update(1.5, _one(13, 30.0, 0.0), none)  # the stitched track is deleted in turn: kept under label 7
    assert s.update(5.0, none, _one(15, 100.0, 0.0)) == []  # 3.5 s later: outside the 2 s window
    with pytest.raises(ValueError, match="stitch window"):
        Stitcher(0.0)


def _frames(gap: range, n: int = 60, dt: float = 0.1):
    """A car at 20 m/s detected every scan but during ``gap`` (the sensor should see it: nominal P_D)."""
    for k in range(n):
        z = np.zeros((0, 2)) if k in gap else np.array([[20.0 * dt * k, 0.0]])
        yield Frame(index=k, time=k * dt, dt=dt if k else 0.0, z=z, R=np.eye(2)[None].repeat(len(z), 0) * 0.04,
                    extent=np.tile([4.6, 1.8, 1.5], (len(z), 1)), heading=np.zeros(len(z)))


@pytest.mark.parametrize("stitch_s", [0.0, 3.0])
def test_a_car_missed_for_a_second_keeps_its_label_with_stitching(stitch_s):
    bt = BuiltinTracker(make_tracker("jpda-kf"), stitch_s)
    labels, stitched, marked = [], 0, []
    for f in _frames(range(20, 32)):
        ts = bt.step(f)
        stitched += ts.stitched
        labels += [int(i) for i, s in zip(ts.ids, ts.status) if s == "confirmed"]
        mark = ts.diagnostics.get("stitched", np.zeros(0))
        marked += [(f.index, int(i)) for i, m in zip(ts.diagnostic_ids, mark) if m == 1.0]
    before, after = labels[0], labels[-1]
    assert len(set(labels)) == (1 if stitch_s else 2) and stitched == (1 if stitch_s else 0)
    assert (before == after) == bool(stitch_s)
    assert [i for _, i in marked] == ([before] if stitch_s else [])  # the diagnostic marks the stitch's scan


def test_a_run_counts_its_stitches_in_scores_json(tmp_path):
    scn = load_scenario("cut_in_out", {"duration_s": 3.0, "tracker.stitch_s": 2.0})
    res = run(scn, out=tmp_path / "r", record=False)
    assert json.loads((tmp_path / "r" / "scores.json").read_text())["stitched_tracks"] == res.stitched == 0
    with pytest.raises(ConfigError, match="tracker.stitch_s"):
        load_scenario("cut_in_out", {"tracker.stitch_s": -1.0})


def test_a_tracker_that_is_not_built_in_refuses_stitching_in_one_line():
    from roadtrack.testbed.tracking.user import build_tracker

    scn = load_scenario("cut_in_out", {"tracker.stitch_s": 2.0})
    with pytest.raises(ConfigError, match=r"^tracker.stitch_s: stitching is a step of the built-in trackers, not "
                                          r"of a named or a user's tracker"):
        build_tracker(scn, "stonesoup-jpda-kf")
