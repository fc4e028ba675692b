"""A run's events (issue 34.1): every relabel, false track and missed car with its time, car, tracks and cause,
in events.parquet, printed after the score table, marked in the recording, and `testbed view --event N`."""
from __future__ import annotations

import collections

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.recording.view import event_time
from roadtrack.testbed.scoring.events import COLUMNS, format_events, run_events

from conftest import cli as _cli


def _tables():
    """Car 1 visible on frames 0-19, tracked by T1 on 0-9 and T2 on 12-19 (T1 deleted while the car is in view:
    a relabel at frame 12); car 2 visible on 0-5 and 16-19 (hidden half the time), never tracked; T3 a false
    track 20 m off any car on frames 3-8; car 3 seen on frames 15-17 only; car 4 always in view, never tracked."""
    rows = []
    for f in range(20):
        rows.append(dict(frame=f, vehicle_id=1, x=f * 1.0, y=0.0, heading=0.0, vx=10.0, vy=0.0, n_points=50))
        rows.append(dict(frame=f, vehicle_id=2, x=5.0, y=7.0, heading=0.0, vx=0.0, vy=0.0,
                         n_points=0 if 6 <= f <= 15 else 20))
        rows.append(dict(frame=f, vehicle_id=4, x=40.0, y=30.0, heading=0.0, vx=0.0, vy=0.0, n_points=30))
        rows.append(dict(frame=f, vehicle_id=3, x=60.0, y=-7.0, heading=0.0, vx=0.0, vy=0.0,
                         n_points=20 if 15 <= f <= 17 else 0))
    tr = []
    for f in range(20):
        if f <= 9:
            tr.append(dict(frame=f, track_id=1, x=f * 1.0 + 0.3, y=0.0, status="confirmed"))
        if f >= 12:
            tr.append(dict(frame=f, track_id=2, x=f * 1.0 - 0.4, y=0.0, status="confirmed"))
        if 3 <= f <= 8:
            tr.append(dict(frame=f, track_id=3, x=30.0, y=-20.0, status="confirmed"))
    return pd.DataFrame(rows), pd.DataFrame(tr)


def test_events_list_relabels_false_tracks_and_missed_cars_with_their_causes():
    truth, tracks = _tables()
    ev = run_events(truth, tracks, dt=0.1)
    assert tuple(ev.columns) == COLUMNS and ev["event"].tolist() == [1, 2, 3, 4, 5]
    got = [(r.frame, r.kind, r.car, r.old_track, r.new_track, r.cause) for r in ev.itertuples()]
    assert got == [(0, "missed car", 2, -1, -1, "occlusion"),
                   (0, "missed car", 4, -1, -1, "never confirmed"),
                   (3, "false track", -1, -1, 3, "clutter"),
                   (12, "relabel", 1, 1, 2, "deletion while visible"),
                   (15, "missed car", 3, -1, -1, "seen briefly")]
    np.testing.assert_allclose(ev["time"], ev["frame"] * 0.1, atol=1e-12)
    rel = ev[ev["kind"] == "relabel"].iloc[0]
    assert (rel["x"], rel["y"]) == (12.0, 0.0)  # where the car was at the relabel
    text = format_events(ev)
    assert "relabel of car 1: T1 -> T2 (deletion while visible)" in text and text.count("\n") == len(ev)
    assert "... and 3 more" in format_events(ev, limit=2)


def test_a_false_track_on_a_tracked_car_is_a_duplicate_and_on_two_cars_a_swap():
    truth, tracks = _tables()
    dup = [dict(frame=f, track_id=7, x=f * 1.0, y=0.0, status="confirmed") for f in range(10, 12)]  # car 1's gap
    dup += [dict(frame=f, track_id=7, x=90.0, y=90.0, status="confirmed") for f in range(12, 20)]
    ev = run_events(truth, pd.concat([tracks, pd.DataFrame(dup)]), dt=0.1)
    row = ev[(ev["kind"] == "false track") & (ev["new_track"] == 7)].iloc[0]
    assert (row["cause"], row["car"], row["frame"]) == ("duplicate", 1, 10)
    swap = [dict(frame=f, track_id=8, x=5.0, y=7.0, status="confirmed") for f in range(0, 3)]  # car 2, then car 4
    swap += [dict(frame=f, track_id=8, x=40.0, y=30.0, status="confirmed") for f in range(3, 6)]
    swap += [dict(frame=f, track_id=8, x=-90.0, y=90.0, status="confirmed") for f in range(6, 20)]
    ev = run_events(truth, pd.concat([tracks, pd.DataFrame(swap)]), dt=0.1)
    assert ev[ev["new_track"] == 8]["cause"].tolist() == ["swap"]
    assert ev[(ev["kind"] == "missed car") & (ev["car"] == 4)]["cause"].tolist() == ["wrong track"]


