"""Box tracking (issue 32.4): each track's bird's-eye-view box (heading, length, width) filtered beside its kinematics
(trackers/box.py), box columns in tracks.parquet, boxes in the recording, and box-overlap (BEV IoU) HOTA / MOTA /
IDF1 beside the centre-distance scores (testbed/scoring/boxes.py)."""
from __future__ import annotations

import collections
import json
import math

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.scenario.spec import load_scenario
from roadtrack.testbed.scoring.boxes import bev_iou, box_metrics
from roadtrack.testbed.scoring.evaluate import score
from roadtrack.testbed.tracking.builtin import along_motion
from roadtrack.trackers import BoxParams, box_birth, box_update


def test_bev_iou_of_known_overlaps():
    a = np.array([[0.0, 0.0, 0.0, 4.0, 2.0]])
    assert bev_iou(a, a)[0, 0] == pytest.approx(1.0)
    assert bev_iou(a, a + [0, 0, math.pi, 0, 0])[0, 0] == pytest.approx(1.0)  # turned by pi: the same rectangle
    sq = np.array([[1.0, 2.0, 0.3, 3.0, 3.0]])
    assert bev_iou(sq, sq + [0, 0, math.pi / 2, 0, 0])[0, 0] == pytest.approx(1.0)
    assert bev_iou(a, a + [2.0, 0, 0, 0, 0])[0, 0] == pytest.approx(4.0 / 12.0)  # overlap 2 x 2 of 8 + 8 - 4
    assert bev_iou(a, a + [10.0, 0, 0, 0, 0])[0, 0] == 0.0
    assert bev_iou(a, np.zeros((0, 5))).shape == (1, 0)
    # a turned box against a Monte Carlo estimate of the overlap
    b = np.array([[1.0, 0.5, math.pi / 5, 4.5, 1.8]])
    rng = np.random.default_rng(0)
    p = rng.uniform([-4, -4], [4, 4], (400_000, 2))

    def inside(box):
        x, y, h, l, w = box[0]
        d = p - [x, y]
        u, v = d @ [math.cos(h), math.sin(h)], d @ [-math.sin(h), math.cos(h)]
        return (np.abs(u) <= l / 2) & (np.abs(v) <= w / 2)

    ia, ib = inside(a), inside(b)
    assert bev_iou(a, b)[0, 0] == pytest.approx((ia & ib).sum() / (ia | ib).sum(), abs=0.01)


def test_the_box_filter_converges_and_reads_headings_modulo_pi():
    params = BoxParams()
    rng = np.random.default_rng(1)
    true = np.array([0.4, 4.8, 1.9])
    b, var = box_birth(true + [0.2, 0.8, -0.5], params)
    b, var = b[None], var[None]
    late = []
    for k in range(400):
        y = true + rng.normal(0.0, [0.1, 0.4, 0.4])
        y[0] += math.pi * (k % 2)  # every other fit reports the heading turned by pi
        b, var = box_update(b, var, y[None], np.array([[1.0]]), np.array([0.0]), 0.1, params)
        if k >= 200:
            late.append(b[0].copy())
    np.testing.assert_allclose(np.mean(late, axis=0), true, atol=0.1)  # unbiased (about 3 std of this mean), flips undone
    assert np.std(np.array(late)[:, 1]) < 0.15  # and far less noisy than one fit (0.4 m)
    assert np.all(var[0] < params.r)
    # a miss (beta0 = 1) only predicts: the box stays, its variances grow by q dt
    b2, var2 = box_update(b, var, np.zeros((0, 3)), np.zeros((1, 0)), np.array([1.0]), 0.5, params)
    np.testing.assert_array_equal(b2, b)
    np.testing.assert_allclose(var2, var + 0.5 * params.q)
    # one scalar KF step by hand: K = P / (P + r), b + K nu
    b3, var3 = box_update(np.array([[0.0, 4.0, 2.0]]), np.array([[0.04, 0.25, 0.25]]), np.array([[0.1, 5.0, 2.0]]),
                          np.array([[1.0]]), np.array([0.0]), 0.0, params)
    K = np.array([0.04, 0.25, 0.25]) / (np.array([0.04, 0.25, 0.25]) + params.r)
    np.testing.assert_allclose(b3[0], [0.0, 4.0, 2.0] + K * [0.1, 1.0, 0.0])
    np.testing.assert_allclose(var3[0], (1 - K) * [0.04, 0.25, 0.25])
    with pytest.raises(ValueError, match="sigma_heading"):
        BoxParams(sigma_heading=0.0)


