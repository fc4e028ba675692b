"""Detections that carry their measurement model (issue 32.1, 32.3): the radar's range / azimuth / range-rate model,
a tracker re-bound to a sensor's model (`Tracker.with_measurement`), the sequential update of a further sensor
(`Tracker.update`) against a hand-computed EKF update, the radar sensor on its own random stream, and radar-alone
and LiDAR + radar runs end to end (tables, recording read back, sensing cache, one-line errors)."""
from __future__ import annotations

import collections
import math

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader

from roadtrack.testbed.common import streams
from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.scenario.spec import load_scenario
from roadtrack.testbed.sensing import Measurements, scenario_sensors, sense
from roadtrack.testbed.sensing.radar import in_view
from roadtrack.trackers import make_tracker
from roadtrack.trackers.filters import ExtendedKalmanFilter, KalmanFilter, with_measurement
from roadtrack.trackers.models import ConstantVelocity, CoordinatedTurn, PositionMeasurement, RangeBearingRate

CV = ConstantVelocity(1.0)
RADAR = RangeBearingRate(0.5, 0.01, 0.2, pose=(3.0, -1.0, 0.3), velocity=(20.0, 1.0))


def test_the_radar_model_and_its_jacobian_match_finite_differences():
    for motion, x in ((CV, np.array([40.0, 5.0, 25.0, -1.0])), (CoordinatedTurn(1.0, 0.1), np.array(
            [-10.0, 30.0, -3.0, 8.0, 0.2]))):
        z = RADAR.h(x, motion)
        d = x[:2] - np.array(RADAR.pose[:2])
        u = x[2:4] - np.array(RADAR.velocity)
        assert z[0] == pytest.approx(np.hypot(*d)) and z[2] == pytest.approx(d @ u / np.hypot(*d))
        assert z[1] == pytest.approx(math.atan2(d[1], d[0]) - 0.3)
        H = RADAR.jacobian(x, motion)
        num = np.zeros_like(H)
        for i in range(len(x)):
            e = np.zeros(len(x))
            e[i] = 1e-6
            num[:, i] = RADAR.residual(RADAR.h(x + e, motion), RADAR.h(x - e, motion)) / 2e-6
        np.testing.assert_allclose(H, num, atol=1e-7)
    p, P = RADAR.position_of(RADAR.h(np.array([40.0, 5.0, 25.0, -1.0]), CV))
    np.testing.assert_allclose(p, [40.0, 5.0], atol=1e-9)
    assert P.shape == (2, 2) and np.all(np.linalg.eigvalsh(P) > 0)
    assert RADAR.residual(np.array([1.0, 3.1, 0.0]), np.array([1.0, -3.1, 0.0]))[1] == pytest.approx(6.2 - 2 * np.pi)


def test_a_filter_takes_the_model_it_can_and_refuses_the_others_in_one_line():
    kf = make_tracker("jpda-kf").filter
    ekf = with_measurement(kf, RADAR)
    assert isinstance(kf, KalmanFilter) and isinstance(ekf, ExtendedKalmanFilter) and ekf.measurement is RADAR
    assert with_measurement(kf, kf.measurement) is kf
    assert isinstance(with_measurement(kf, PositionMeasurement(0.5)), KalmanFilter)
    imm = with_measurement(make_tracker("imm-pda-kf").filter, RADAR)
    assert all(f.measurement is RADAR for f in imm.filters)
    for name in ("pda-svsf", "jpda-gvbl-svsf", "pda-gc-svsf"):
        with pytest.raises(ValueError, match=r"takes only its own kind of measurement") as err:
            make_tracker(name).with_measurement(RADAR)
        assert "\n" not in str(err.value)


def _tracks(name: str):
    trk = make_tracker(name)
    tracks, nid = (), 1
    rng = np.random.default_rng(3)
    truth = np.array([[20.0, 0.0, 10.0, 0.0], [40.0, 3.5, 12.0, 0.0]])
    for _ in range(15):
        truth[:, :2] += 0.1 * truth[:, 2:]
        res = trk.step(tracks, truth[:, :2] + 0.2 * rng.standard_normal((2, 2)), 0.1, nid)
        tracks, nid = res.tracks, res.next_id
    return trk, tracks, truth


