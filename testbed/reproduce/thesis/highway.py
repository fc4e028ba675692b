"""The thesis's highway tables (Attari, Tables 4.3 and 5.4) on our motorway benchmark, for every named tracker.

    run(out_dir, *, quick=False, seed=0, progress=True) -> Path   writes summary.md, results.csv and PNG figures

The thesis scores its trackers on real HDL-32E data of the QEW (58 cars in Table 4.3, 4275 frames in Table 5.4) by
TP, FP and break-up rates per car (thesis §4.6.2, §5.6.2; testbed/scoring/rates.py says how we read them). Here every
named tracker of the papers (``trackers.PAPER_TRACKERS``) runs on ``highway_benchmark`` (427.4 s, 4275 frames,
two-way IDM traffic) for ``N_SEEDS`` scenario seeds (the seed draws the traffic, the roadside objects and the sensor
noise), with both perception pipelines: ``full`` (map ROI, moving-object test, vehicle boxes, occlusion-aware P_D;
docs/perception.md) and ``thesis`` (the thesis's plain pipeline, ``sensor.pipeline = "thesis"``). Each seed and
pipeline is sensed once (testbed/sensing/cache.py) and every tracker runs on the same detections, so the trackers
are compared on common random numbers and the differences against ``jpda-kf`` are paired by seed.

Two denominators ("cars seen", [D]; the thesis does not say which cars it counts):
* cars seen: every car hit by at least one beam in at least one frame (the scoring default);
* trackable cars: a car with at least ``TRACKABLE_POINTS`` LiDAR points in at least ``TRACKABLE_FRAMES`` frames
  (many oncoming cars are hit by a few beams once and no tracker could confirm them); the other cars are left out
  of the counts (their frames are not "visible"), false tracks count as before.

Intervals: Student t 95 % over the per-seed values (n = number of seeds); the thesis-form rows also give the counts
summed over the seeds. Verdicts: a claim that a tracker scores better than another holds when the 95 % interval of
the paired per-seed difference lies on the better side of 0, does not hold when it lies on the other side, and is
"not shown" when it contains 0.

Speed: one task per (pipeline, seed), on a process pool of the usable cores: about 90 s of sensing and 13 tracker
runs from the cache (20-120 s each). Full: 2 pipelines x 5 seeds x 13 trackers; quick (CI): the first 15 s of the scenario, 2 seeds, 4 trackers (33 s wall
on one core, measured with `time taskset -c 0 testbed reproduce thesis-highway --quick`).
"""
from __future__ import annotations

import concurrent.futures as cf
import math
import multiprocessing
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..markdown import verdict as shown_verdict
from ...campaign.report import THESIS_TABLES, mean_sd_ci
from ...common.safe_io import save_figure, write_text
from ...common.stats import PAIRED_T, paired_t

SCENARIO = "highway_benchmark"
PIPELINES = ("full", "thesis")
N_SEEDS = 5
BASELINE = "jpda-kf"
TRACKABLE_POINTS = 10  # [points] in one frame
TRACKABLE_FRAMES = 5  # frames with at least TRACKABLE_POINTS points
QUICK_TRACKERS = ("jpda-kf", "pda-kf", "jpda-gvbl-svsf", "apda-svsf")
QUICK_DURATION_S = 15.0
SCORES = ("tp_pct", "fp_pct", "breakup_pct")
BETTER = {"tp_pct": 1.0, "fp_pct": -1.0, "breakup_pct": -1.0}  # sign of "better"
LABELS = {"tp_pct": "TP %", "fp_pct": "FP %", "breakup_pct": "break-ups %"}
COUNTS = ("cars_seen", "cars_tracked", "false_tracks", "cars_relabelled")
# The thesis's claims: (table, tracker, than, what the thesis printed)
CLAIMS = (("Table 4.3", "jpda-gvbl-svsf", "jpda-kf", "JPDA-GVBL-SVSF TP 91.38 / FP 8.62 / break-ups 2.0 % against "
           "JPDA-KF 84.48 / 15.52 / 8.0 %"),
          ("Table 5.4 (text)", "apda-svsf", "pda-kf", "APDA-SVSF TP 93.42 / FP 6.58 / break-ups 3.1 % against "
           "PDA-KF 84.21 / 14.79 / 7.3 % (the table's row labels say JPDA-GVBL-SVSF and JPDA-KF)"),
          ("Table 5.4 (labels)", "jpda-gvbl-svsf", "jpda-kf", "as the row labels read"))


