"""Track life cycle of finished runs: the thesis's scores, the largest gate any confirmed track reached, and why
cars were missed or relabelled (issue 17's diagnosis, from a run folder's tables alone).

    python benchmarks/bench_track_life.py runs/highway_benchmark [more run folders ...]

Per run folder (written by `testbed run`, tables kept): TP / FP / break-ups in the thesis's form (per car
seen, scores.json), the largest gate area [m^2] of a confirmed track and how many confirmed tracks passed
1000 m^2, then a diagnosis:

* a car seen but never tracked is **barely detected** (its detections, by provenance, in fewer than 5
  frames: beams hit it, perception did not make a vehicle of it), or **well detected, never confirmed**;
* a break-up (a car whose matched confirmed label changes) is an **occlusion or detector miss** when the car
  had no detection for more than half of the frames between the two labels, a **swap** when the new label
  was already another car's, else a **deletion** (the tracker dropped a track while the car was detected).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from testbed.scoring.rates import assign_frames

GATE_BOUND_M2 = 1000.0
WELL_DETECTED_FRAMES = 5


def _tables(run: Path) -> dict:
    return {n: pq.read_table(run / f"{n}.parquet").to_pandas() for n in ("truth", "detections", "tracks",
                                                                          "diagnostics")}


def largest_gate(tracks, diag) -> tuple[float, int]:
    """Largest gate volume [m^2] of a confirmed track and the number of confirmed tracks that passed the bound."""
    gv = diag[diag.name == "gate_volume"][["frame", "track_id", "value"]]
    conf = tracks[tracks.status == "confirmed"][["frame", "track_id"]]
    # the gate of frame k is the prediction of a track reported (confirmed) in frame k - 1
    conf = conf.assign(frame=conf.frame + 1)
    joined = gv.merge(conf, on=["frame", "track_id"])
    if joined.empty:
        return 0.0, 0
    over = joined[joined.value > GATE_BOUND_M2].track_id.nunique()
    return float(joined.value.max()), int(over)


def matched_labels(truth, tracks, match_m: float) -> dict[int, list[tuple[int, int]]]:
    """Car id -> [(frame, confirmed track id)] of the per-frame matches, in frame order."""
    g = truth[~truth.is_ego]
    t = tracks[tracks.status == "confirmed"]
    rt, rg = assign_frames(t.frame.to_numpy(), t[["x", "y"]].to_numpy(), g.frame.to_numpy(),
                           g[["x", "y"]].to_numpy(), match_m)
    out: dict[int, list[tuple[int, int]]] = {}
    for f, v, tid in zip(g.frame.to_numpy()[rg], g.vehicle_id.to_numpy()[rg], t.track_id.to_numpy()[rt]):
        out.setdefault(int(v), []).append((int(f), int(tid)))
    return out


def diagnose(run: Path) -> dict:
    """The scores, the largest gate and the causes of misses and break-ups of one run folder."""
    meta = json.loads((run / "scores.json").read_text())
    tb = _tables(run)
    sc = meta["config"]["scoring"]
    truth, dets = tb["truth"], tb["detections"]
    seen = set(truth[(~truth.is_ego) & (truth.n_points >= sc["visible_min_points"])].vehicle_id.unique().tolist())
    det_frames = dets[dets.provenance >= 0].groupby("provenance").frame.apply(lambda f: set(f.tolist())).to_dict()
    labels = matched_labels(truth, tb["tracks"], sc["match_distance_m"])
    owner: dict[int, int] = {}
    for car, pairs in labels.items():
        for _, tid in pairs:
            owner.setdefault(tid, car)
    missed = sorted(seen - set(labels))
    barely = sum(len(det_frames.get(c, ())) < WELL_DETECTED_FRAMES for c in missed)
    causes = {"occlusion or detector miss": 0, "swap": 0, "deletion": 0}
    for car, pairs in labels.items():
        for (f0, a), (f1, b) in zip(pairs, pairs[1:]):
            if a == b:
                continue
            between = range(f0 + 1, f1)
            undetected = sum(f not in det_frames.get(car, ()) for f in between)
            if len(between) and undetected > len(between) / 2:
                causes["occlusion or detector miss"] += 1
            elif owner.get(b, car) != car:
                causes["swap"] += 1
            else:
                causes["deletion"] += 1
    gate, over = largest_gate(tb["tracks"], tb["diagnostics"])
    s = meta["scores"]
    return dict(run=str(run), tracker=meta["tracker"], seed=meta["seed"], tp_pct=s["tp_pct"], fp_pct=s["fp_pct"],
                breakup_pct=s["breakup_pct"], cars_seen=s["cars_seen"], relabel_events=s["relabel_events"],
                largest_gate_m2=gate, tracks_over_1000_m2=over, missed=len(missed), missed_barely_detected=barely,
                missed_well_detected=len(missed) - barely, **{f"breakup_{k}": v for k, v in causes.items()},
                ms_tracking=meta["timings_ms_per_frame"]["tracking"])


def main(argv: list[str]) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", help="run folders written by `testbed run` (tables kept)")
    rows = [diagnose(Path(a)) for a in p.parse_args(argv).runs]
    keys = list(rows[0])
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
