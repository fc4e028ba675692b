"""Campaign summaries: mean, standard deviation and 95 % confidence interval per tracker x grid point,
PNG plots, all collected in ``DIR/report.md`` (``testbed campaign report DIR``).

Statistics are over the successful runs of a cell (scenario, tracker, grid point) whose score is finite
(e.g. ``pos_rmse_m`` is NaN in a run without a correct track): n values x_i, mean, sample standard
deviation s (n - 1 in the denominator) and the Student t interval mean +- t_{0.975, n-1} s / sqrt(n)
(NaN for n < 2).

Plots (matplotlib, Agg backend):

* ``plots/rmse_vs_time*.png``: per-frame position RMSE of correctly tracked vehicles against time, one
  line per tracker, one panel per grid point; across runs the per-frame RMSEs combine as an RMS,
  sqrt(mean_r e_r(t)^2), over the runs that matched a vehicle at that frame;
* ``plots/scores_vs_<key>*.png``: each main score against each grid parameter with 95 % CI error bars,
  one line per tracker (and per value of the other grid parameters); the x axis is logarithmic when the
  positive values span more than two decades (symmetric-log when 0 is among them);
* ``plots/scores_by_tracker*.png`` when the campaign has no grid.

A report reads only finished (whole) run files and removes nothing, so it may be written while the
campaign runs; a damaged run file is left out with a warning line (``resume`` runs it again). A symbolic
link in the folder is refused in one line before anything is written (:func:`store.refuse_links`).
"""
from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common import safe_io
from ..common.stats import PAIRED_T, mean_ci, paired_t
from . import store

BOUNDS = {"tp_pct": (0.0, 100.0), "fp_pct": (0.0, math.inf), "breakup_pct": (0.0, 100.0),
          "coverage_pct": (0.0, 100.0), "pos_rmse_m": (0.0, math.inf), "vel_rmse_mps": (0.0, math.inf),
          "hota": (0.0, 1.0), "idf1": (0.0, 1.0), "mota": (-math.inf, 1.0), "gospa": (0.0, math.inf)}
"""Range of each score: a confidence interval is clipped to it (FP % per car seen can exceed 100)."""
MAIN_SCORES = ("tp_pct", "fp_pct", "breakup_pct", "coverage_pct", "pos_rmse_m", "vel_rmse_mps", "hota", "mota",
               "idf1", "gospa")
LABELS = {"tp_pct": "TP [%]", "fp_pct": "FP [%]", "breakup_pct": "break-ups [%]", "coverage_pct": "coverage [%]",
          "pos_rmse_m": "position RMSE [m]", "vel_rmse_mps": "velocity RMSE [m/s]", "hota": "HOTA", "mota": "MOTA",
          "idf1": "IDF1", "gospa": "GOSPA [m]"}
# Thesis (Attari) Tables 4.3 and 5.4: real HDL-32E data on the QEW, 58 cars (Table 4.3) and 4275 frames
# (Table 5.4: FP 14.79 is printed; 12 of 76 cars would be 15.79). TP, FP, break-ups [%].
THESIS_TABLES = (("Table 4.3", "JPDA-KF", 58, 49, 9, 84.48, 15.52, 8.0),
                 ("Table 4.3", "JPDA-GVBL-SVSF", 58, 53, 5, 91.38, 8.62, 2.0),
                 ("Table 5.4", "JPDA-KF (text: PDA-KF)", None, None, None, 84.21, 14.79, 7.3),
                 ("Table 5.4", "JPDA-GVBL-SVSF (text: APDA-SVSF)", None, None, None, 93.42, 6.58, 3.1))
THESIS_COUNTS = ("cars_seen", "cars_tracked", "false_tracks", "cars_relabelled")


@dataclass
class Report:
    path: Path
    n_runs: int = 0
    n_failed: int = 0
    tables: list[str] = field(default_factory=list)
    plots: list[Path] = field(default_factory=list)


def mean_sd_ci(values) -> tuple[int, float, float, float, float]:
    """(n, mean, sd, ci_lo, ci_hi) of the finite values: Student t 95 % interval of the mean."""
    return mean_ci(values)


def main_scores(columns) -> list[str]:
    return [s for s in MAIN_SCORES if s in columns]