@dataclass(frozen=True)
class Settings:
    trackers: tuple[str, ...]
    seeds: tuple[int, ...]
    duration_s: float | None  # None: the scenario's 427.4 s


def settings(quick: bool, seed: int) -> Settings:
    from roadtrack.trackers import PAPER_TRACKERS

    n = 2 if quick else N_SEEDS
    return Settings(QUICK_TRACKERS if quick else tuple(PAPER_TRACKERS), tuple(range(seed, seed + n)),
                    QUICK_DURATION_S if quick else None)


def trackable_truth(truth):
    """The truth table (DataFrame) with ``n_points`` set to 0 except in the frames of trackable cars that have
    TRACKABLE_POINTS points or more: scoring it counts only the trackable cars as seen."""
    t = truth.copy()
    n = t["n_points"].to_numpy(dtype=np.int64)
    good = n >= TRACKABLE_POINTS
    cars = t.loc[good, "vehicle_id"].value_counts()
    keep = cars.index[cars.to_numpy() >= TRACKABLE_FRAMES]
    t["n_points"] = np.where(good & t["vehicle_id"].isin(keep).to_numpy(), n, 0)
    return t


def run_task(pipeline: str, seed: int, trackers: tuple[str, ...], duration_s: float | None) -> list[dict]:
    """Every tracker of one (pipeline, seed), sensed once: rows of scores for both denominators."""
    import pandas as pd

    from ...pipeline.run import run_scenario
    from ...scenario.spec import load_scenario
    from ...scoring.evaluate import score

    over = {"sensor.pipeline": pipeline, "seed": seed, **({} if duration_s is None else {"duration_s": duration_s})}
    rows = []
    with tempfile.TemporaryDirectory(prefix="roadtrack-thesis-highway-") as cache:
        for name in trackers:
            scn = load_scenario(SCENARIO, {**over, "tracker.name": name})
            res = run_scenario(scn, record=False, sensing_cache=cache)
            cols = ("frame", "vehicle_id", "x", "y", "vx", "vy", "n_points", "is_ego")
            truth = pd.DataFrame({c: res.tables["truth"].array(c) for c in cols})
            tracks = pd.DataFrame({c: res.tables["tracks"].array(c) for c in ("frame", "track_id", "x", "y", "vx",
                                                                            "vy", "status")})
            for cars, t in (("seen", truth), ("trackable", trackable_truth(truth))):
                s = score(t, tracks, scn.scoring, res.n_frames).scores
                rows.append(dict(pipeline=pipeline, seed=seed, tracker=name, cars=cars, n_frames=res.n_frames,
                                 pos_rmse_m=s.pos_rmse_m, **{k: getattr(s, k) for k in SCORES + COUNTS}))
    return rows


def run_all(s: Settings, progress: bool, out_dir: Path) -> list[dict]:
    """run_task for every (pipeline, seed) on a process pool of the usable cores. Each finished task's rows are kept
    in ``out_dir/results-partial.csv`` at once, and the tasks found there (same trackers and duration) are not run
    again: an interrupted study resumes where it stopped."""
    import pandas as pd
    from tqdm import tqdm

    partial = out_dir / "results-partial.csv"
    rows = done_rows(partial, s)
    done = {(r["pipeline"], int(r["seed"])) for r in rows}
    tasks = [(p, k) for k in s.seeds for p in PIPELINES if (p, k) not in done]
    workers = max(1, min(len(tasks), len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                         else os.cpu_count() or 1))
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool, \
            tqdm(total=len(tasks) + len(done), initial=len(done), desc="thesis-highway", unit="seed",
                 disable=not progress) as bar:
        futures = [pool.submit(run_task, p, k, s.trackers, s.duration_s) for p, k in tasks]
        try:
            for fut in cf.as_completed(futures):
                rows += fut.result()
                write_text(partial, pd.DataFrame(rows).to_csv(index=False))
                bar.update(1)
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    return rows