def test_a_real_run_lists_its_events_in_a_table_the_terminal_and_the_recording(short_run):
    from rerun.chunk import RrdReader

    out, proc = short_run
    ev = pd.read_parquet(out / "events.parquet")
    assert tuple(ev.columns) == COLUMNS
    rel = ev[ev["kind"] == "relabel"]
    assert [(r.frame, r.car, r.old_track, r.new_track, r.cause) for r in rel.itertuples()] == \
        [(71, 2, 2, 3, "merge"), (72, 2, 3, 2, "merge")]
    assert "relabel of car 2: T2 -> T3 (merge)" in proc.stdout
    assert proc.stdout.index("events (") > proc.stdout.index("GOSPA")  # after the score table
    rows, texts = collections.Counter(), []
    for ch in RrdReader(str(out / "run.rrd")).stream():
        rows[ch.entity_path] += ch.num_rows
        if ch.entity_path == "/events":
            texts += [t for t in ch.to_record_batch().column("TextLog:text").to_pylist()]
    assert len(texts) == len(ev) and any("T2 -> T3 (merge)" in str(t) for t in texts)
    assert rows["/world/events"] >= 10  # the rings follow the car for up to 3 s (until the run's end at frame 80)


def test_view_event_resolves_to_the_events_time_and_refuses_a_missing_one(short_run, capsys):
    out, _ = short_run
    assert event_time(out, 1) == pytest.approx(7.1, abs=1e-9)
    assert event_time(out, 2) == pytest.approx(7.2, abs=1e-9)
    assert "event 2 at 7.2 s: relabel of car 2: T3 -> T2 (merge)" in capsys.readouterr().err
    n = len(pd.read_parquet(out / "events.parquet"))
    with pytest.raises(ConfigError, match=f"allowed: 1..{n}"):
        event_time(out, n + 1)
    proc = _cli("view", str(out), "--event", str(n + 1), timeout=60)  # one line, exit 2, no viewer started
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "no such event" in proc.stderr
    proc = _cli("view", str(out), "--event", "0", timeout=60)
    assert proc.returncode == 2 and "event number >= 1" in proc.stderr


def test_a_track_and_the_track_replacing_it_have_different_colours_in_the_viewer_and_the_timeline(short_run):
    """Every relabel's old and new track differ in colour, and the recording's confirmed-track colours are the
    ones the timeline and the exports replay from tracks.parquet (testbed.recording.slots.track_colours)."""
    from rerun.chunk import RrdReader

    from roadtrack.testbed.recording.slots import track_colours

    out, _ = short_run
    col = {t: tuple(c.tolist()) for t, c in track_colours(pd.read_parquet(out / "tracks.parquet")).items()}
    ev = pd.read_parquet(out / "events.parquet")
    for r in ev[ev["kind"] == "relabel"].itertuples():
        assert col[r.old_track] != col[r.new_track]
    seen = {}
    for ch in RrdReader(str(out / "run.rrd")).stream():
        if ch.entity_path == "/world/tracks/confirmed":
            rb = ch.to_record_batch()
            for ids, cs in zip(rb.column("Points3D:class_ids").to_pylist(), rb.column("Points3D:colors").to_pylist()):
                for i, c in zip(ids or [], cs or []):
                    seen[int(i)] = tuple((int(c) >> s) & 255 for s in (24, 16, 8))  # packed RGBA
    assert seen and seen == {t: col[t] for t in seen}


def test_score_lists_the_events_of_any_tracks_table(short_run, tmp_path):
    """`testbed score RUN --tracks FILE` (another program's tracks) lists that table's events: here the run's
    tracks with T3 renamed T30."""
    out, _ = short_run
    tracks = pd.read_parquet(out / "tracks.parquet")
    tracks["track_id"] = tracks["track_id"].replace(3, 30)
    tracks[["frame", "track_id", "x", "y", "status"]].to_csv(tmp_path / "theirs.csv", index=False)
    proc = _cli("score", str(out), "--tracks", str(tmp_path / "theirs.csv"), timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "relabel of car 2: T2 -> T30 (merge)" in proc.stdout and "relabel of car 2: T30 -> T2 (merge)" in proc.stdout