def summarize(df, grid_keys: tuple[str, ...] | list[str]):
    """Long table: one row per (scenario, tracker, grid point, score) with runs, failed, n, mean, sd,
    ci_lo, ci_hi; cells in plan order."""
    import pandas as pd

    keys = ["scenario", "tracker", *grid_keys]
    scores = main_scores(df.columns)
    rows = []
    for cell, group in df.groupby(keys, sort=False, dropna=False):
        cell = cell if isinstance(cell, tuple) else (cell,)
        ok = group[group["status"] == "ok"]
        for score in scores:
            n, mean, sd, lo, hi = mean_sd_ci(ok[score].to_numpy(dtype=np.float64))
            floor, ceil = BOUNDS.get(score, (-math.inf, math.inf))
            lo, hi = min(max(lo, floor), ceil), min(max(hi, floor), ceil)  # NaN (n < 2) stays NaN
            rows.append(dict(zip(keys, cell), score=score, runs=len(group), failed=int((group["status"] != "ok").sum()),
                             n=n, mean=mean, sd=sd, ci_lo=lo, ci_hi=hi))
    return pd.DataFrame(rows)


def thesis_form(df, scenario: str, grid_keys) -> list[str]:
    """Markdown lines: per tracker (and grid point) the counts summed over the seeds and the thesis-form
    percentages of those sums (the thesis's own rows are in :func:`thesis_rows`, once per report)."""
    if not set(THESIS_COUNTS) <= set(df.columns):
        return []
    ok = df[(df["scenario"] == scenario) & (df["status"] == "ok")]
    rows = []
    for cell, g in ok.groupby(["tracker", *grid_keys], sort=False, dropna=False):
        cell = cell if isinstance(cell, tuple) else (cell,)
        seen, tracked, false, relab = (int(g[c].sum()) for c in THESIS_COUNTS)
        pct = [100.0 * x / seen if seen else math.nan for x in (tracked, false, relab)]
        rows.append([f"{cell[0]} (ours)", *cell[1:], len(g), seen, tracked, false, *pct])
    head = ["tracker", *[f"`{k}`" for k in grid_keys], "runs", "cars seen", "correctly tracked", "falsely tracked",
            "TP %", "FP %", "break-ups %"]
    return ["### Thesis-table form (counts summed over the runs)", "",
            "Cars seen = cars hit by at least one beam, summed over the runs; TP % = 100 x cars correctly tracked / "
            "cars seen; FP % = 100 x false confirmed tracks / cars seen; break-ups % = 100 x cars relabelled at least "
            "once / cars seen (definitions in the README).", "", _md_table(head, rows), ""]


def thesis_rows() -> list[str]:
    """Markdown lines: the thesis's published Tables 4.3 and 5.4 rows, once per report."""
    rows = [[f"thesis {table}: {name}", *("–" if v is None else v for v in vals)] for table, name, *vals in THESIS_TABLES]
    return ["## The thesis's published rows (for orientation)", "",
            "Real HDL-32E data on the QEW, another perception: not comparable run for run with ours; the thesis-form "
            "rows of each scenario below are computed the same way from our runs.", "",
            _md_table(["thesis row", "cars", "correctly tracked", "falsely tracked", "TP %", "FP %", "break-ups %"],
                      rows), ""]


def fmt_ci(mean: float, lo: float, hi: float) -> str:
    """``mean [lo, hi]`` with every number to the same decimals, set by the interval's half-width (two
    significant digits of it); a zero-width interval prints as ``mean (no spread)``, a missing one (n < 2) as
    the mean alone."""
    if not np.isfinite(mean):
        return "–"
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return f"{mean:.4g}"
    half = (hi - lo) / 2
    if half <= 0:
        return f"{mean:.4g} (no spread)"
    d = int(min(max(1 - math.floor(math.log10(half)), 0), 6))
    return f"{mean:.{d}f} [{lo:.{d}f}, {hi:.{d}f}]"