def done_rows(partial: Path, s: Settings) -> list[dict]:
    """The rows of the tasks of ``partial`` (results-partial.csv) run with the trackers and duration of ``s``."""
    import pandas as pd

    if not partial.is_file():
        return []
    from ...scenario.spec import load_scenario

    df = pd.read_csv(partial)
    n_frames = load_scenario(SCENARIO, {} if s.duration_s is None else {"duration_s": s.duration_s}).n_frames
    rows = []
    for (pipeline, seed), g in df.groupby(["pipeline", "seed"]):
        complete = set(g.tracker) == set(s.trackers) and len(g) == 2 * len(s.trackers)
        if complete and (g.n_frames == n_frames).all() and int(seed) in s.seeds:
            rows += g.to_dict("records")
    return rows


def paired(df, pipeline: str, cars: str, tracker: str, than: str, col: str) -> tuple[int, float, float, float]:
    """(n, mean, lo, hi) of the per-seed difference tracker - than of score ``col`` (paired t 95 %: the same seed
    is the same sensed frames for both trackers)."""
    sub = df[(df.pipeline == pipeline) & (df.cars == cars)]
    a = sub[sub.tracker == tracker].set_index("seed")[col]
    b = sub[sub.tracker == than].set_index("seed")[col]
    both = a.to_frame("a").join(b.to_frame("b"), how="inner").dropna()
    if both.empty:
        return 0, math.nan, math.nan, math.nan
    t = paired_t(both["a"].to_numpy(dtype=np.float64), both["b"].to_numpy(dtype=np.float64))
    return t.n, t.est, t.lo, t.hi


def compare(df, pipeline: str, cars: str, tracker: str, than: str) -> tuple[dict[str, str], list[str]]:
    """Per score "better", "worse" or "no difference shown" of ``tracker`` against ``than`` (the 95 % interval of
    the paired difference on one side of 0), with the evidence "TP % +1.23 [+0.40, +2.06]"."""
    out, words = {}, []
    for col in SCORES:
        n, mean, lo, hi = paired(df, pipeline, cars, tracker, than, col)
        b_lo, b_hi = sorted((BETTER[col] * lo, BETTER[col] * hi)) if n >= 2 else (math.nan, math.nan)
        out[col] = "better" if b_lo > 0 else "worse" if b_hi < 0 else "no difference shown"
        words.append(f"{LABELS[col]} {mean:+.2f} [{lo:+.2f}, {hi:+.2f}] ({out[col]})")
    return out, words


def supports(result: dict[str, str]) -> bool:
    """A variant supports "tracker beats than" when its TP is better and neither FP nor break-ups is worse [D]."""
    return result["tp_pct"] == "better" and "worse" not in (result["fp_pct"], result["breakup_pct"])


def claim_verdict(df, tracker: str, than: str) -> tuple[str, list[str]]:
    """Over the four variants (pipeline x cars): "holds" (all support it), "does not hold" (none does) or "holds only
    under ..." naming the variants that do; with one evidence line per variant. A verdict other than "holds" is
    carried by the seeds' own intervals when some score is shown worse ("worse on ...")."""
    yes, worse, lines = [], [], []
    for pipeline in PIPELINES:
        for cars in ("seen", "trackable"):
            result, words = compare(df, pipeline, cars, tracker, than)
            if supports(result):
                yes.append(f"{pipeline} pipeline, {cars} cars")
            worse += [f"{LABELS[c]} ({pipeline} pipeline, {cars} cars)" for c in SCORES if result[c] == "worse"]
            lines.append(f"{pipeline} pipeline, {cars} cars: " + "; ".join(words))
    if len(yes) == 2 * len(PIPELINES):
        return "holds", lines
    if not yes:
        why = f"worse on {', '.join(worse)}" if worse else "no variant shows a better TP %"
        return f"does not hold ({why})", lines
    return "holds only under: " + ", ".join(yes), lines


