"""KITTI-tracking export and replay (issue 31.2, 31.3, 31.5): the files read by an independent reader (pykitti 0.3.1
and the format's published description), and the round trip export -> replay reproducing the run."""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.export import export_run
from roadtrack.testbed.pipeline.replay import replay
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.pipeline.runfolder import read_run
from roadtrack.testbed.sensing import kitti as k
from roadtrack.testbed.world import load_scenario

from conftest import cli

pykitti = pytest.importorskip("pykitti")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """cut_in_out, nn-kf, 3 s (31 frames), its KITTI export and the export's replay with the same tracker."""
    base = tmp_path_factory.mktemp("kitti")
    scn = load_scenario("cut_in_out", {"duration_s": 3.0})
    run_scenario(scn, out_dir=base / "run", record=False, tracker="nn-kf", label="nn-kf")
    seq = export_run(base / "run", "kitti", base / "kitti")
    replay(seq, tracker="nn-kf", label="nn-kf", out_dir=base / "replay", record=False)
    return read_run(base / "run"), seq, read_run(base / "replay")


def test_round_trip_reproduces_detections_tracks_and_scores(exported):
    run, _, rep = exported
    a, b = run.detections, rep.detections
    assert len(a) == len(b) > 0
    assert np.array_equal(a["frame"], b["frame"])
    # float32 scans: the detections agree to the points' float32 precision (about 1e-5 m at 70 m)
    for c in ("x", "y", "length", "width", "height"):
        assert np.abs(a[c] - b[c]).max() <= 1e-4, c
    assert np.array_equal(a["n_points"], b["n_points"])
    assert np.array_equal(a["provenance"], b["provenance"])  # from the label boxes, not per-point truth
    ta, tb = run.tracks, rep.tracks
    assert len(ta) == len(tb) and np.array_equal(ta["track_id"], tb["track_id"])
    assert np.array_equal(ta["status"], tb["status"])
    for c in ("x", "y", "vx", "vy"):
        assert np.abs(ta[c] - tb[c]).max() <= 1e-3, c
    sa, sb = run.scores["scores"], rep.scores["scores"]
    for key, va in sa.items():
        if key == "vel_rmse_mps":  # truth velocity: the simulator's live, central differences of labels replayed
            assert abs(va - sb[key]) <= 0.1
        elif isinstance(va, float):
            assert sb[key] == pytest.approx(va, rel=1e-4, abs=1e-6), key
        else:
            assert sb[key] == va, key
    for key, va in run.scores["mot_metrics"].items():
        assert rep.scores["mot_metrics"][key] == pytest.approx(va, rel=1e-4, abs=1e-6), key


def test_pykitti_reads_the_scans_and_poses(exported):
    run, seq, _ = exported
    data = pykitti.tracking(str(seq), k.SEQUENCE)
    assert len(data.velo_files) == run.n_frames
    ego = run.truth[run.truth["is_ego"]].sort_values("frame")
    xy = ego[["x", "y"]].to_numpy()
    scan = data.get_velo(5)
    assert scan.dtype == np.float32 and scan.shape[1] == 4 and len(scan) > 10000
    # velodyne frame: the road lies mount_height_m below the sensor (the lowest returns), nothing beyond range
    h = run.scenario.sensor.lidar.mount_height_m
    assert np.median(scan[:, 2]) == pytest.approx(-h, abs=0.05)
    assert np.linalg.norm(scan[:, :3], axis=1).max() <= run.scenario.sensor.lidar.max_range_m + 1e-3
    oxts = pykitti.utils.load_oxts_packets_and_poses([str(seq / "oxts" / f"{k.SEQUENCE}.txt")])
    assert len(oxts) == run.n_frames
    t = np.array([o.T_w_imu[:2, 3] for o in oxts])  # pykitti: east, north relative to the first pose
    assert np.abs(t - (xy - xy[0])).max() <= 1e-6
    yaw = np.array([math.atan2(o.T_w_imu[1, 0], o.T_w_imu[0, 0]) for o in oxts])
    assert np.abs(k.wrap(yaw - ego["heading"].to_numpy())).max() <= 1e-9
    assert oxts[0].packet.lat == pytest.approx(k.LAT0, abs=1e-3) and oxts[0].packet.navstat == 4


