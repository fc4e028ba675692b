"""Record levels (testbed/recording/levels.py): the default recording of a short run stays under 0.1 MB per
frame, and each level's recording, read back with rerun's own reader, holds what the level promises."""
from __future__ import annotations

import collections
import json
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from roadtrack.testbed.cli.main import main
from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.recording.levels import OBJECT_POINTS, OTHER_EVERY, content, lidar_step, thinned
from roadtrack.testbed.recording.scene import TRAIL_EVERY_S
from roadtrack.testbed.scenario.spec import RECORD_LEVELS, load_scenario

DURATION = 3.0
MB_PER_FRAME = 0.1  # the issue-20 target for the default level


def _read(rrd: Path) -> tuple[dict[str, int], dict[str, list]]:
    """Rows per entity; per frame, the object points' (truth vehicle ids, detection indices) and the number of
    ground points."""
    rows: collections.Counter = collections.Counter()
    points: dict[str, list] = collections.defaultdict(list)
    for chunk in RrdReader(str(rrd)).stream():
        rows[chunk.entity_path] += chunk.num_rows
        rb = chunk.to_record_batch()
        if chunk.entity_path == "/world/lidar/objects":
            points["objects"] += [(np.array(v), np.array(d)) for v, d in
                                  zip(rb.column("vehicle_id").to_pylist(), rb.column("detection").to_pylist())]
        if chunk.entity_path == "/world/lidar/ground":
            points["ground"] += [len(v) for v in rb.column("Points3D:positions").to_pylist()]
    return dict(rows), points


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    out = {}
    for level in RECORD_LEVELS:
        folder = tmp_path_factory.mktemp(level)
        scn = load_scenario("cut_in_out", {"duration_s": DURATION, "record.level": level})
        res = run_scenario(scn, out_dir=folder, record=True)
        out[level] = (folder / "run.rrd", res)
    return out


def test_the_default_recording_is_at_most_a_tenth_of_a_megabyte_per_frame(recordings):
    rrd, res = recordings["default"]
    per_frame = rrd.stat().st_size / 1e6 / res.n_frames
    assert per_frame <= MB_PER_FRAME, per_frame
    full, _ = recordings["full"]
    assert rrd.stat().st_size < 0.5 * full.stat().st_size  # the thinning is what makes it small


def test_each_level_holds_what_it_promises(recordings):
    n = recordings["full"][1].n_frames
    always = ["/world/truth/vehicles", "/world/truth/ego", "/world/ego", "/world/tracks/confirmed",
              "/world/tracks/velocity", "/metrics/tracks_confirmed"]
    trail_every = round(TRAIL_EVERY_S * 10.0)  # trails: a dot every 0.5 s at 10 Hz (issue 34.4)
    lidar = ["/world/lidar/ground", "/world/lidar/objects", "/world/lidar/ground_errors"]
    truth_copy = ["/world/lidar/truth", "/world/lidar/shadows"]
    dets = ["/world/detections", "/world/detections/boxes", "/world/detections/rejected"]
    extras = ["/world/tracks/covariance", "/world/tracks/gates"]
    want = dict(full=always + lidar + truth_copy + dets + extras, default=always + lidar + dets + extras,
                light=always + dets + extras, tracks=always)
    every = set(always + lidar + truth_copy + dets + extras)
    for level, (rrd, _) in recordings.items():
        rows, _ = _read(rrd)
        for path in want[level]:
            expected = n + 1 if path.startswith("/metrics") else n  # + the static series style
            assert rows.get(path) == expected, (level, path, rows.get(path))
        assert rows.get("/world/tracks/trajectories") == -(-n // trail_every), (level, rows.get("/world/tracks/trajectories"))
        for path in every - set(want[level]):
            assert path not in rows, (level, path)
        assert rows["/world/road/lanes"] == 1 and rows["/world/roadside"] == 1  # static, once
        diag = any(p.startswith("/diagnostics/") for p in rows)
        assert diag == content(level).diagnostics, level


def test_the_default_level_keeps_far_objects_whole_and_thins_the_rest(recordings):
    _, full = _read(recordings["full"][0])
    _, thin = _read(recordings["default"][0])
    assert len(full["objects"]) == len(thin["objects"]) > 20
    def objects(ids, det):  # one key per detection, else per vehicle; None for the other points
        return collections.Counter(("d", d) if d >= 0 else ("v", v) if v >= 0 else None
                                   for v, d in zip(ids.tolist(), det.tolist()))

    for (f_ids, f_det), (t_ids, t_det) in zip(full["objects"], thin["objects"]):
        f, t = objects(f_ids, f_det), objects(t_ids, t_det)
        for key in (k for k in f if k is not None):  # all up to OBJECT_POINTS, about that many beyond
            assert t[key] == f[key] if f[key] <= OBJECT_POINTS else OBJECT_POINTS / 2 <= t[key] <= OBJECT_POINTS
        assert t[None] == -(-f[None] // OTHER_EVERY)  # the other points: every 8th
    for f_n, t_n in zip(full["ground"], thin["ground"]):
        assert t_n == -(-f_n // 16)  # every 16th ground point (record.ground_decimation)


def test_thinned_keeps_clusters_up_to_the_cap_and_every_nth_other_point():
    is_ground = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0], bool)
    labels = np.array([-1, -1, -1, 0, 0, 0, 0, -1, -1, -1, -1, 1])
    source = np.array([-2, -2, -2, 3, 3, 3, 3, 5, 5, -1, -1, -1])
    ground, objects = thinned(is_ground, labels, source, ground_every=2, other_every=2, per_object=2)
    np.testing.assert_array_equal(ground, [0, 2])
    # cluster 0 (4 points, cap 2): every 2nd; vehicle 5 (2 points): both; others 9, 10: every 2nd; cluster 1: all
    np.testing.assert_array_equal(objects, [3, 5, 7, 8, 9, 11])


def test_an_unknown_level_is_one_line_naming_the_levels():
    with pytest.raises(ConfigError, match="record.level.*full, default, light, tracks"):
        load_scenario("cut_in_out", {"record.level": "most"})
    with pytest.raises(ValueError, match="unknown record level 'most'; allowed: full, default, light, tracks"):
        content("most")


def test_a_long_run_logs_the_point_cloud_on_at_most_max_lidar_frames_frames(tmp_path, capsys):
    assert [lidar_step(1, 1200, n) for n in (1, 1200, 1201, 4275)] == [1, 1, 2, 4]
    assert lidar_step(5, 1200, 4275) == 5 and lidar_step(0, 10, 99) == 0 and lidar_step(1, 0, 10**6) == 1
    assert main(["run", "cut_in_out", "--set", f"duration_s={DURATION}", "--set", "record.max_lidar_frames=10",
                 "--out", str(tmp_path), "--quiet", "--no-plot"]) == 0
    n = json.loads((tmp_path / "scores.json").read_text())["frames"]
    step = -(-n // 10)
    assert f"run.rrd holds the point cloud of every {step}th frame: a {n}-frame run, " \
           "record.max_lidar_frames = 10" in capsys.readouterr().out
    rows, _ = _read(tmp_path / "run.rrd")
    assert step > 1
    assert rows["/world/lidar/ground"] == rows["/world/lidar/objects"] == -(-n // step) <= 10
    assert rows["/world/truth/vehicles"] == n  # the rest on every frame