def paired_differences(df, baseline: str, grid_keys, scores) -> "pd.DataFrame":
    """Per scenario, tracker (not ``baseline``), grid point and score: the per-seed difference tracker minus
    baseline over the seeds both finished with a finite score (common random numbers: the same seed is the
    same traffic and sensor noise), as n, mean, ci_lo, ci_hi (the paired t 95 % interval,
    testbed.common.stats.paired_t)."""
    import pandas as pd

    ok = df[df["status"] == "ok"]
    keys = ["scenario", *grid_keys, "seed_index"]
    base = ok[ok["tracker"] == baseline].set_index(keys)
    rows = []
    for (scenario, tracker), g in ok[ok["tracker"] != baseline].groupby(["scenario", "tracker"], sort=False):
        g = g.set_index(keys)
        for point, gp in (g.groupby(level=list(range(1, 1 + len(grid_keys))), sort=False) if grid_keys
                          else [((), g)]):
            point = point if isinstance(point, tuple) else (point,)
            for score in scores:
                both = gp[[score]].join(base[[score]], rsuffix="_base", how="inner")
                if both.empty:
                    t = paired_t([math.nan], [math.nan])
                else:
                    t = paired_t(both[score].to_numpy(dtype=np.float64), both[f"{score}_base"].to_numpy(np.float64))
                rows.append(dict(scenario=scenario, tracker=tracker, **dict(zip(grid_keys, point)), score=score,
                                 n=t.n, mean=t.est, ci_lo=t.lo, ci_hi=t.hi))
    return pd.DataFrame(rows)


def _summary_table(summary, scenarios, trackers, grid_keys, scores) -> list[str]:
    """The report's opening table: per scenario, tracker and grid point, n and every main score as mean [95 % CI]."""
    rows = []
    for scenario in scenarios:
        sub = summary[summary["scenario"] == scenario]
        for _, cell in sub.drop_duplicates(subset=["tracker", *grid_keys]).iterrows():
            sel = _rows(sub, cell["tracker"], grid_keys, [cell[k] for k in grid_keys])
            by = sel.set_index("score")
            n = int(by["n"].max()) if len(by) else 0
            rows.append([scenario, cell["tracker"], *[cell[k] for k in grid_keys], n,
                         *[fmt_ci(*(by.loc[c, ["mean", "ci_lo", "ci_hi"]])) if c in by.index else "–" for c in scores]])
    return ["## Summary", "",
            "Mean over the runs of each cell, 95 % Student-t interval of the mean in brackets, n = runs with a "
            "finite score (per score, n can be smaller where a run has nothing to measure, e.g. no correct track "
            "for the RMSE; summary.csv has every n).", "",
            _md_table(["scenario", "tracker", *[f"`{k}`" for k in grid_keys], "n", *[LABELS.get(c, c) for c in scores]],
                      rows), ""]


def _warnings(df, summary, grid_keys, scores) -> list[str]:
    """Markdown warning lines: cells with fewer than 5 runs, and cells whose seeds gave identical results."""
    out = []
    small = summary[(summary["n"] < 5) & (summary["score"] == scores[0])] if scores else summary.iloc[:0]
    if len(small):
        out.append(f"- **n < 5** in {len(small)} of {len(summary[summary['score'] == scores[0]])} cells (fewest: "
                   f"{int(small['n'].min())}): their t intervals are wide and assume near-normal per-run scores; "
                   "raise `seeds` for conclusions.")
    ok = df[df["status"] == "ok"]
    same = []
    for cell, g in ok.groupby(["scenario", "tracker", *grid_keys], sort=False, dropna=False):
        cols = [c for c in (*scores, *THESIS_COUNTS) if c in g.columns]
        if len(g) >= 2 and all(g[c].nunique(dropna=False) == 1 for c in cols):
            same.append(cell if isinstance(cell, tuple) else (cell,))
    if same:
        scen = sorted({c[0] for c in same})
        out.append(f"- **Seeds gave identical results** in {len(same)} cells (scenarios: {', '.join(scen)}): every "
                   "score and count is equal across the seeds, so the seed probably does not change the traffic "
                   "(scripted vehicles, no sensor noise drawn) and the intervals show no spread that is not there; "
                   "these runs are repeats, not samples.")
    return (["## Warnings", "", *out, ""] if out else [])