def test_a_further_sensors_update_is_the_hand_computed_ekf_update():
    trk, tracks, truth = _tracks("nn-kf")
    live = [t for t in tracks if not t.candidate and t.confirmed]
    assert len(live) == 2
    Z = np.array([RADAR.h(np.r_[truth[i, :2] + 0.1, truth[i, 2:]], CV) for i in range(2)])
    radar = trk.with_measurement(RADAR, clutter_density=1e-4)
    res = radar.update(tracks, Z, 0.0)
    assert len(res.tracks) == len(tracks) and res.info.W.shape == (len(res.info.ids), len(Z))
    for before, after in zip(tracks, res.tracks):
        assert (before.id, before.score, before.age, before.hits) == (after.id, after.score, after.age, after.hits)
        if before.candidate:
            assert after is before
            continue
        x, P = before.state.x, before.state.P
        j = int(np.argmin([np.linalg.norm(RADAR.residual(z, RADAR.h(x, CV))) for z in Z]))
        H = RADAR.jacobian(x, CV)
        S = H @ P @ H.T + RADAR.R
        K = P @ H.T @ np.linalg.inv(S)
        nu = RADAR.residual(Z[j], RADAR.h(x, CV))
        I_KH = np.eye(4) - K @ H
        np.testing.assert_allclose(after.state.x, x + K @ nu, atol=1e-9)  # thesis (1.11) EKF update
        np.testing.assert_allclose(after.state.P, I_KH @ P @ I_KH.T + K @ RADAR.R @ K.T, atol=1e-9)  # Joseph form
        np.testing.assert_array_equal(after.state.e_post, before.state.e_post)  # the LiDAR's memory is kept
    # the next LiDAR step takes the updated tracks as they are
    nxt = trk.step(res.tracks, truth[:, :2], 0.1, 100)
    assert {t.id for t in nxt.tracks if t.confirmed} >= {t.id for t in live}


def test_an_imm_takes_a_radar_update_and_goes_on_with_the_lidar():
    trk, tracks, truth = _tracks("imm-pda-kf")
    Z = np.array([RADAR.h(np.r_[t[:2], t[2:]], CV) for t in truth])
    res = trk.with_measurement(RADAR).update(tracks, Z, 0.0)
    moved = [np.linalg.norm(a.state.x[:2] - b.state.x[:2]) for a, b in zip(tracks, res.tracks) if not a.candidate]
    assert max(moved) > 0.0
    for a, b in zip(tracks, res.tracks):
        if not a.candidate:
            assert [m.e_post.shape for m in b.state.modes] == [m.e_post.shape for m in a.state.modes]
            assert abs(b.state.mu.sum() - 1.0) < 1e-12
    trk.step(res.tracks, truth[:, :2], 0.1, 100)


def test_the_radar_senses_on_its_own_stream_and_leaves_the_lidar_as_it_was():
    base = load_scenario("cut_in_out", {"duration_s": 1.0})
    scn = load_scenario("cut_in_out", {"duration_s": 1.0, "sensor.extra": ["radar"], "sensor.radar.pd": 1.0,
                                       "sensor.radar.clutter_per_scan": 0.0})
    assert [s.name for s in scenario_sensors(scn)] == ["lidar", "radar"]
    assert scenario_sensors(scn)[1].streams == ("sensor.radar",) and "sensor.radar" not in streams.LEGACY
    seen = 0
    for a, b in zip(sense(base), sense(scn)):
        np.testing.assert_array_equal(a.detections.z, b.detections.z)
        got = b.others["radar"].data
        view, exact = in_view(type("C", (), {"scn": scn})(), b.truth)
        np.testing.assert_array_equal(np.sort(got["truth_id"]), np.sort(b.truth.ids[view]))  # pd 1, no clutter
        for z, vid in zip(got["z"], got["truth_id"]):
            err = np.abs(z - exact[np.flatnonzero(b.truth.ids == vid)[0]])
            assert err[0] < 5 * 0.25 and err[1] < 5 * math.radians(1.0) and err[2] < 5 * 0.1
        seen += len(got["z"])
    assert seen >= 10


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """cut_in_out, 6 s, with the radar: fused, sensed live and recorded; LiDAR alone (filling a sensing cache),
    radar alone and fused again from that cache."""
    root = tmp_path_factory.mktemp("radar")

    def scn(sensors):
        return load_scenario("cut_in_out", {"duration_s": 6.0, "sensor.extra": ["radar"], "tracker.sensors": sensors,
                                            "record.level": "light"})

    out = {"fused": run_scenario(scn(["lidar", "radar"]), out_dir=root / "fused", record=True)}
    for name, sensors in (("lidar", ["lidar"]), ("radar", ["radar"]), ("cached", ["lidar", "radar"])):
        out[name] = run_scenario(scn(sensors), out_dir=root / name, record=False, sensing_cache=root / "cache")
    return out