def thesis_rows(df, pipeline: str, cars: str, trackers: tuple[str, ...]) -> list[str]:
    """Markdown rows: per tracker the counts summed over the seeds, the pooled rates and the per-seed mean [95 % CI]."""
    rows = []
    for name in trackers:
        sub = df[(df.pipeline == pipeline) & (df.cars == cars) & (df.tracker == name)]
        seen, tracked, false, relab = (int(sub[c].sum()) for c in COUNTS)
        pooled = [100.0 * x / seen if seen else math.nan for x in (tracked, false, relab)]
        cis = []
        for col in SCORES:
            n, mean, _, lo, hi = mean_sd_ci(sub[col].to_numpy())
            cis.append(f"{mean:.2f} [{lo:.2f}, {hi:.2f}]" if n >= 2 else f"{mean:.2f}")
        rows.append(f"| {name} (ours) | {len(sub)} | {seen} | {tracked} | {false} | {relab} | "
                    + " | ".join(f"{v:.2f}" for v in pooled) + " | " + " | ".join(cis) + " |")
    for table, name, cars_n, ok, bad, tp, fp, bu in THESIS_TABLES:
        counts = " | ".join("–" if v is None else str(v) for v in (cars_n, ok, bad)) + " | –"
        rows.append(f"| thesis {table}: {name} | – | {counts} | {tp:.2f} | {fp:.2f} | {bu:.2f} | – | – | – |")
    return rows


def paired_rows(df, pipeline: str, cars: str, trackers: tuple[str, ...]) -> list[str]:
    """Markdown rows: per tracker the paired per-seed difference against BASELINE, mean [95 % CI], per score."""
    rows = []
    for name in trackers:
        if name == BASELINE:
            continue
        cells = []
        for col in SCORES:
            n, mean, lo, hi = paired(df, pipeline, cars, name, BASELINE, col)
            cells.append(f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]" if n >= 2 else f"{mean:+.2f}")
        rows.append(f"| {name} | {n} | " + " | ".join(cells) + " |")
    return rows