def test_a_reported_heading_points_along_the_motion():
    box = np.array([[math.pi - 0.05, 4.5, 1.8], [0.1, 4.5, 1.8], [2.0, 4.0, 2.0]])
    out = along_motion(box, np.array([[20.0, 0.0], [20.0, 0.0], [0.1, 0.0]]))
    np.testing.assert_allclose(out[:, 0], [-0.05, 0.1, 2.0], atol=1e-12)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("box")
    on = run_scenario(load_scenario("cut_in_out", {"duration_s": 6.0, "tracker.box": True, "record.level": "light"}),
                      out_dir=root / "on", record=True)
    off = run_scenario(load_scenario("cut_in_out", {"duration_s": 6.0}), out_dir=root / "off", record=False)
    return on, off


def test_a_box_run_writes_boxes_and_box_overlap_scores(runs):
    on, off = runs
    t_on, t_off = pd.read_parquet(on.out_dir / "tracks.parquet"), pd.read_parquet(off.out_dir / "tracks.parquet")
    assert list(t_on.columns) == list(t_off.columns) + ["heading", "length", "width"]
    pd.testing.assert_frame_equal(t_on[t_off.columns], t_off)  # the kinematic tracks are those without boxes
    conf = t_on[t_on.status == "confirmed"]
    assert conf[["heading", "length", "width"]].notna().all().all()
    assert conf.length.between(3.5, 6.5).all() and conf.width.between(1.4, 2.6).all()
    doc = json.loads((on.out_dir / "scores.json").read_text())["mot_metrics"]
    assert doc["bev_mean_iou"] > 0.7 and doc["bev_mota"] > 0.7 and doc["bev_hota"] > 0.6
    assert "bev_hota" not in json.loads((off.out_dir / "scores.json").read_text())["mot_metrics"]
    assert {k: v for k, v in doc.items() if not k.startswith("bev_")} == off.metrics
    rows = collections.Counter()
    for chunk in RrdReader(str(on.out_dir / "run.rrd")).stream():
        rows[chunk.entity_path] += chunk.num_rows
    assert rows["/world/tracks/boxes"] == 61


def test_any_tracks_table_with_boxes_gets_box_scores(runs):
    on, _ = runs
    truth = pd.read_parquet(on.out_dir / "truth.parquet")
    tracks = pd.read_parquet(on.out_dir / "tracks.parquet")
    ev = score(truth, tracks, n_frames=61)
    assert ev.metrics["bev_hota"] == pytest.approx(on.metrics["bev_hota"])
    perfect = truth[~truth.is_ego].rename(columns={"vehicle_id": "track_id"})
    m = box_metrics({"frame": truth.frame[~truth.is_ego], "vehicle_id": truth.vehicle_id[~truth.is_ego],
                     "box": truth.loc[~truth.is_ego, ["x", "y", "heading", "length", "width"]].to_numpy()},
                    {"frame": perfect.frame, "track_id": perfect.track_id,
                     "box": perfect[["x", "y", "heading", "length", "width"]].to_numpy()}, 61)
    assert m["hota"] == pytest.approx(1.0) and m["mota"] == 1.0 and m["mean_iou"] == pytest.approx(1.0)


def test_box_tracking_needs_a_built_in_tracker_reading_the_lidar(tmp_path):
    with pytest.raises(ConfigError, match=r"^tracker\.box: box tracking reads the LiDAR's fitted boxes") as err:
        run_scenario(load_scenario("cut_in_out", {"duration_s": 0.3, "tracker.box": True, "sensor.extra": ["radar"],
                                                  "tracker.sensors": ["radar"]}), out_dir=tmp_path / "a", record=False)
    assert "\n" not in str(err.value)

    class Mine:
        def step(self, frame):
            raise AssertionError("not reached")

    with pytest.raises(ConfigError, match=r"^tracker\.box: box tracking is a step of the built-in trackers"):
        run_scenario(load_scenario("cut_in_out", {"duration_s": 0.3, "tracker.box": True}), out_dir=tmp_path / "b",
                     record=False, tracker=Mine())


def test_the_html_replay_draws_the_track_boxes(runs):
    from roadtrack.testbed.export.html import replay_data
    from roadtrack.testbed.pipeline.runfolder import read_run

    on, off = runs
    data = replay_data(read_run(on.out_dir), [])
    assert len(data["tracks"]["h"]) == len(data["tracks"]["x"]) and min(data["tracks"]["l"]) > 0
    assert "h" not in replay_data(read_run(off.out_dir), [])["tracks"] and data["sensors"]["x"] == []