def test_radar_alone_and_fused_runs_track_every_car(runs):
    for name in ("lidar", "radar", "fused"):
        s = runs[name].scores
        assert s.cars_tracked == s.cars_seen == 3 and s.false_tracks == 0, name
    assert runs["fused"].scores.pos_rmse_m < runs["lidar"].scores.pos_rmse_m  # the radar's range helps
    fused = runs["fused"].out_dir
    radar = pd.read_parquet(fused / "detections-radar.parquet")
    assert list(radar.columns) == ["frame", "time", "x", "y", "z"] and radar.frame.nunique() == 61
    assert np.stack(radar.z).shape == (len(radar), 3)
    rows = collections.Counter()
    for chunk in RrdReader(str(fused / "run.rrd")).stream():
        rows[chunk.entity_path] += chunk.num_rows
    assert rows["/world/sensors/radar"] == 61


def test_a_fused_run_from_the_sensing_cache_equals_the_live_one(runs):
    live, cached = runs["fused"].out_dir, runs["cached"].out_dir
    for table in ("tracks", "detections-radar"):
        pd.testing.assert_frame_equal(pd.read_parquet(live / f"{table}.parquet"),
                                      pd.read_parquet(cached / f"{table}.parquet"))


def test_bad_sensor_lists_are_one_line_errors(tmp_path):
    cases = (({"tracker.sensors": ["radar"]}, r"tracker\.sensors\[0\]: 'radar' is not a sensor of this scenario"),
             ({"tracker.sensors": []}, r"tracker\.sensors"),
             ({"tracker.sensors": ["lidar", "lidar"]}, r"tracker\.sensors"),
             ({"sensor.extra": ["radar"], "tracker.sensors": ["lidar", "radar"], "tracker.name": "pda-svsf"},
              r"tracker\.sensors: pda-svsf: the SVSF takes only its own kind of measurement"))
    for over, match in cases:
        with pytest.raises(ConfigError, match=match) as err:
            run_scenario(load_scenario("cut_in_out", {"duration_s": 0.3, **over}), out_dir=tmp_path / "x", record=False)
        assert "\n" not in str(err.value)


def test_measurements_carry_the_frames_pose():
    scn = load_scenario("cut_in_out", {"duration_s": 0.3, "sensor.extra": ["radar"]})
    from roadtrack.testbed.pipeline.run import further_measurements
    from roadtrack.testbed.sensing import SensingContext

    for sf in sense(scn):
        m = further_measurements(sf, SensingContext(scn, None, None))["radar"]
        assert isinstance(m, Measurements) and m.model.pose == tuple(sf.truth.ego_pose)
        assert m.model.velocity == tuple(sf.truth.velocity[0]) and m.z.shape[1] == 3 and m.clutter_density > 0


def test_the_html_replay_and_read_run_carry_the_radars_detections(runs):
    from roadtrack.testbed.export.html import replay_data
    from roadtrack.testbed.pipeline.runfolder import read_run

    run = read_run(runs["fused"].out_dir)
    assert set(run.sensors) == {"radar"} and len(run.sensors["radar"]) > 0
    # sensed with the radar, tracked on the LiDAR alone: the radar's detections are written all the same
    pd.testing.assert_frame_equal(read_run(runs["lidar"].out_dir).sensors["radar"], run.sensors["radar"])
    data = replay_data(run, [])
    assert len(data["sensors"]["x"]) == len(run.sensors["radar"]) and len(data["sensors"]["start"]) == 62
    assert "h" not in data["tracks"]