def plot_paired(df, cars: str, trackers: tuple[str, ...], path: Path) -> None:
    """Paired per-seed differences against BASELINE (mean, 95 % CI) per tracker: a row per pipeline, a column per
    score, the better side shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    others = [t for t in trackers if t != BASELINE]
    fig, axes = plt.subplots(len(PIPELINES), len(SCORES), figsize=(13, 1.2 + 0.42 * len(others) * len(PIPELINES)),
                             sharey=True, squeeze=False)
    y = np.arange(len(others))
    for i, pipeline in enumerate(PIPELINES):
        for j, col in enumerate(SCORES):
            ax = axes[i, j]
            stats = [paired(df, pipeline, cars, t, BASELINE, col) for t in others]
            mean = np.array([s[1] for s in stats])
            err = np.array([[s[1] - s[2], s[3] - s[1]] for s in stats]).T
            ax.errorbar(mean, y, xerr=np.nan_to_num(err), fmt="o", color="tab:blue", capsize=3)
            ax.axvline(0.0, color="0.3", lw=0.8)
            lo, hi = ax.get_xlim()
            ax.axvspan(0.0, hi if BETTER[col] > 0 else lo, color="tab:green", alpha=0.08, lw=0)
            ax.set_xlim(lo, hi)
            ax.set_yticks(y, others)
            ax.set_title(f"{pipeline} pipeline: {LABELS[col]}, minus {BASELINE}", fontsize=9)
            ax.grid(axis="x", alpha=0.3)
    fig.suptitle(f"{SCENARIO}, {cars} cars: paired per-seed difference against {BASELINE} ({PAIRED_T}; green: better)",
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def summary_text(df, s: Settings, quick: bool) -> str:
    """summary.md: the verdicts, the thesis-form tables with intervals and the paired differences."""
    dur = f"{s.duration_s:g} s" if s.duration_s is not None else "the full 427.4 s (4275 frames)"
    lines = [f"# Thesis Tables 4.3 and 5.4 on `{SCENARIO}`{' (quick)' if quick else ''}", ""]
    for table, tracker, than, printed in CLAIMS:
        if tracker in s.trackers and than in s.trackers:
            result, _ = claim_verdict(df, tracker, than)
            result = shown_verdict(result, quick=quick, supported=result == "holds" or "worse on" in result,
                                   n=len(s.seeds), unit="seeds")
            lines.append(f"- **{table}: {tracker} beats {than}: {result}.** Thesis: {printed}.")
    lines += ["", f"Ours: {len(s.trackers)} trackers, {dur}, seeds {', '.join(map(str, s.seeds))} (the seed draws the "
              "traffic, roadside objects and sensor noise), pipelines `full` and `thesis`; every tracker of a seed and "
              "pipeline on the same sensed frames. The thesis: real HDL-32E data on the QEW, 58 cars (Table 4.3) and "
              "4275 frames (Table 5.4): different data and perception, so its rows are beside ours for orientation.",
              "", "A variant supports \"A beats B\" when A's TP % is better and neither FP % nor break-ups % is worse, "
              f"each judged by the {PAIRED_T} of the per-seed difference (n = seeds) [D]; a quick run states a verdict "
              "only when those intervals carry it. Cars seen: hit by "
              f"at least one beam in one frame; trackable: at least {TRACKABLE_POINTS} points in at least "
              f"{TRACKABLE_FRAMES} frames [D] (the thesis does not say which cars it counts).", ""]
    for table, tracker, than, _ in CLAIMS:
        if tracker in s.trackers and than in s.trackers:
            _, evidence = claim_verdict(df, tracker, than)
            lines += [f"**{table}, {tracker} minus {than}** (per seed, mean [{PAIRED_T}]):", ""]
            lines += [f"- {e}" for e in evidence] + [""]
    head = ("| tracker | runs | cars | correctly tracked | falsely tracked | relabelled | TP % (pooled) | FP % (pooled)"
            " | break-ups % (pooled) | TP % per seed [CI] | FP % per seed [CI] | break-ups % per seed [CI] |")
    for pipeline in PIPELINES:
        for cars in ("seen", "trackable"):
            lines += [f"## {pipeline} pipeline, {cars} cars", "", "Thesis form (counts summed over the seeds; pooled "
                      "rates = counts / cars; per seed: mean and t 95 % interval over the seeds):", "", head,
                      "|" + "---|" * 12] + thesis_rows(df, pipeline, cars, s.trackers)
            lines += ["", f"Paired differences against {BASELINE} (per seed, mean [{PAIRED_T}]; ours only):", "",
                      f"| tracker | seeds | Δ TP % [{PAIRED_T}] | Δ FP % [{PAIRED_T}] | Δ break-ups % [{PAIRED_T}] |",
                      "|---|---|---|---|---|"]
            lines += paired_rows(df, pipeline, cars, s.trackers) + [""]
    lines += ["![paired differences, cars seen](paired_seen.png)", "",
              "![paired differences, trackable cars](paired_trackable.png)", ""]
    return "\n".join(lines)


def run(out_dir: Path, *, quick: bool = False, seed: int = 0, progress: bool = True) -> Path:
    """Run the study into ``out_dir`` (summary.md, results.csv, paired_seen.png, paired_trackable.png)."""
    import pandas as pd

    s = settings(quick, seed)
    out_dir = Path(out_dir)
    df = pd.DataFrame(run_all(s, progress, out_dir)).sort_values(["pipeline", "cars", "tracker", "seed"], kind="stable")
    write_text(out_dir / "results.csv", df.to_csv(index=False))
    return report(out_dir, df, s, quick)


def report(out_dir: Path, df, s: Settings, quick: bool) -> Path:
    """summary.md and the figures of the results ``df`` (results.csv's rows) into ``out_dir``."""
    for cars in ("seen", "trackable"):
        plot_paired(df, cars, s.trackers, out_dir / f"paired_{cars}.png")
    path = out_dir / "summary.md"
    write_text(path, summary_text(df, s, quick))
    return path
