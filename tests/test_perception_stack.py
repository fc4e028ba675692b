"""The perception stack in the loop: static roadside objects do not become reported tracks, and the
`testbed perception` characterisation report (real highway-env, LiDAR, perception, tracker)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from roadtrack.testbed.perception.characterise import characterise, merge_curve
from roadtrack.testbed.cli.main import main
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.sensing import rng_streams
from roadtrack.testbed.scenario.spec import load_scenario
from roadtrack.testbed.world.simulation import Simulation, roadside_objects

# A straight 3-lane road lined with bushes, trees and signs; the sensor car and two cars drive past them.
ROADSIDE = {"duration_s": 8.0, "seed": 3, "roadside.bushes_per_km": 60.0, "roadside.trees_per_km": 40.0,
            "roadside.signs_per_km": 20.0, "roadside.barrier_offset_m": 2.0}


def _static_boxes(scn):
    return roadside_objects(Simulation(scn).network, scn.roadside, rng_streams(scn.seed)["roadside"])


def _reported_near_static(res, static: np.ndarray, radius: float = 3.0) -> int:
    """Reported (status confirmed) track-frames within ``radius`` of a roadside object's centre."""
    t = res.tables["tracks"]
    conf = t.array("status") == "confirmed"
    xy = np.column_stack([t.array("x"), t.array("y")])[conf]
    if not len(xy) or not len(static):
        return 0
    d = np.hypot(xy[:, None, 0] - static[None, :, 0], xy[:, None, 1] - static[None, :, 1])
    return int(np.count_nonzero(d.min(axis=1) <= radius))


@pytest.fixture(scope="module")
def roadside_scenario():
    return load_scenario("cut_in_out", ROADSIDE)


@pytest.fixture(scope="module")
def no_roi_sensing(tmp_path_factory):
    """A sensing cache for ROADSIDE without the map ROI: the moving-object test is not a sensing key
    (testbed.sensing.cache), so the runs with and without it below are sensed once, whichever comes first (a run
    from the cache is identical to one from scratch: tests/test_sensing_cache.py)."""
    return tmp_path_factory.mktemp("no-roi-sensing")


def test_no_bush_becomes_a_confirmed_track_with_the_map_roi(roadside_scenario, no_roi_sensing):
    static = _static_boxes(roadside_scenario)
    assert len(static) > 20
    roi_only = run_scenario(load_scenario("cut_in_out", {**ROADSIDE, "moving_test.enabled": False}), record=False)
    assert _reported_near_static(roi_only, static) == 0
    assert roi_only.scores.false_tracks == 0 and roi_only.scores.cars_tracked == roi_only.scores.cars_seen
    # the same run without the ROI does confirm tracks on roadside objects: the check above can fail
    plain = run_scenario(load_scenario("cut_in_out", {**ROADSIDE, "moving_test.enabled": False,
                                                      "sensor.perception.roi": False}), record=False,
                         sensing_cache=no_roi_sensing)
    assert _reported_near_static(plain, static) > 0 and plain.scores.false_tracks > 0


def test_the_moving_object_test_alone_keeps_static_objects_out_of_the_report(roadside_scenario, no_roi_sensing):
    static = _static_boxes(roadside_scenario)
    res = run_scenario(load_scenario("cut_in_out", {**ROADSIDE, "sensor.perception.roi": False}), record=False,
                       sensing_cache=no_roi_sensing)
    assert _reported_near_static(res, static) == 0
    status = res.tables["tracks"].array("status")
    assert (status == "static").any()  # tracked, withheld
    assert res.scores.false_tracks == 0


def test_characterisation_measures_what_the_trackers_get(roadside_scenario):
    ch = characterise(load_scenario("cut_in_out", {**ROADSIDE, "duration_s": 3.0}), merge_sweep=False)
    s = ch.summary()
    assert s["ground_precision"] >= 0.99 and s["ground_recall"] >= 0.99
    assert s["pd_visible"] >= 0.95
    assert s["centre_rmse_box_m"] < s["centre_rmse_centroid_m"]
    assert 0.3 < s["r_nees_mean"] < 6.0
    assert s["clutter_per_frame"] == 0.0  # the ROI keeps the roadside objects out
    # clutter appears without the ROI: the count measures something
    off = characterise(load_scenario("cut_in_out", {**ROADSIDE, "duration_s": 3.0, "sensor.perception.roi": False}),
                       merge_sweep=False)
    assert off.summary()["clutter_per_frame"] > 0.0


def test_merge_curve_two_cars_far_apart_never_merge():
    curve = merge_curve(load_scenario("cut_in_out"), gaps=(1.0, 5.0, 20.0))
    assert set(curve) == {1.0, 5.0, 20.0}
    assert curve[5.0] == 0.0 and curve[20.0] == 0.0
    assert 0.0 <= curve[1.0] <= 1.0


def test_perception_cli_writes_report_plots_and_loadable_settings(tmp_path, capsys):
    out = tmp_path / "report"
    settings = tmp_path / "measured.toml"
    rc = main(["perception", "cut_in_out", "--duration", "2", "--out", str(out), "--quiet", "--no-merge-sweep",
               "--write-settings", str(settings)])
    assert rc == 0, capsys.readouterr().err
    for name in ("report.md", "summary.json", "pd.png", "centre_error.png", "merge_clutter.png"):
        assert (out / name).is_file(), name
    doc = json.loads((out / "summary.json").read_text())
    assert set(doc["ablation"]) == {"full", "no map ROI", "no moving-object test", "neither", "thesis pipeline"}
    md = (out / "report.md").read_text()
    assert "ground precision / recall" in md and "False confirmed tracks removed" in md
    scn = load_scenario(settings)
    assert scn.tracker.associator["pd"] == doc["settings"]["tracker.associator.pd"]
    assert scn.tracker.filter["sigma_w"] == doc["settings"]["tracker.filter.sigma_w"]
    assert scn.vehicles == load_scenario("cut_in_out").vehicles  # the rest of the scenario is kept ...
    assert scn.duration_s == load_scenario("cut_in_out").duration_s  # ... without the report's --duration


def test_perception_cli_bad_input_is_one_line(tmp_path, capsys):
    assert main(["perception", "no_such_scenario", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    assert main(["perception", "cut_in_out", "--quiet", "--write-settings", str(tmp_path / "nope" / "x.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err