def _paired_table(pairs, baseline: str, grid_keys, scores) -> list[str]:
    if pairs.empty:
        return []
    rows = []
    for (scenario, tracker, *point), g in pairs.groupby(["scenario", "tracker", *grid_keys], sort=False, dropna=False):
        by = g.set_index("score")
        rows.append([scenario, tracker, *point, int(by["n"].max()),
                     *[fmt_ci(*(by.loc[c, ["mean", "ci_lo", "ci_hi"]])) if c in by.index else "–" for c in scores]])
    return [f"## Paired differences against `{baseline}`", "",
            f"Per seed, the tracker's score minus `{baseline}`'s on the same seed (same traffic and sensor noise), "
            f"mean over the seeds with the {PAIRED_T} (the Student-t interval of the per-seed differences); an "
            "interval that excludes 0 is a difference the runs show. n = seeds both finished.", "",
            _md_table(["scenario", "tracker", *[f"`{k}`" for k in grid_keys], "n",
                       *[f"Δ {LABELS.get(c, c)} [{PAIRED_T}]" for c in scores]], rows), ""]


def _plot_paired(pairs, baseline: str, scenario: str, grid_keys, scores, path: Path) -> bool:
    """Forest plot: per score one panel, per tracker (and grid point) the paired difference with its interval."""
    import matplotlib.pyplot as plt

    sub = pairs[pairs["scenario"] == scenario]
    if sub.empty:
        return False
    labels = []
    for (tracker, *point), g in sub.groupby(["tracker", *grid_keys], sort=False, dropna=False):
        if np.isfinite(g["mean"].to_numpy(dtype=np.float64)).any():  # a cell whose baseline failed has no row
            labels.append((tracker, tuple(point)))
    if not labels:
        return False
    ncol = min(3, len(scores))
    nrow = math.ceil(len(scores) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.8 * ncol, 0.35 * len(labels) * nrow + 1.6 * nrow),
                             squeeze=False)
    for ax, score in zip(axes.flat, scores):
        s = sub[sub["score"] == score]
        for i, (tracker, point) in enumerate(labels):
            sel = _rows(s, tracker, grid_keys, point)
            if sel.empty or not np.isfinite(sel["mean"].iloc[0]):
                continue
            r = sel.iloc[0]
            err = [[r["mean"] - r["ci_lo"]], [r["ci_hi"] - r["mean"]]] if np.isfinite(r["ci_lo"]) else None
            excl = np.isfinite(r["ci_lo"]) and (r["ci_lo"] > 0 or r["ci_hi"] < 0)
            ax.errorbar([r["mean"]], [-i], xerr=err, fmt="o", ms=4, capsize=3, color="tab:red" if excl else "tab:blue")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_ylim(-len(labels) + 0.5, 0.5)
        ax.set_yticks(-np.arange(len(labels)),
                      [t + (" (" + ", ".join(_fmt(v) for v in p) + ")" if p else "") for t, p in labels], fontsize=7)
        ax.set_xlabel(f"Δ {LABELS.get(score, score)}", fontsize=8)
        ax.grid(alpha=0.3)
    _save(fig, axes, len(scores), f"{scenario}: paired difference against {baseline} per seed (mean, {PAIRED_T}; "
          "red: excludes 0)", path)
    return True


def _rows(df, tracker: str | None, keys, values):
    """The rows of ``df`` of ``tracker`` (None: any) whose columns ``keys`` equal ``values``."""
    sel = df if tracker is None else df[df["tracker"] == tracker]
    for k, v in zip(keys, values):
        sel = sel[sel[k] == v]
    return sel


def _fmt(x) -> str:
    if isinstance(x, (float, np.floating)):
        return "–" if not np.isfinite(x) else f"{x:.4g}"
    return str(x)


def _md_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_fmt(v).replace("|", "\\|") for v in r) + " |" for r in rows]
    return "\n".join(lines)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
               for v in values)


def _x_scale(ax, xs: np.ndarray) -> None:
    pos = xs[xs > 0]
    if len(pos) >= 2 and pos.max() / pos.min() > 100.0:
        if np.all(xs > 0):
            ax.set_xscale("log")
        else:
            ax.set_xscale("symlog", linthresh=float(pos.min()))


