"""examples/nn_tracker.awk (issue 31.4): a tracker in another language reads `testbed export --format csv` and its
tracks are scored by `testbed score RUN --tracks FILE`."""
from __future__ import annotations

import json
import shutil
import subprocess

import pandas as pd
import pytest

from conftest import REPO, cli

AWK = shutil.which("awk")


@pytest.mark.skipif(AWK is None, reason="no awk on this machine (every CI image has one)")
def test_the_awk_tracker_tracks_the_exported_detections_and_testbed_score_scores_it(short_run, short_run_csv, tmp_path):
    out, _ = short_run
    csv, proc = short_run_csv  # `testbed export RUN --format csv`, run once for the session (conftest)
    assert proc.returncode == 0, proc.stderr
    tracks = tmp_path / "awk_tracks.csv"
    with open(tracks, "w") as fh:
        subprocess.run([AWK, "-f", str(REPO / "examples" / "nn_tracker.awk"), str(csv / "detections.csv")],
                       stdout=fh, check=True, timeout=60)
    t = pd.read_csv(tracks)
    assert list(t.columns) == ["frame", "time", "track_id", "status", "x", "y", "vx", "vy"]
    assert (t["status"] == "confirmed").sum() > 100
    table = cli("score", str(out), "--tracks", str(tracks), timeout=120)
    assert table.returncode == 0, table.stderr
    (line,) = [ln for ln in table.stdout.splitlines() if ln.startswith("awk_tracks.csv")]
    assert line.split()[1:3] == ["3", "3"]  # cars seen, cars correctly tracked
    res = json.loads(cli("score", str(out), "--tracks", str(tracks), "--json", timeout=120).stdout)
    s, m = res["scores"], res["mot_metrics"]
    # the fixture's run (conftest, cut_in_out 8 s): every car tracked, no false track, MOTA 0.921 on visible truth
    assert s["cars_tracked"] == 3 and s["false_tracks"] == 0 and s["tp_pct"] == 100.0
    assert m["mota"] == pytest.approx(0.921, abs=0.01) and m["hota"] > 0.8
