"""`testbed export RUN --format mot` (issue 31.2, 31.5): a MOTChallenge sequence that TrackEval's own reader loads,
and from which TrackEval's own evaluation gives the testbed's HOTA / CLEAR / Identity numbers."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.export.mot import FOOTPRINT_M, safe_name, track_rows, trackeval_dataset

from conftest import cli


def _evaluate(folder, similarity: str, scale_m: float) -> dict:
    """TrackEval's Evaluator on the export (every tracker, the combined sequence, class 'pedestrian')."""
    import trackeval

    ev = trackeval.Evaluator({"USE_PARALLEL": False, "PRINT_RESULTS": False, "PRINT_CONFIG": False,
                              "TIME_PROGRESS": False, "OUTPUT_SUMMARY": False, "OUTPUT_DETAILED": False,
                              "PLOT_CURVES": False, "DISPLAY_LESS_PROGRESS": True})
    cfg = {"THRESHOLD": 0.5, "PRINT_CONFIG": False}
    res, msg = ev.evaluate([trackeval_dataset(folder, similarity, scale_m)],
                           [trackeval.metrics.HOTA(), trackeval.metrics.CLEAR(cfg), trackeval.metrics.Identity(cfg)])
    (per_tracker,) = res.values()
    (tracker,) = per_tracker.values()
    r = tracker["COMBINED_SEQ"]["pedestrian"]
    return dict(hota=np.mean(r["HOTA"]["HOTA"]), deta=np.mean(r["HOTA"]["DetA"]), assa=np.mean(r["HOTA"]["AssA"]),
                loca=np.mean(r["HOTA"]["LocA"]), mota=r["CLEAR"]["MOTA"], motp=r["CLEAR"]["MOTP"],
                idf1=r["Identity"]["IDF1"], id_switches=r["CLEAR"]["IDSW"], gt=r["CLEAR"]["CLR_TP"] + r["CLEAR"]["CLR_FN"])


@pytest.fixture(scope="module")
def exported(short_run, tmp_path_factory):
    out, _ = short_run
    mot = tmp_path_factory.mktemp("mot") / "mot"
    proc = cli("export", str(out), "--format", "mot", "--out", str(mot), timeout=120)
    assert proc.returncode == 0, proc.stderr
    return out, mot


def test_mot_export_has_the_layout_and_trackevals_reader_loads_the_runs_rows(exported):
    out, mot = exported
    seq = "cut_in_out-s7"
    assert (mot / "gt" / "seqmaps" / "ROADTRACK-all.txt").read_text() == f"name\n{seq}\n"
    for rel in ("seqinfo.ini", "gt/gt.txt", "det/det.txt"):
        assert (mot / "gt" / seq / rel).is_file()
    truth = pd.read_parquet(out / "truth.parquet")
    tracks = pd.read_parquet(out / "tracks.parquet")
    det = pd.read_parquet(out / "detections.parquet")
    n = int(truth["frame"].max()) + 1
    ds = trackeval_dataset(mot)  # TrackEval's MotChallenge2DBox, its own file reader
    assert ds.seq_list == [seq] and ds.seq_lengths == {seq: n} and ds.tracker_list == ["nn-kf"]
    raw = ds.get_raw_seq_data("nn-kf", seq)
    cars = truth[~truth["is_ego"]]
    conf = tracks[tracks["status"] == "confirmed"]
    for f in (0, 40, n - 1):  # frame f of the run is timestep f of TrackEval, frame f + 1 in the files
        want = cars[cars["frame"] == f].sort_values("vehicle_id")
        np.testing.assert_array_equal(raw["gt_ids"][f], want["vehicle_id"])
        centre = raw["gt_dets"][f][:, :2] + raw["gt_dets"][f][:, 2:] / 2
        np.testing.assert_allclose(centre, want[["x", "y"]], atol=1e-6)
        np.testing.assert_array_equal(raw["gt_dets"][f][:, 2:], np.tile(FOOTPRINT_M, (len(want), 1)))
        vis = want["n_points"].to_numpy() >= 1
        np.testing.assert_array_equal(raw["gt_classes"][f], np.where(vis, 1, 8))
        np.testing.assert_array_equal(raw["gt_extras"][f]["zero_marked"], vis.astype(int))
        wt = conf[conf["frame"] == f].sort_values("track_id")
        np.testing.assert_array_equal(raw["tracker_ids"][f], wt["track_id"])
        np.testing.assert_allclose(raw["tracker_dets"][f][:, :2] + raw["tracker_dets"][f][:, 2:] / 2,
                                   wt[["x", "y"]], atol=1e-6)
    assert sum(len(i) for i in raw["tracker_ids"]) == len(conf) and sum(len(i) for i in raw["gt_ids"]) == len(cars)
    d = np.loadtxt(mot / "gt" / seq / "det" / "det.txt", delimiter=",")
    assert d.shape == (len(det), 10) and d[:, 0].min() == 1 and (d[:, 1] == -1).all()
    np.testing.assert_allclose(d[:, 7:9], det[["x", "y"]], atol=1e-6)
    np.testing.assert_allclose(d[:, 2:4] + d[:, 4:6] / 2, det[["x", "y"]], atol=1e-6)


def test_trackeval_from_the_files_gives_the_runs_own_mot_metrics(exported):
    out, mot = exported
    ours = json.loads((out / "scores.json").read_text())["mot_metrics"]
    got = _evaluate(mot, "distance", 3.0)  # the scenario's similarity_scale_m: the match distance, 3 m
    for key in ("hota", "deta", "assa", "loca", "mota", "motp", "idf1", "id_switches"):
        assert got[key] == pytest.approx(ours[key], abs=1e-6), key
    assert ours["id_switches"] == 0 and ours["mota"] > 0.5  # the fixture's run (conftest): a tracked scene
    iou = _evaluate(mot, "iou", 3.0)  # the MOTChallenge benchmark's box overlap: other matches, the same truth
    assert iou["gt"] == got["gt"] == int((pd.read_parquet(out / "truth.parquet").query("~is_ego").n_points >= 1).sum())
    assert 0.5 < iou["mota"] <= 1 and iou["motp"] < got["motp"]


def test_mot_names_and_ids():
    assert safe_name("examples/nearest_tracker.py:NearestNeighbour") == "examples_nearest_tracker.py_NearestNeighbour"
    rows = pd.DataFrame(dict(frame=[0, 0], track_id=[3, -1], status=["confirmed"] * 2, x=[1.0, 2.0], y=[0.0, 0.0]))
    with pytest.raises(ConfigError, match="id -1 is negative"):
        track_rows(rows)
    assert track_rows(rows.iloc[:1]) == "1,3,-1.500000,-1.000000,5.000000,2.000000,1,-1,-1,-1\n"
