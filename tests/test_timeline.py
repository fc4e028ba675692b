"""timeline.png (issue 20.5): each car seen as a bar over its visible frames, coloured by the confirmed track that
covered it, relabels and false tracks marked, and the per-car position error; written by `testbed run`."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from roadtrack.testbed.scoring.evaluate import score
from roadtrack.testbed.scoring.timeline import _runs, car_timeline, draw_timeline

REPO = Path(__file__).resolve().parent.parent


def _tables():
    """Car 1 visible frames 0-19, tracked by T1 on 0-9 and T2 on 12-19 (a relabel at frame 12); car 2 visible
    on 0-4 and 10-19 (hidden 5-9), never tracked; T3 a false track (20 m off any car) on frames 3-8."""
    rows = []
    for f in range(20):
        rows.append(dict(frame=f, vehicle_id=1, x=10.0 * f * 0.1, y=0.0, vx=10.0, vy=0.0, n_points=50))
        rows.append(dict(frame=f, vehicle_id=2, x=5.0, y=7.0, vx=0.0, vy=0.0, n_points=0 if 5 <= f <= 9 else 20))
    truth = pd.DataFrame(rows)
    tr = []
    for f in range(20):
        if f <= 9:
            tr.append(dict(frame=f, track_id=1, x=f * 1.0 + 0.3, y=0.0, status="confirmed"))
        if f >= 12:
            tr.append(dict(frame=f, track_id=2, x=f * 1.0 - 0.4, y=0.0, status="confirmed"))
        if 3 <= f <= 8:
            tr.append(dict(frame=f, track_id=3, x=30.0, y=-20.0, status="confirmed"))
    return truth, pd.DataFrame(tr)


def test_runs_split_at_gaps_and_at_mask_changes():
    assert _runs(np.array([1, 1, 0, 1, 1, 1], bool), np.array([0, 1, 2, 3, 4, 6])) == [(0, 2), (3, 5), (6, 7)]
    assert _runs(np.zeros(3, bool), np.arange(3)) == []


def test_timeline_has_the_cars_tracks_relabels_and_false_tracks_the_scores_count(tmp_path):
    truth, tracks = _tables()
    tl = car_timeline(truth, tracks)
    assert list(tl.cars) == [1, 2]
    assert tl.correct == {1: 1, 2: 1} and set(tl.false_tracks) == {3}
    np.testing.assert_array_equal(tl.false_tracks[3], np.arange(3, 9))
    a = tl.assigned[0]
    assert (a[:10] == 1).all() and (a[10:12] == -1).all() and (a[12:] == 2).all()
    np.testing.assert_array_equal(tl.relabels(0), [12])
    assert (tl.assigned[1] == -1).all() and not tl.visible[1][5:10].any() and tl.visible[1][:5].all()
    np.testing.assert_allclose(tl.err[0][:10], 0.3, atol=1e-12)
    np.testing.assert_allclose(tl.err[0][12:], 0.4, atol=1e-12)
    s = score(truth, tracks).scores  # the same counts as the thesis-form scores
    assert (s.cars_seen, s.false_tracks, s.cars_relabelled) == (len(tl.cars), len(tl.false_tracks), 1)
    path = draw_timeline(tl, tmp_path / "timeline.png", 10.0, "synthetic")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_testbed_run_writes_the_timeline(tmp_path, short_run):
    out, proc = short_run  # `testbed run cut_in_out ... --quiet`, recorded, run once for the session (conftest)
    assert proc.returncode == 0, proc.stderr
    assert "timeline.png" in proc.stdout
    assert (out / "timeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    proc = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "run", "cut_in_out", "--set", "duration_s=1",
                           "--no-record", "--no-plot", "--out", str(tmp_path / "bare"), "--quiet"],
                          capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "bare" / "timeline.png").exists() and "timeline.png" not in proc.stdout


def test_a_timeline_that_cannot_be_drawn_is_a_warning_and_the_run_stands(tmp_path, monkeypatch, capsys):
    """If drawing fails, `testbed run` still commits the run (exit 0, no INCOMPLETE) and says so in one line."""
    import roadtrack.testbed.pipeline.plots as plots
    from roadtrack.testbed.cli.main import main

    def broken(folder):
        raise ValueError("no figure today")

    monkeypatch.setattr(plots, "write_run_plots", broken)
    out = tmp_path / "run"
    code = main(["run", "cut_in_out", "--set", "duration_s=0.3", "--no-record", "--out", str(out), "--quiet"])
    err = capsys.readouterr()
    assert code == 0, err.err
    assert "warning: timeline.png not drawn: ValueError: no figure today" in err.err
    assert "timeline.png" not in err.out and (out / "scores.json").is_file() and not (out / "INCOMPLETE").exists()
