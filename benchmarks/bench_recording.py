"""Size and cost of each record level (testbed/recording/levels.py): MB per frame and the recording stage's
ms per frame (the run's ``timings_ms["recording"]``, close included), one thread.

    .venv/bin/python benchmarks/bench_recording.py [--scenario cut_in_out] [--duration 16] [--levels full,default]
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
from roadtrack.testbed.common.threads import one_thread_per_process  # noqa: E402 - before numpy, as `testbed` does

one_thread_per_process()

from roadtrack.testbed.pipeline.run import run_scenario  # noqa: E402
from roadtrack.testbed.scenario.spec import RECORD_LEVELS, load_scenario  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cut_in_out")
    ap.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's)")
    ap.add_argument("--levels", default=",".join(RECORD_LEVELS))
    a = ap.parse_args()
    extra = {} if a.duration is None else {"duration_s": a.duration}
    for level in a.levels.split(","):
        scn = load_scenario(a.scenario, {**extra, "record.level": level})
        with tempfile.TemporaryDirectory() as out:
            res = run_scenario(scn, out_dir=out, record=True)
            size = (Path(out) / "run.rrd").stat().st_size
        print(f"{a.scenario} {scn.duration_s:g} s, {level:<8} {size / 1e6 / res.n_frames:.3f} MB/frame "
              f"({size / 1e6:.1f} MB, {res.n_frames} frames), recording {res.timings_ms['recording']:.1f} ms/frame",
              flush=True)


if __name__ == "__main__":
    main()
