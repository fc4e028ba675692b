"""A run must not die because traffic is dense (issue 30): highway_benchmark at 100 vehicles per km and lane,
3 s. The exact JPDA's budget is lowered (max_nodes = 64 edges per net layer) so that this short run meets
over-budget clusters as the full-size budget meets them in longer dense runs (tests/test_association_overflow.py
builds those at the real budget): the run completes, each fallback cluster is counted once (scores.json
``association_fallbacks``, RunResult.fallbacks) and flagged per track in diagnostics.parquet; with
``on_overflow = "raise"`` the same run stops with JPDAOverflowError."""
import json

import pandas as pd
import pytest

from roadtrack import testbed
from roadtrack.trackers import JPDAOverflowError

DENSE = {"traffic.density_per_km_lane": 100.0, "duration_s": 3.0, "tracker.associator.max_nodes": 64}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("dense-sensing")


def test_a_dense_motorway_runs_to_the_end_and_counts_its_fallbacks(cache, tmp_path):
    scn = testbed.load_scenario("highway_benchmark", DENSE)
    res = testbed.run(scn, tracker="jpda-kf", out=tmp_path, record=False, sensing_cache=cache)
    assert res.n_frames == scn.n_frames == 31
    doc = json.loads((tmp_path / "scores.json").read_text())
    assert doc["association_fallbacks"] == res.fallbacks > 0
    diag = pd.read_parquet(tmp_path / "diagnostics.parquet")
    flagged = diag[diag.name == "jpda_fallback"]
    assert (flagged.value == 1.0).all()
    # every fallback cluster holds at least two flagged tracks; every frame with a flag has a cluster
    assert flagged.frame.nunique() <= res.fallbacks <= len(flagged) // 2
    assert res.scores.cars_tracked > 0


def test_on_overflow_raise_stops_the_dense_run(cache):
    scn = testbed.load_scenario("highway_benchmark", {**DENSE, "tracker.associator.on_overflow": "raise"})
    with pytest.raises(JPDAOverflowError, match=r"^JPDA \(ehm\) cluster of .* max_nodes=64"):
        testbed.run(scn, tracker="jpda-kf", record=False, sensing_cache=cache)
