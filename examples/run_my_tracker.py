"""Run your own tracker on a shipped scenario, score it, and compare it with a built-in one on the same traffic.

    python examples/run_my_tracker.py [--out runs/mine] [--duration 5]

Writes the run folder (tables, scores.json; open run.rrd with `testbed view`), then scores the tracks table again
from the folder with the plain-table scorer, as another program's tracks would be (`testbed score RUN --tracks`).
"""
import argparse
import sys
from pathlib import Path

from roadtrack import testbed

sys.path.insert(0, str(Path(__file__).resolve().parent))  # this example's own folder, for nearest_tracker.py
from nearest_tracker import NearestNeighbour  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="runs/mine")
    p.add_argument("--duration", type=float, default=5.0)
    args = p.parse_args()
    scn = testbed.load_scenario("cut_in_out", {"duration_s": args.duration})
    mine = testbed.run(scn, tracker=NearestNeighbour, out=args.out)
    ours = testbed.run(scn, tracker="jpda-kf")
    for name, res in (("NearestNeighbour", mine), ("jpda-kf", ours)):
        s = res.scores
        print(f"{name:>16}: TP {s.tp_pct:6.2f} %  FP {s.fp_pct:5.2f} %  break-up {s.breakup_pct:5.2f} %  "
              f"pos RMSE {s.pos_rmse_m:.3f} m  HOTA {res.metrics['hota']:.3f}")
    run = testbed.read_run(args.out)
    again = testbed.score(run.truth, run.tracks, run.scenario.scoring, run.n_frames)
    assert again.scores.to_dict() == mine.scores.to_dict(), "scoring the folder's tables gives the run's scores"
    print(f"re-scored {args.out}/tracks.parquet: TP {again.scores.tp_pct:.2f} % (same as the run)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
