"""`testbed reproduce thesis-highway --quick`: the thesis's highway tables for 4 trackers, 2 seeds, both pipelines."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.reproduce import REPRODUCTIONS, entry
from roadtrack.testbed.reproduce.thesis import highway


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("thesis-highway")
    path = entry("thesis-highway")(out, quick=True, seed=0, progress=False)
    return out, path.read_text(), pd.read_csv(out / "results.csv")


def test_quick_form_writes_verdicts_tables_and_figures(quick):
    out, text, df = quick
    assert "thesis-highway" in REPRODUCTIONS
    for table, tracker, than, _ in highway.CLAIMS:
        assert f"**{table}: {tracker} beats {than}: " in text
    for pipeline in highway.PIPELINES:
        for cars in ("seen", "trackable"):
            assert f"## {pipeline} pipeline, {cars} cars" in text
    assert "| thesis Table 4.3: JPDA-GVBL-SVSF | – | 58 | 53 | 5 | – | 91.38 | 8.62 | 2.00 |" in text
    assert (out / "paired_seen.png").stat().st_size > 10_000 and (out / "paired_trackable.png").stat().st_size > 10_000
    # every (pipeline, seed, tracker) for both denominators, the same cars for every tracker of a seed
    assert len(df) == len(highway.PIPELINES) * 2 * len(highway.QUICK_TRACKERS) * 2
    per = df.groupby(["pipeline", "seed", "cars"])["cars_seen"].nunique()
    assert (per == 1).all()
    seen = df[df.cars == "seen"].set_index(["pipeline", "seed", "tracker"])["cars_seen"]
    trackable = df[df.cars == "trackable"].set_index(["pipeline", "seed", "tracker"])["cars_seen"]
    assert (trackable <= seen).all() and (trackable > 0).all()


def test_pooled_row_is_the_sum_over_the_seeds(quick):
    _, text, df = quick
    sub = df[(df.pipeline == "full") & (df.cars == "seen") & (df.tracker == "jpda-kf")]
    seen, tracked = int(sub.cars_seen.sum()), int(sub.cars_tracked.sum())
    row = next(line for line in text.splitlines() if line.startswith("| jpda-kf (ours) |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert int(cells[2]) == seen and int(cells[3]) == tracked
    assert float(cells[6]) == pytest.approx(100.0 * tracked / seen, abs=0.006)


def test_trackable_cars_need_ten_points_in_five_frames():
    frames = np.arange(12)
    rows = [(f, 1, 30) for f in frames[:5]]  # car 1: 30 points in 5 frames -> trackable
    rows += [(f, 2, 9) for f in frames]  # car 2: 9 points in 12 frames -> never
    rows += [(f, 3, 50) for f in frames[:4]] + [(4, 3, 2)]  # car 3: 4 frames of 50 -> not trackable
    t = pd.DataFrame(rows, columns=["frame", "vehicle_id", "n_points"])
    out = highway.trackable_truth(t)
    assert out.loc[out.vehicle_id == 1, "n_points"].tolist() == [30] * 5
    assert (out.loc[out.vehicle_id.isin([2, 3]), "n_points"] == 0).all()
    assert t.loc[t.vehicle_id == 2, "n_points"].tolist() == [9] * 12  # the input is not changed


def test_paired_difference_interval_and_verdict_by_hand():
    rows = []
    for seed, (a, b) in enumerate([(90.0, 85.0), (92.0, 86.0), (91.0, 85.5)]):
        for name, tp in (("x", a), ("jpda-kf", b)):
            rows.append(dict(pipeline="full", cars="seen", seed=seed, tracker=name, tp_pct=tp, fp_pct=5.0,
                             breakup_pct=1.0))
    df = pd.DataFrame(rows)
    n, mean, lo, hi = highway.paired(df, "full", "seen", "x", "jpda-kf", "tp_pct")
    d = np.array([5.0, 6.0, 5.5])
    half = 4.302652729911275 * d.std(ddof=1) / np.sqrt(3)  # t_{0.975, 2}
    assert n == 3 and mean == pytest.approx(5.5) and lo == pytest.approx(5.5 - half) and hi == pytest.approx(5.5 + half)
    result, _ = highway.compare(df, "full", "seen", "x", "jpda-kf")
    assert result == {"tp_pct": "better", "fp_pct": "no difference shown", "breakup_pct": "no difference shown"}
    assert highway.supports(result)


def test_finished_tasks_are_kept_and_not_run_again(quick):
    out, _, df = quick
    partial = out / "results-partial.csv"
    s = highway.settings(True, 0)
    assert len(highway.done_rows(partial, s)) == len(df)  # a rerun into the folder starts no task
    assert highway.done_rows(partial, highway.settings(True, 1)) == [] or all(
        r["seed"] == 1 for r in highway.done_rows(partial, highway.settings(True, 1)))  # seeds 1, 2: only seed 1 kept
    longer = highway.Settings(s.trackers, s.seeds, 20.0)
    assert highway.done_rows(partial, longer) == []  # another duration: everything runs again


def _claims_df(tp_gain: list[float]) -> pd.DataFrame:
    """jpda-gvbl-svsf and jpda-kf on len(tp_gain) seeds, both pipelines and denominators: TP % differs by
    tp_gain[seed], FP and break-ups equal."""
    rows = []
    for pipeline in highway.PIPELINES:
        for cars in ("seen", "trackable"):
            for seed, gain in enumerate(tp_gain):
                for name, tp in (("jpda-gvbl-svsf", 85.0 + gain), ("jpda-kf", 85.0)):
                    rows.append(dict(pipeline=pipeline, cars=cars, seed=seed, tracker=name, tp_pct=tp, fp_pct=5.0,
                                     breakup_pct=1.0, cars_seen=50, cars_tracked=40, false_tracks=3,
                                     cars_relabelled=1))
    return pd.DataFrame(rows)


def test_quick_verdicts_are_indicative_unless_the_paired_intervals_carry_them():
    """Two seeds whose TP differences straddle 0: the quick summary says "indicative (2 seeds): not a verdict",
    the full one "does not hold"; a TP shown worse on every variant is stated in the quick run with its n."""
    s = highway.Settings(("jpda-kf", "jpda-gvbl-svsf"), (0, 1), 15.0)
    mixed = _claims_df([+2.0, -1.0])
    quick = highway.summary_text(mixed, s, quick=True)
    assert "**Table 4.3: jpda-gvbl-svsf beats jpda-kf: indicative (2 seeds): not a verdict.**" in quick
    assert "**Table 4.3: jpda-gvbl-svsf beats jpda-kf: does not hold (no variant shows a better TP %).**" in \
        highway.summary_text(mixed, s, quick=False)
    worse = highway.summary_text(_claims_df([-2.0, -2.1, -1.9]), highway.Settings(s.trackers, (0, 1, 2), 15.0), True)
    assert "beats jpda-kf: does not hold (worse on TP % (full pipeline, seen cars)" in worse
    assert "(quick run, n = 3 seeds).**" in worse and "paired t 95 % CI" in worse
