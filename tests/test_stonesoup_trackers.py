"""Stone Soup's trackers (stonesoup-gnn-kf, stonesoup-jpda-kf) on the testbed's traffic, compared with ours.

cut_in_out (20 s, 3 cars) is sensed once into a sensing cache and every tracker runs on the same detections with
the scenario's jpda-kf settings (sigma_v 4 m/s^2, sigma_w 0.5 m, gate 16, P_D 0.9, clutter 1e-2 /m^2, 5 coasted
scans, position std <= 7.5 m). Differences, by design of Stone Soup: its CV process noise is the continuous
model (4/3 of our position term), a track is confirmed by its second detection (ours by the SPRT score), and
Stone Soup ignores the occlusion-aware P_D. Measured: all four track the 3 cars with no false track; HOTA 0.833
(ours, both) and 0.840 (Stone Soup, both).
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from roadtrack import testbed
from roadtrack.testbed.tracking.stonesoup import RunDetectionReader, components


@pytest.fixture(scope="module")
def runs(tmp_path_factory, cut_in_out_sensing):
    cache = cut_in_out_sensing  # the session's sensing of cut_in_out (conftest)
    scn = testbed.load_scenario("cut_in_out")
    out = {}
    for name in ("jpda-kf", "gnn-kf", "stonesoup-gnn-kf", "stonesoup-jpda-kf"):
        folder = tmp_path_factory.mktemp(name)
        out[name] = (testbed.run(scn, tracker=name, out=folder, record=False, sensing_cache=cache), folder)
    return scn, out


@pytest.mark.parametrize("ours, theirs", [("gnn-kf", "stonesoup-gnn-kf"), ("jpda-kf", "stonesoup-jpda-kf")])
def test_stone_soup_tracks_the_same_traffic_as_ours_at_equal_settings(runs, ours, theirs):
    _, out = runs
    a, b = out[ours][0], out[theirs][0]
    assert a.scores.cars_seen == b.scores.cars_seen == 3
    assert b.scores.cars_tracked == a.scores.cars_tracked == 3 and b.scores.false_tracks == 0
    assert abs(a.metrics["hota"] - b.metrics["hota"]) < 0.1, (a.metrics["hota"], b.metrics["hota"])
    assert b.tracker == theirs
    tracks = pd.read_parquet(out[theirs][1] / "tracks.parquet")
    confirmed = tracks[tracks.status == "confirmed"]
    assert len(confirmed) > 100 and np.isfinite(np.stack(confirmed["cov"].to_numpy())).all()
    assert (tracks.status == "tentative").any()  # the initiator's held tracks, awaiting a second detection


def test_a_stone_soup_script_reads_a_run_folder_with_the_detection_reader(runs):
    scn, out = runs
    folder = out["jpda-kf"][1]
    parts = components(scn, "gnn")
    scans = list(RunDetectionReader(folder, parts["model"]))
    det = pd.read_parquet(folder / "detections.parquet")
    assert len(scans) == scn.n_frames and sum(len(d) for _, d in scans) == len(det) > 0
    first = det[det.frame == det.frame.min()]
    t, dets = scans[int(first.frame.iloc[0])]
    got = sorted(tuple(np.asarray(d.state_vector).ravel()) for d in dets)
    assert np.allclose(got, sorted(map(tuple, first[["x", "y"]].to_numpy())))


def test_without_stone_soup_the_tracker_is_refused_in_one_line_naming_the_extra():
    code = ("import sys; sys.modules['stonesoup'] = None\n"
            "from roadtrack.testbed.cli.main import main\n"
            "sys.exit(main(['run', 'cut_in_out', '--tracker', 'stonesoup-jpda-kf', '--no-record', '--out', "
            "'/nonexistent/x']))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: tracker: the Stone Soup trackers need Stone Soup 1.9.1")
    assert lines[0].endswith("pip install 'roadtrack[stonesoup]'")


def test_a_campaign_compares_stone_soup_with_ours_on_traffic_sensed_once(tmp_path):
    from roadtrack.testbed.campaign import store
    from roadtrack.testbed.campaign.engine import EngineOptions, run_campaign
    from roadtrack.testbed.campaign.spec import load_campaign
    from roadtrack.testbed.sensing.cache import SensingCache

    spec = tmp_path / "ss.toml"
    spec.write_text('name = "ss"\nscenarios = ["cut_in_out"]\ntrackers = ["jpda-kf", "stonesoup-jpda-kf"]\n'
                    'seeds = 1\n\n[overrides]\nduration_s = 4.0\n\n[grid]\n"tracker.filter.sigma_v" = [2.0, 4.0]\n')
    outcome = run_campaign(load_campaign(spec), tmp_path / "out", EngineOptions(workers=1), quiet=True)
    assert not outcome.failed
    res = pd.read_parquet(tmp_path / "out" / store.RESULTS_FILE)
    assert sorted(res.tracker.unique()) == ["jpda-kf", "stonesoup-jpda-kf"] and (res.status == "ok").all()
    assert len(res) == 4 and len(list((tmp_path / "out" / store.SENSING_DIR).glob("*/meta.json"))) == 1
    ss = res[res.tracker == "stonesoup-jpda-kf"].sort_values("tracker.filter.sigma_v")
    assert ss["cars_seen"].tolist() == [3, 3] and (ss["cars_tracked"] >= 2).all()
    assert SensingCache(tmp_path / "out" / store.SENSING_DIR).size_bytes() > 0


def ss_scene(n_tracks: int, spacing: float, std: float, seed: int = 0):
    """Stone Soup tracks in a row along x, `spacing` [m] apart, position std `std` [m], and one detection
    near each (N(0, 0.3^2)): a gate cluster when the spacing is small against std."""
    import datetime

    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track

    from roadtrack.testbed.tracking.stonesoup import EPOCH, detections

    rng = np.random.default_rng(seed)
    scn = testbed.load_scenario("cut_in_out")
    parts = components(scn, "jpda")
    P = np.diag([std ** 2, 1.0, std ** 2, 1.0])
    tracks = {Track([GaussianState(np.array([[k * spacing], [0.0], [0.0], [0.0]]), P, timestamp=EPOCH)])
              for k in range(n_tracks)}
    z = np.c_[np.arange(n_tracks) * spacing, np.zeros(n_tracks)] + 0.3 * rng.standard_normal((n_tracks, 2))
    when = EPOCH + datetime.timedelta(seconds=0.1)
    return parts, tracks, detections(0.1, z, parts["model"]), when


def ss_probabilities(assoc) -> dict:
    """{(track id, detection index or -1): probability} of a Stone Soup association."""
    return {(t.id, h.measurement.metadata["index"] if h else -1): float(h.probability)
            for t, hyps in assoc.items() for h in hyps}


def test_stone_soup_jpda_is_ehm2_with_the_probabilities_of_its_plain_jpda():
    from stonesoup.dataassociator.probability import JPDA

    parts, tracks, dets, when = ss_scene(5, 3.0, 1.0)
    guarded = parts["associator"]
    assert type(guarded).__name__ == "GuardedJPDAwithEHM2"
    ours = ss_probabilities(guarded.associate(tracks, dets, when))
    plain = ss_probabilities(JPDA(guarded.hypothesiser).associate(tracks, dets, when))
    assert guarded.fallbacks == 0 and ours.keys() == plain.keys() and len(ours) > 2 * 5
    assert max(abs(ours[k] - plain[k]) for k in ours) < 1e-9


def test_a_stone_soup_cluster_over_its_budget_falls_back_to_lbp_is_counted_or_raises():
    import time

    from stonesoup.dataassociator.probability import JPDAwithLBP

    from roadtrack.testbed.tracking.stonesoup import SS_MAX_NODES
    from roadtrack.trackers import JPDAOverflowError

    parts, tracks, dets, when = ss_scene(30, 2.0, 4.0)  # 30 tracks, every one gating most detections
    guarded = parts["associator"]
    t0 = time.perf_counter()
    ours = ss_probabilities(guarded.associate(tracks, dets, when))
    assert time.perf_counter() - t0 < 60.0 and guarded.fallbacks == 1 and guarded.max_nodes == SS_MAX_NODES
    lbp = ss_probabilities(JPDAwithLBP(guarded.hypothesiser).associate(tracks, dets, when))
    assert ours.keys() == lbp.keys() and max(abs(ours[k] - lbp[k]) for k in ours) < 1e-12
    guarded.on_overflow = "raise"
    with pytest.raises(JPDAOverflowError, match=r"^Stone Soup JPDA \(EHM2\) cluster of 30 tracks and \d+ detections"):
        guarded.associate(tracks, dets, when)
