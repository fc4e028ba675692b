"""Thesis scores (TP / FP / break-ups, RMSE) on hand-made truth and tracks."""
from __future__ import annotations

import numpy as np
import pytest

from testbed.scoring import format_table, score_run


def _truth(n_frames=20):
    """Two vehicles: id 1 along y=0 at 20 m/s, id 2 along y=4 at 25 m/s; dt = 0.1 s."""
    f = np.repeat(np.arange(n_frames), 2)
    vid = np.tile([1, 2], n_frames)
    t = f * 0.1
    xy = np.column_stack([np.where(vid == 1, 20 * t, 10 + 25 * t), np.where(vid == 1, 0.0, 4.0)])
    v = np.column_stack([np.where(vid == 1, 20.0, 25.0), np.zeros(len(f))])
    return dict(frame=f, vehicle_id=vid, xy=xy, v=v)


def _tracks(truth, ids, offset=(0.0, 0.0), dv=(0.0, 0.0), confirmed=True):
    n = len(truth["frame"])
    return dict(frame=truth["frame"].copy(), track_id=np.asarray(ids, dtype=np.int64),
                confirmed=np.full(n, confirmed), xy=truth["xy"] + np.asarray(offset),
                v=truth["v"] + np.asarray(dv))


def _cat(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def test_perfect_tracking():
    g = _truth()
    s = score_run(g, _tracks(g, np.where(g["vehicle_id"] == 1, 10, 11)), np.array([1, 2]))
    assert (s.tp_pct, s.fp_pct, s.breakup_pct) == (100.0, 0.0, 0.0)
    assert (s.n_correct, s.n_false, s.n_ref, s.n_breakups, s.vehicles_seen, s.vehicles_tracked) == (2, 0, 2, 0, 2, 2)
    assert s.pos_rmse_m == pytest.approx(0.0, abs=1e-12) and s.vel_rmse_mps == pytest.approx(0.0, abs=1e-12)
    assert s.n_matched_frames == 40
    assert np.allclose(s.series_pos_rmse_m, 0.0)


def test_rmse_is_the_root_mean_square_of_the_offsets():
    g = _truth()
    s = score_run(g, _tracks(g, np.where(g["vehicle_id"] == 1, 10, 11), offset=(0.3, 0.4), dv=(1.0, 0.0)),
                  np.array([1, 2]))
    assert s.pos_rmse_m == pytest.approx(0.5, rel=1e-12)
    assert s.vel_rmse_mps == pytest.approx(1.0, rel=1e-12)


def test_relabel_counts_one_breakup_per_relabel():
    g = _truth()
    ids = np.where(g["vehicle_id"] == 1, 10, 11)
    ids[(g["vehicle_id"] == 1) & (g["frame"] >= 12)] = 12  # vehicle 1 re-acquired under a new label
    s = score_run(g, _tracks(g, ids), np.array([1, 2]))
    assert s.n_breakups == 1 and s.breakup_pct == pytest.approx(50.0)
    assert (s.n_correct, s.n_false) == (3, 0)  # both labels of vehicle 1 are correct tracks
    assert s.tp_pct == pytest.approx(100.0)


def test_far_track_is_false_and_unconfirmed_tracks_are_ignored():
    g = _truth()
    good = _tracks(g, np.where(g["vehicle_id"] == 1, 10, 11))
    far = _tracks(g, np.full(len(g["frame"]), 30), offset=(0.0, 50.0))
    far["track_id"][g["vehicle_id"] == 2] = 31
    tentative = _tracks(g, np.full(len(g["frame"]), 40), offset=(0.0, -60.0), confirmed=False)
    s = score_run(g, _cat(good, far, tentative), np.array([1, 2]))
    assert (s.n_correct, s.n_false, s.n_ref) == (2, 2, 4)
    assert s.tp_pct == pytest.approx(50.0) and s.fp_pct == pytest.approx(50.0)
    assert s.mean_false_tracks_per_frame == pytest.approx(2.0)


def test_correct_fraction_threshold():
    g = _truth()
    ids = np.where(g["vehicle_id"] == 1, 10, 11)
    tr = _tracks(g, ids)
    # track 11 drifts 10 m away for the last 12 of its 20 frames: matched 8/20 = 40 %
    drift = (g["vehicle_id"] == 2) & (g["frame"] >= 8)
    tr["xy"][drift, 1] += 10.0
    assert score_run(g, tr, np.array([1, 2]), correct_fraction=0.5).n_correct == 1
    assert score_run(g, tr, np.array([1, 2]), correct_fraction=0.4).n_correct == 2


def test_assignment_is_one_to_one_within_match_distance():
    g = _truth()
    ids = np.where(g["vehicle_id"] == 1, 10, 11)
    dup = _tracks(g, np.where(g["vehicle_id"] == 1, 20, 21), offset=(0.5, 0.0))  # duplicates of both
    s = score_run(g, _cat(_tracks(g, ids), dup), np.array([1, 2]), match_distance_m=3.0)
    assert (s.n_correct, s.n_false) == (2, 2)  # the duplicates never win a vehicle
    assert s.pos_rmse_m == pytest.approx(0.0, abs=1e-12)


def test_empty_run_gives_nan_rates_not_errors():
    g = _truth()
    empty = dict(frame=np.zeros(0, np.int64), track_id=np.zeros(0, np.int64), confirmed=np.zeros(0, bool),
                 xy=np.zeros((0, 2)), v=np.zeros((0, 2)))
    s = score_run(g, empty, np.zeros(0, np.int64))
    assert s.n_ref == 0 and np.isnan(s.tp_pct) and np.isnan(s.pos_rmse_m) and s.vehicles_seen == 0
    assert "nan" in format_table({"x": s})