def _plot_rmse_vs_time(df, grid_keys, scenario, trackers, path: Path) -> bool:
    import matplotlib.pyplot as plt

    ok = df[(df["scenario"] == scenario) & (df["status"] == "ok")]
    if ok.empty or store.SERIES_COLUMN not in ok:
        return False
    points = list(ok.groupby(list(grid_keys), sort=False).groups) if grid_keys else [None]
    if len(points) > 9:
        points = [None]  # too many panels: pool every grid point
    ncol = min(3, len(points))
    nrow = math.ceil(len(points) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 3.4 * nrow), squeeze=False, sharey=True)
    drew = False
    for ax, point in zip(axes.flat, points):
        sel = ok
        title = scenario
        if point is not None:
            point = point if isinstance(point, tuple) else (point,)
            sel = _rows(sel, None, grid_keys, point)
            title = ", ".join(f"{k} = {_fmt(v)}" for k, v in zip(grid_keys, point))
        for tracker in trackers:
            runs = sel[sel["tracker"] == tracker]
            series = [np.asarray(s, dtype=np.float64) for s in runs[store.SERIES_COLUMN]]
            if not series:
                continue
            width = max(len(s) for s in series)
            stack = np.full((len(series), width), np.nan)
            for i, s in enumerate(series):
                stack[i, : len(s)] = s
            counts = np.sum(np.isfinite(stack), axis=0)
            with np.errstate(invalid="ignore"):
                rms = np.sqrt(np.nansum(stack**2, axis=0) / np.maximum(counts, 1))
            rms[counts == 0] = np.nan
            dt = float(np.nanmedian(runs["dt_s"])) if np.isfinite(runs["dt_s"]).any() else 1.0
            ax.plot(np.arange(width) * dt, rms, label=f"{tracker} ({len(series)} runs)")
            drew = True
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("position RMSE [m]")
    axes.flat[0].legend(fontsize=8)
    _save(fig, axes, len(points), f"Position RMSE of correctly tracked vehicles vs time (RMS over runs) — {scenario}",
          path)
    return drew


def _save(fig, axes, used: int, title: str, path: Path) -> None:
    """Hide the axes past the first ``used``, title, write ``path`` (PNG) and free the figure."""
    import matplotlib.pyplot as plt

    for ax in axes.flat[used:]:
        ax.set_visible(False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    safe_io.save_figure(fig, path, dpi=110)
    plt.close(fig)


def _plot_scores_vs_key(summary, key, grid_keys, grid_values, scenario, trackers, path: Path) -> bool:
    import matplotlib.pyplot as plt
    from matplotlib.transforms import ScaledTranslation

    sub = summary[summary["scenario"] == scenario]
    scores = [s for s in MAIN_SCORES if s in set(sub["score"])]
    if not scores:
        return False
    values = list(grid_values[key])
    numeric = _numeric(values)
    others = [k for k in grid_keys if k != key]
    other_points = list(itertools.product(*(grid_values[k] for k in others))) if others else [()]
    lines = [(t, p) for t in trackers for p in other_points]
    ncol = min(3, len(scores))
    nrow = math.ceil(len(scores) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.3 * nrow), squeeze=False)
    for ax, score in zip(axes.flat, scores):
        s = sub[sub["score"] == score]
        for i, (tracker, point) in enumerate(lines):
            sel = _rows(s, tracker, others, point)
            ys, lo, hi, xs = [], [], [], []
            for j, v in enumerate(values):
                row = sel[sel[key] == v]
                if row.empty:
                    continue
                r = row.iloc[0]
                xs.append(float(v) if numeric else j)
                ys.append(r["mean"])
                lo.append(r["mean"] - r["ci_lo"] if np.isfinite(r["ci_lo"]) else 0.0)
                hi.append(r["ci_hi"] - r["mean"] if np.isfinite(r["ci_hi"]) else 0.0)
            if not xs:
                continue
            shift = (i - (len(lines) - 1) / 2) * 0.05
            trans = ax.transData + ScaledTranslation(shift, 0.0, fig.dpi_scale_trans)
            label = tracker
            if others:
                label += " (" + ", ".join(f"{k}={_fmt(v)}" for k, v in zip(others, point)) + ")"
            bars = ax.errorbar(xs, ys, yerr=[lo, hi], marker="o", ms=4, capsize=3, transform=trans, label=label)
            # a shifted transform hides the points from autoscaling: show them to it, invisibly
            ys_arr = np.asarray(ys, dtype=np.float64)
            ax.plot(xs + xs, np.concatenate([ys_arr - lo, ys_arr + hi]), linestyle="none", marker="none",
                    color=bars.lines[0].get_color())
        if numeric:
            _x_scale(ax, np.asarray(values, dtype=np.float64))
        else:
            ax.set_xticks(range(len(values)), [_fmt(v) for v in values], rotation=20, fontsize=8)
        ax.set_xlabel(key, fontsize=8)
        ax.set_ylabel(LABELS.get(score, score))
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=7)
    _save(fig, axes, len(scores), f"Scores vs {key} (mean, 95 % CI) — {scenario}", path)
    return True