def test_labels_follow_the_published_description(exported):
    """readme of KITTI's object/tracking devkit: frame, track id, type, truncated, occluded, alpha, 2-D box
    (left, top, right, bottom) [px], h, w, l [m], location x, y, z of the bottom centre in camera coordinates
    [m], rotation_y in [-pi, pi]; checked with pykitti's label parser and a parser written here."""
    run, seq, _ = exported
    path = seq / "label_02" / f"{k.SEQUENCE}.txt"
    parser = importlib.import_module("pykitti.tracking").KittiTrackingLabels  # the module; pykitti.tracking is a class
    labels = parser(str(path))  # pykitti's parser: 17 columns, ids made 0-based
    df = labels._df  # noqa: SLF001 - pykitti exposes no public frame
    truth = run.truth[~run.truth["is_ego"]].sort_values(["frame", "vehicle_id"])
    assert len(df) == len(truth)
    assert set(df["class"]) <= {"Car", "Truck"}
    assert df["truncated"].between(0, 1).all() and df["occluded"].isin([0, 1, 2, 3]).all()
    calib = {}
    for line in (seq / "calib" / f"{k.SEQUENCE}.txt").read_text().splitlines():  # "P2: ..." and "R_rect ..."
        key, *vals = line.replace(":", " ", 1).split()
        calib[key] = np.array(vals, float).reshape(3, -1)
    assert set(calib) == {"P0", "P1", "P2", "P3", "R_rect", "Tr_velo_cam", "Tr_imu_velo"}
    ego = run.truth[run.truth["is_ego"]].set_index("frame")
    h = run.scenario.sensor.lidar.mount_height_m
    imu_velo = np.vstack([calib["Tr_imu_velo"], [0, 0, 0, 1]])
    velo_cam = np.vstack([calib["Tr_velo_cam"], [0, 0, 0, 1]])
    rect = np.eye(4)
    rect[:3, :3] = calib["R_rect"]
    rows = [line.split() for line in path.read_text().splitlines()]
    assert all(len(r) == 17 for r in rows)
    for r, (_, tr) in zip(rows, truth.iterrows()):
        f, tid = int(r[0]), int(r[1])
        assert (f, tid) == (tr["frame"], tr["vehicle_id"])
        hh, ww, ll = map(float, r[10:13])
        assert (ll, ww, hh) == pytest.approx((tr["length"], tr["width"], tr["height"]), abs=1e-6)
        # the truth's bottom centre: world -> IMU (on the road below the sensor, x forward) -> velo -> camera
        ex, ey, eyaw = ego.at[f, "x"], ego.at[f, "y"], ego.at[f, "heading"]
        dx, dy = tr["x"] - ex, tr["y"] - ey
        imu = np.array([math.cos(eyaw) * dx + math.sin(eyaw) * dy, -math.sin(eyaw) * dx + math.cos(eyaw) * dy, 0, 1])
        cam = rect @ velo_cam @ imu_velo @ imu
        assert np.array(r[13:16], float) == pytest.approx(cam[:3], abs=1e-5)
        # rotation_y: the car's forward axis in camera coordinates is (cos ry, 0, -sin ry)
        ry = float(r[16])
        fwd = np.array([math.cos(tr["heading"] - eyaw), math.sin(tr["heading"] - eyaw), 0.0])
        assert np.array([math.cos(ry), 0.0, -math.sin(ry)]) == pytest.approx((velo_cam[:3, :3] @ fwd), abs=1e-5)
        if float(r[3]) == 0.0:  # wholly in the image: the 2-D box is the 3-D box's corners through P2
            corners = k.box_corners_cam(cam[:3], np.array([hh, ww, ll]), ry)
            uvw = corners @ calib["P2"][:, :3].T + calib["P2"][:, 3]
            uv = uvw[:, :2] / uvw[:, 2:]
            assert np.array(r[6:10], float) == pytest.approx([*uv.min(axis=0), *uv.max(axis=0)], abs=1e-4)


def test_export_is_fast_and_refuses_what_it_cannot_write(exported, tmp_path):
    run, seq, _ = exported
    assert sorted(p.name for p in (seq / "velodyne" / k.SEQUENCE).iterdir())[-1] == f"{run.n_frames - 1:06d}.bin"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="is a file"):
        export_run(run.folder, "kitti", tmp_path / "file")
    (tmp_path / "link").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(ConfigError, match="symbolic link"):
        export_run(run.folder, "kitti", tmp_path / "link")
    assert not (tmp_path / "elsewhere").exists()
    proc = cli("replay", str(tmp_path), "--no-record")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "no velodyne/" in proc.stderr


def test_geodetic_round_trip():
    xy = np.array([[12.5, 4.0], [-3000.0, 2500.0], [1e5, -2e4]])
    lat, lon, scale = k.geodetic(xy)
    assert scale == pytest.approx(math.cos(math.radians(lat[0])), abs=0)
    assert np.abs(k.world_xy(lat, lon) - xy).max() <= 1e-6
