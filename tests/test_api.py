"""The public API (issue 18): load_scenario, sense, track, run, read_run, score; the tracker protocol with a user's
tracker from Python and from `testbed run --tracker file.py:Class`; `testbed score` on another program's CSV; the
example in examples/ as a user runs it."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtrack import testbed
from roadtrack.testbed.cli.main import main
from roadtrack.testbed.tracking import TrackSet

REPO = Path(__file__).resolve().parent.parent
SHORT = {"duration_s": 2.0}


class Echo:
    """Every detection is a confirmed track with a fresh label: the simplest tracker the protocol allows."""

    def __init__(self, scenario):
        self.next = 1
        self.frames = []

    def step(self, frame):
        self.frames.append((frame.index, frame.time, frame.dt, frame.pd is not None))
        ids = self.next + np.arange(len(frame.z))
        self.next += len(frame.z)
        return TrackSet(ids=ids, xy=frame.z, diagnostics={"n": np.full(len(ids), 1.0)})


@pytest.fixture(scope="module")
def scn():
    return testbed.load_scenario("cut_in_out", SHORT)


def test_sense_then_track_gives_the_tables_run_writes(scn, tmp_path):
    """One sensing loop and one tracking loop: sense() + track() give exactly what run() logs."""
    res = testbed.run(scn, tracker="jpda-kf", out=tmp_path / "r", record=False)
    rows = [(sf.index, ts.ids.tolist(), ts.xy.copy(), ts.status.tolist())
            for sf, ts in testbed.track(testbed.sense(scn), "jpda-kf", scn)]
    tracks = pd.read_parquet(tmp_path / "r" / "tracks.parquet")
    assert len(rows) == res.n_frames == scn.n_frames
    for frame, ids, xy, status in rows:
        t = tracks[tracks.frame == frame]
        assert t.track_id.tolist() == ids and t.status.tolist() == status
        np.testing.assert_array_equal(t[["x", "y"]].to_numpy(), xy)


def test_a_user_tracker_gets_tables_scores_diagnostics_and_a_recording(scn, tmp_path):
    from rerun.chunk import RrdReader  # noqa: F401 - the recording is rerun's

    made = []

    def factory(scenario):
        made.append(Echo(scenario))
        return made[-1]

    res = testbed.run(scn, tracker=factory, out=tmp_path / "u")
    echo = made[0]
    assert [f[0] for f in echo.frames] == list(range(scn.n_frames))
    assert echo.frames[0][2] == 0.0 and echo.frames[1][2] == pytest.approx(scn.dt)
    assert all(f[3] for f in echo.frames)  # the occlusion-aware P_D is offered
    run = testbed.read_run(tmp_path / "u")
    assert run.scores["tracker"] == "factory" and run.scenario == scn
    dets = run.detections.groupby("frame").size()
    assert run.tracks.groupby("frame").size().equals(dets)  # one track per detection, as Echo reports
    assert set(run.diagnostics.name) == {"n"}
    # a label lives one frame, so no track is ever seen to move: the moving-object test withholds them all
    assert set(run.tracks.status) == {"static"} and res.scores.confirmed_tracks == 0
    assert (tmp_path / "u" / "run.rrd").stat().st_size > 100_000


def test_run_from_the_command_line_with_a_tracker_file(tmp_path, capsys):
    src = tmp_path / "mine.py"
    src.write_text("import numpy as np\nfrom roadtrack.testbed import TrackSet\n"
                   "class Mine:\n    def step(self, frame):\n"
                   "        return TrackSet(ids=np.arange(len(frame.z)), xy=frame.z)\n")
    out = tmp_path / "run"
    rc = main(["run", "cut_in_out", "--set", "duration_s=1", "--tracker", f"{src}:Mine", "--out", str(out),
               "--quiet", "--no-record"])
    assert rc == 0, capsys.readouterr().err
    assert testbed.read_run(out).scores["tracker"] == f"{src}:Mine"
    for spec, msg in ((f"{src}:Nope", "has no attribute 'Nope'"), ("no_such_module_xyz:T", "cannot import"),
                      (f"{tmp_path}/none.py:T", "no such file")):
        assert main(["run", "cut_in_out", "--tracker", spec, "--out", str(tmp_path / "x"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: --tracker") and msg in err and "\n" not in err
        assert not (tmp_path / "x").exists()


def test_a_tracker_returning_something_else_is_one_line(tmp_path, capsys):
    src = tmp_path / "bad.py"
    src.write_text("class Bad:\n    def step(self, frame):\n        return [1, 2]\n")
    rc = main(["run", "cut_in_out", "--set", "duration_s=1", "--tracker", f"{src}:Bad", "--out",
               str(tmp_path / "o"), "--quiet", "--no-record"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err and "returned a list, not a testbed.tracking.TrackSet" in err


def test_testbed_score_scores_a_csv_written_by_another_program(scn, tmp_path, capsys):
    """Another program's tracks (time instead of frame, id instead of track_id, no velocity, CSV) score like the
    run's own table, except the velocity RMSE it did not give."""
    out = tmp_path / "r"
    res = testbed.run(scn, tracker="gnn-kf", out=out, record=False)
    run = testbed.read_run(out)
    times = run.truth.groupby("frame").time.first()
    conf = run.tracks[run.tracks.status == "confirmed"]
    csv = tmp_path / "theirs.csv"
    pd.DataFrame({"time": conf.frame.map(times).round(6), "id": conf.track_id, "x": conf.x.round(6),
                  "y": conf.y.round(6)}).to_csv(csv, index=False)
    assert main(["score", str(out), "--tracks", str(csv), "--json"]) == 0
    import json

    doc = json.loads(capsys.readouterr().out)
    want = res.scores.to_dict()
    for k in ("tp_pct", "fp_pct", "breakup_pct", "cars_seen", "cars_tracked", "false_tracks", "relabel_events"):
        assert doc["scores"][k] == want[k], k
    assert doc["scores"]["pos_rmse_m"] == pytest.approx(want["pos_rmse_m"], abs=1e-5)
    assert doc["scores"]["vel_rmse_mps"] is None  # NaN, as JSON null
    assert doc["mot_metrics"]["hota"] == pytest.approx(res.metrics["hota"], abs=1e-6)
    assert main(["score", str(out)]) == 0 and "TP %" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,id,x\n0,1,2.0\n")
    assert main(["score", str(out), "--tracks", str(bad)]) == 2
    assert "no column 'y'" in capsys.readouterr().err