def _plot_scores_by_tracker(summary, scenario, trackers, path: Path) -> bool:
    import matplotlib.pyplot as plt

    sub = summary[summary["scenario"] == scenario]
    scores = [s for s in MAIN_SCORES if s in set(sub["score"])]
    if not scores:
        return False
    ncol = min(3, len(scores))
    nrow = math.ceil(len(scores) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.3 * nrow), squeeze=False)
    for ax, score in zip(axes.flat, scores):
        s = sub[sub["score"] == score].set_index("tracker").reindex(trackers)
        lo = (s["mean"] - s["ci_lo"]).fillna(0.0).to_numpy()
        hi = (s["ci_hi"] - s["mean"]).fillna(0.0).to_numpy()
        ax.errorbar(range(len(trackers)), s["mean"].to_numpy(), yerr=[lo, hi], fmt="o", capsize=4)
        ax.set_xticks(range(len(trackers)), trackers, rotation=20, fontsize=8)
        ax.set_ylabel(LABELS.get(score, score))
        ax.grid(alpha=0.3)
    _save(fig, axes, len(scores), f"Scores by tracker (mean, 95 % CI) — {scenario}", path)
    return True


def _detail_table(sub, scenario: str, grid_keys, rep: Report) -> list[str]:
    """Markdown lines: one scenario's every main score per cell, n, mean, sd and 95 % CI (one table)."""
    scores = [s for s in MAIN_SCORES if s in set(sub["score"])]
    rows = []
    for _, r in sub[sub["score"].isin(scores)].iterrows():
        ci = fmt_ci(r["mean"], r["ci_lo"], r["ci_hi"])
        rows.append([r["tracker"], *[r[k] for k in grid_keys], LABELS.get(r["score"], r["score"]), r["runs"],
                     r["failed"], r["n"], _fmt(r["sd"]), ci])
    rep.tables.append(f"{scenario}/details")
    return ["### Every score (n, sd, mean [95 % CI])", "",
            _md_table(["tracker", *[f"`{k}`" for k in grid_keys], "score", "runs", "failed", "n", "sd",
                       "mean [95 % CI]"], rows), ""]


def _failed_runs(df) -> list[str]:
    """Markdown lines: the failed runs grouped by error."""
    err = df[df["status"] != "ok"]
    rows = [[f"`{t}`", m, len(g), g["run_id"].iloc[0]]
            for (t, m), g in err.groupby(["error_type", "error"], sort=False)]
    return ["## Failed runs", "", _md_table(["error", "message", "runs", "first run"], rows), ""]


def _score_plots(summary, grid_keys, grid_values, scenario, trackers, plots: Path, suffix: str) -> list:
    """The scores-vs-grid-key plots (one per key), or scores by tracker without a grid: (title, path) drawn."""
    out = []
    if grid_keys:
        for key in grid_keys:
            p = plots / f"scores_vs_{_slug(key)}{suffix}.png"
            if _plot_scores_vs_key(summary, key, grid_keys, grid_values, scenario, trackers, p):
                out.append((f"scores vs {key}", p))
    else:
        p = plots / f"scores_by_tracker{suffix}.png"
        if _plot_scores_by_tracker(summary, scenario, trackers, p):
            out.append(("scores by tracker", p))
    return out


