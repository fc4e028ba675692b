"""Thesis scores per car (TP / FP / break-ups), coverage and RMSE on hand-built truth and track tables."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadtrack.testbed.scoring.rates import format_table, score_run


def _truth(n_frames=20, visible=None):
    """Two cars: id 1 along y=0 at 20 m/s, id 2 along y=4 at 25 m/s; dt = 0.1 s; all visible by default."""
    f = np.repeat(np.arange(n_frames), 2)
    vid = np.tile([1, 2], n_frames)
    t = f * 0.1
    xy = np.column_stack([np.where(vid == 1, 20 * t, 10 + 25 * t), np.where(vid == 1, 0.0, 4.0)])
    v = np.column_stack([np.where(vid == 1, 20.0, 25.0), np.zeros(len(f))])
    vis = np.ones(len(f), bool) if visible is None else visible(f, vid)
    return dict(frame=f, vehicle_id=vid, xy=xy, v=v, visible=vis)


def _tracks(truth, ids, offset=(0.0, 0.0), dv=(0.0, 0.0), confirmed=True, rows=None):
    rows = np.ones(len(truth["frame"]), bool) if rows is None else rows
    ids = np.broadcast_to(np.asarray(ids, dtype=np.int64), rows.shape)
    return dict(frame=truth["frame"][rows], track_id=ids[rows].copy(), confirmed=np.full(int(rows.sum()), confirmed),
                xy=truth["xy"][rows] + np.asarray(offset), v=truth["v"][rows] + np.asarray(dv))


def _cat(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _ids(g, car1, car2):
    return np.where(g["vehicle_id"] == 1, car1, car2)


def test_perfect_tracking():
    g = _truth()
    s = score_run(g, _tracks(g, _ids(g, 10, 11)))
    assert (s.tp_pct, s.fp_pct, s.breakup_pct, s.fp_alt_pct) == (100.0, 0.0, 0.0, 0.0)
    assert (s.cars_seen, s.cars_tracked, s.false_tracks, s.correct_tracks, s.confirmed_tracks) == (2, 2, 0, 2, 2)
    assert (s.cars_relabelled, s.relabel_events) == (0, 0)
    assert s.track_precision_pct == 100.0 and s.coverage_pct == 100.0
    assert s.pos_rmse_m == pytest.approx(0.0, abs=1e-12) and s.vel_rmse_mps == pytest.approx(0.0, abs=1e-12)
    assert s.n_matched_frames == 40
    assert np.allclose(s.series_pos_rmse_m, 0.0)


def test_rmse_is_the_root_mean_square_of_the_offsets():
    g = _truth()
    s = score_run(g, _tracks(g, _ids(g, 10, 11), offset=(0.3, 0.4), dv=(1.0, 0.0)))
    assert s.pos_rmse_m == pytest.approx(0.5, rel=1e-12)
    assert s.vel_rmse_mps == pytest.approx(1.0, rel=1e-12)


def test_one_car_tracked_by_three_tracks_counts_once():
    """Car 1 is tracked by T10 (frames 0-5), T12 (6-12) and T13 (13-19): one car correctly tracked,
    three correct tracks, two relabel events, one car relabelled."""
    g = _truth()
    ids = _ids(g, 10, 11)
    ids[(g["vehicle_id"] == 1) & (g["frame"] >= 6)] = 12
    ids[(g["vehicle_id"] == 1) & (g["frame"] >= 13)] = 13
    s = score_run(g, _tracks(g, ids))
    assert (s.cars_seen, s.cars_tracked, s.correct_tracks, s.confirmed_tracks) == (2, 2, 4, 4)
    assert (s.relabel_events, s.cars_relabelled) == (2, 1)
    assert s.tp_pct == pytest.approx(100.0) and s.fp_pct == pytest.approx(0.0)
    assert s.breakup_pct == pytest.approx(50.0)          # 1 of 2 cars, not 2 events / 2 cars
    assert s.track_precision_pct == pytest.approx(100.0)


def test_track_flipping_between_two_cars_is_false():
    """T20 sits on car 1 for frames 0-9 and on car 2 for frames 10-19 (50/50 is not >= 60 %): a false
    track; both cars keep their own correct tracks on the frames T20 does not take."""
    g = _truth()
    f, vid = g["frame"], g["vehicle_id"]
    flip = _tracks(g, 20, rows=((vid == 1) & (f < 10)) | ((vid == 2) & (f >= 10)))
    own = _tracks(g, _ids(g, 10, 11), rows=((vid == 1) & (f >= 10)) | ((vid == 2) & (f < 10)))
    s = score_run(g, _cat(flip, own), correct_fraction=0.6)
    assert (s.cars_tracked, s.correct_tracks, s.false_tracks, s.confirmed_tracks) == (2, 2, 1, 3)
    assert s.tp_pct == pytest.approx(100.0) and s.fp_pct == pytest.approx(50.0)
    assert s.track_precision_pct == pytest.approx(200.0 / 3.0)
    assert (s.relabel_events, s.cars_relabelled) == (2, 2)   # each car: T20 -> own track
    assert s.breakup_pct == pytest.approx(100.0)
    assert s.coverage_pct == pytest.approx(50.0)              # correct tracks cover half the car-frames


def test_car_never_visible_is_not_a_car_seen():
    g = _truth(visible=lambda f, vid: vid == 1)
    s = score_run(g, _tracks(g, 10, rows=g["vehicle_id"] == 1))
    assert (s.cars_seen, s.cars_tracked) == (1, 1)
    assert s.tp_pct == pytest.approx(100.0) and s.fp_pct == pytest.approx(0.0)
    assert s.coverage_pct == pytest.approx(100.0)


def test_static_false_track():
    """A track parked 50 m away (a bush) for the whole run, and a tentative one that is ignored."""
    g = _truth()
    good = _tracks(g, _ids(g, 10, 11))
    bush = _tracks(g, 30, rows=g["vehicle_id"] == 1)
    bush["xy"] = np.tile([100.0, 20.0], (len(bush["frame"]), 1))
    tentative = _tracks(g, 40, offset=(0.0, -60.0), confirmed=False)
    s = score_run(g, _cat(good, bush, tentative))
    assert (s.cars_seen, s.cars_tracked, s.false_tracks, s.confirmed_tracks) == (2, 2, 1, 3)
    assert s.fp_pct == pytest.approx(50.0) and s.fp_alt_pct == pytest.approx(0.0)
    assert s.mean_false_tracks_per_frame == pytest.approx(1.0)


def test_coverage_counts_visible_car_frames_only():
    """Car 2 is hidden in frames 10-19 and its track is lost there: coverage stays 100 %."""
    g = _truth(visible=lambda f, vid: (vid == 1) | (f < 10))
    s = score_run(g, _tracks(g, _ids(g, 10, 11), rows=(g["vehicle_id"] == 1) | (g["frame"] < 10)))
    assert s.coverage_pct == pytest.approx(100.0)
    lost = _tracks(g, _ids(g, 10, 11), rows=(g["vehicle_id"] == 1) | (g["frame"] < 5))
    assert score_run(g, lost).coverage_pct == pytest.approx(100.0 * 25 / 30)


def test_correct_fraction_threshold():
    g = _truth()
    tr = _tracks(g, _ids(g, 10, 11))
    tr["xy"][(g["vehicle_id"] == 2) & (g["frame"] >= 8), 1] += 10.0  # matched 8 of 20 frames: 40 %
    assert score_run(g, tr, correct_fraction=0.5).correct_tracks == 1
    assert score_run(g, tr, correct_fraction=0.4).correct_tracks == 2


def test_assignment_is_one_to_one_within_match_distance():
    g = _truth()
    dup = _tracks(g, _ids(g, 20, 21), offset=(0.5, 0.0))  # duplicates of both
    s = score_run(g, _cat(_tracks(g, _ids(g, 10, 11)), dup), match_distance_m=3.0)
    assert (s.correct_tracks, s.false_tracks, s.cars_tracked) == (2, 2, 2)
    assert s.fp_pct == pytest.approx(100.0)
    assert s.pos_rmse_m == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5), min_size=40, max_size=40), st.integers(1, 20))
def test_breakup_never_exceeds_100_percent(labels, n_frames):
    """Any labelling of the car-frames (six labels) keeps break-up % and TP % in [0, 100]."""
    g = _truth(n_frames)
    ids = np.asarray(labels[: 2 * n_frames], dtype=np.int64)
    s = score_run(g, _tracks(g, ids))
    assert 0.0 <= s.breakup_pct <= 100.0 and 0.0 <= s.tp_pct <= 100.0
    assert s.cars_relabelled <= s.cars_seen and s.relabel_events >= s.cars_relabelled
    assert s.fp_alt_pct == pytest.approx(100.0 - s.tp_pct)


def test_empty_run_gives_nan_rates_not_errors():
    g = _truth(visible=lambda f, vid: np.zeros(len(f), bool))
    empty = dict(frame=np.zeros(0, np.int64), track_id=np.zeros(0, np.int64), confirmed=np.zeros(0, bool),
                 xy=np.zeros((0, 2)), v=np.zeros((0, 2)))
    s = score_run(g, empty)
    assert s.confirmed_tracks == 0 and np.isnan(s.tp_pct) and np.isnan(s.pos_rmse_m) and s.cars_seen == 0
    assert "nan" in format_table({"x": s})