def test_score_on_plain_tables_and_its_errors(scn):
    truth = pd.DataFrame(dict(frame=[0, 0, 1, 1], vehicle_id=[1, 2, 1, 2], x=[0.0, 10, 1, 11], y=[0.0, 0, 0, 0],
                              vx=[10.0] * 4, vy=[0.0] * 4, n_points=[50] * 4))
    tracks = pd.DataFrame(dict(frame=[0, 1], track_id=[7, 7], x=[0.1, 1.1], y=[0.0, 0.0]))
    ev = testbed.score(truth, tracks)
    assert ev.scores.cars_seen == 2 and ev.scores.cars_tracked == 1 and ev.scores.false_tracks == 0
    assert ev.scores.pos_rmse_m == pytest.approx(0.1)
    from roadtrack.testbed.config.strict import ConfigError

    with pytest.raises(ConfigError, match="tracks.x, tracks.y: 1 rows hold a non-finite position"):
        testbed.score(truth, tracks.assign(x=[0.1, np.nan]))
    with pytest.raises(ConfigError, match="truth: no column 'n_points'"):
        testbed.score(truth.drop(columns="n_points"), tracks)


def test_trackset_checks_what_a_tracker_returns():
    TrackSet(ids=np.zeros(0, np.int64), xy=np.zeros((0, 2)))
    with pytest.raises(ValueError, match="a label appears twice"):
        TrackSet(ids=[1, 1], xy=np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"xy: expected shape \(2, 2\)"):
        TrackSet(ids=[1, 2], xy=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="positions must be finite"):
        TrackSet(ids=[1], xy=[[np.nan, 0.0]])
    with pytest.raises(ValueError, match="status"):
        TrackSet(ids=[1], xy=[[0.0, 0.0]], status=["lost"])


def test_the_example_runs_as_a_user_runs_it(tmp_path):
    proc = subprocess.run([sys.executable, "examples/run_my_tracker.py", "--out", str(tmp_path / "mine"),
                           "--duration", "2"], cwd=REPO, capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, RERUN_ANALYTICS="0"))
    assert proc.returncode == 0, proc.stderr
    assert "NearestNeighbour: TP" in proc.stdout and "(same as the run)" in proc.stdout
    assert (tmp_path / "mine" / "run.rrd").is_file()
