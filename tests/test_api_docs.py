"""docs/api.md cannot rot: its Python code blocks run, in order, as one script in an empty folder, as a user
would paste them; then the plug-in filter and associator the page defines are checked: the filter combines with
every associator by name, with alpha = 1 it tracks as the built-in Kalman filter, and the page's PDA associator
gives the built-in PDA's tracks."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "api.md"

CHECKS = '''
import dataclasses, json
import numpy as np
from roadtrack import trackers

out = {"associators": sorted(trackers.ASSOCIATORS), "fading": {}}
for assoc in out["associators"]:  # every associator with the page's filter, by name
    ev = testbed.score_frames(testbed.track(frames, f"{assoc}-fading-kf", scn), scn)
    out["fading"][assoc] = [ev.scores.cars_seen, ev.scores.cars_tracked, ev.scores.confirmed_tracks]

def tracks(scenario, name=None):
    return [(sf.index, ts.ids.tolist(), ts.xy.copy(), ts.status.tolist())
            for sf, ts in testbed.track(frames, name, scenario)]

def max_gap(a, b):  # largest position difference of two runs with the same labels, or inf
    if [r[:2] + r[3:] for r in a] != [r[:2] + r[3:] for r in b]:
        return float("inf")
    return max((float(np.abs(x[2] - y[2]).max()) for x, y in zip(a, b) if len(x[2])), default=0.0)

def without_road_hooks(name, **filter_keys):  # the page's filter has no shift_many / pseudo_update_many
    mgmt = {**scn.tracker.management, "road_curvature": False, "road_lane_keeping": False}
    return dataclasses.replace(scn, tracker=dataclasses.replace(scn.tracker, name=name, management=mgmt,
                                                                filter={**scn.tracker.filter, **filter_keys}))

out["alpha1_vs_kf"] = max_gap(tracks(without_road_hooks("jpda-fading-kf", alpha=1.0)),
                              tracks(without_road_hooks("jpda-kf")))
out["alpha2_vs_kf"] = max_gap(tracks(without_road_hooks("jpda-fading-kf", alpha=1.5)),
                              tracks(without_road_hooks("jpda-kf")))
out["mypda_vs_pda"] = max_gap(tracks(scn, "my-pda-kf"), tracks(scn, "pda-kf"))
out["mypda_svsf"] = testbed.score_frames(testbed.track(frames, "my-pda-svsf", scn), scn).scores.cars_tracked
print("CHECKS " + json.dumps(out))
'''


def python_blocks(text: str) -> list[str]:
    """The ```python fenced blocks of a Markdown text, in order."""
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_page_has_the_plugin_examples():
    blocks = python_blocks(DOC.read_text(encoding="utf-8"))
    assert len(blocks) >= 6
    joined = "\n".join(blocks)
    for needle in ("register_filter(\"fading-kf\"", "register_associator(\"my-pda\"", "light=True",
                   "sensing_cache=", "score_frames("):
        assert needle in joined, needle


def test_the_docs_code_blocks_run_and_the_plugins_combine(tmp_path):
    script = "\n\n".join(python_blocks(DOC.read_text(encoding="utf-8"))) + "\n" + CHECKS
    (tmp_path / "doc_blocks.py").write_text(script, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(REPO), "RERUN_ANALYTICS": "0"}
    proc = subprocess.run([sys.executable, "doc_blocks.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("CHECKS "))
    got = json.loads(line[len("CHECKS "):])
    assert {"nn", "gnn", "pda", "jpda", "an", "apda"} <= set(got["associators"])
    for assoc, (seen, tracked, confirmed) in got["fading"].items():  # 5 s of cut_in_out: the 3 cars
        assert seen == 3 and tracked == 3 and confirmed >= 3, (assoc, seen, tracked, confirmed)
    assert got["alpha1_vs_kf"] <= 1e-9  # the same labels, status and positions to 1 nanometre
    assert got["alpha2_vs_kf"] > 1e-3  # and alpha does fade the memory
    assert got["mypda_vs_pda"] <= 1e-9
    assert got["mypda_svsf"] == 3
    assert "jpda-fading-kf" in proc.stdout and "my-pda-kf" in proc.stdout
    assert (tmp_path / "cache").is_dir() and (tmp_path / "runs" / "cut_in_out" / "tracks.parquet").is_file()