def _head_lines(campaign, rep: Report, df) -> list[str]:
    """Markdown: the report's title, what ran (runs, axes, seeds, overrides, versions) and how it is summarised."""
    md = [f"# Campaign `{campaign.name}`", ""]
    if campaign.description:
        md += [campaign.description, ""]
    md += [f"{rep.n_runs} of {campaign.n_runs} runs finished, {rep.n_failed} failed. "
           f"{len(campaign.scenarios)} scenario(s) x {len(campaign.trackers)} tracker(s)"
           + "".join(f" x {len(v)} `{k}`" for k, v in campaign.grid) + f" x {campaign.seeds} seeds "
           f"(base_seed {campaign.base_seed}; common random numbers: every tracker and grid point sees the same "
           "seeds).", ""]
    if campaign.overrides:
        md += ["Fixed overrides: " + ", ".join(f"`{k} = {v!r}`" for k, v in campaign.overrides.items()) + ".", ""]
    vcols = [c for c in df.columns if c.startswith("v_")]
    if vcols:
        seen = {c[2:]: sorted(set(df[c].dropna()) - {""}) for c in vcols}
        md += ["Versions: " + ", ".join(f"{k} {'/'.join(v)}" for k, v in seen.items() if v) + ".", ""]
    return md + ["Statistics over the successful runs with a finite score: n, mean, sample standard deviation (sd) "
                 "and the Student t 95 % confidence interval of the mean. Files: `results.parquet` (one row per "
                 "run), `summary.csv` (these tables).", ""]


def write_report(out_dir: str | Path, campaign) -> Report:
    """Consolidate the results of ``out_dir`` and write ``summary.csv``, ``plots/*.png`` and ``report.md``."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    rep = Report(path=out / "report.md")
    store.refuse_links(out)  # before anything is written
    df = store.load_results(out)
    if df.empty:
        return rep
    rep.n_runs = len(df)
    rep.n_failed = int((df["status"] != "ok").sum())
    grid_keys = [k for k in campaign.grid_keys if k in df.columns]
    from .spec import column_values

    grid_values = {k: list(column_values(v)) for k, v in campaign.grid}
    trackers = [t for t in campaign.trackers if t in set(df["tracker"])]
    scenarios = [s.name for s in campaign.scenarios if s.name in set(df["scenario"])]
    summary = summarize(df, grid_keys)
    store.atomic_write_bytes(out / "summary.csv", summary.to_csv(index=False).encode())
    plots = safe_io.make_folder(out / store.PLOTS_DIR)

    planned = campaign.n_runs
    md = _head_lines(campaign, rep, df)
    scores = main_scores(df.columns)
    md += _summary_table(summary, scenarios, trackers, grid_keys, scores)
    rep.tables.append("summary")
    md += _warnings(df, summary, grid_keys, scores)
    baseline = campaign.baseline_tracker
    pairs = paired_differences(df, baseline, grid_keys, scores) if baseline in trackers and len(trackers) > 1 \
        and "seed_index" in df.columns else None
    if pairs is not None and not pairs.empty:
        md += _paired_table(pairs, baseline, grid_keys, scores)
        rep.tables.append("paired")
    if set(THESIS_COUNTS) <= set(df.columns):
        md += thesis_rows()
        rep.tables.append("thesis")

    for scenario in scenarios:
        sub = summary[summary["scenario"] == scenario]
        suffix = f"_{_slug(scenario)}" if len(scenarios) > 1 else ""
        md += [f"## Scenario `{scenario}`", ""]
        md += thesis_form(df, scenario, grid_keys) + _detail_table(sub, scenario, grid_keys, rep)
        md += ["### Plots", ""]
        drawn = []  # (title, path) of each plot drawn
        if pairs is not None and not pairs.empty:
            p = plots / f"paired_vs_{_slug(baseline)}{suffix}.png"
            if _plot_paired(pairs, baseline, scenario, grid_keys, scores, p):
                drawn.append((f"paired differences against {baseline}", p))
        p = plots / f"rmse_vs_time{suffix}.png"
        if _plot_rmse_vs_time(df, grid_keys, scenario, trackers, p):
            drawn.append(("position RMSE vs time", p))
        drawn += _score_plots(summary, grid_keys, grid_values, scenario, trackers, plots, suffix)
        for title, p in drawn:
            rep.plots.append(p)
            md += [f"![{title}]({p.relative_to(out).as_posix()})", ""]

    if rep.n_failed:
        md += _failed_runs(df)
    if planned > rep.n_runs:
        md += [f"{planned - rep.n_runs} runs are missing: `testbed campaign resume {out}` runs them.", ""]
    store.atomic_write_bytes(rep.path, "\n".join(md).encode())
    return rep
