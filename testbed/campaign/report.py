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
from ..common.stats import mean_ci
from . import store

BOUNDS = {"tp_pct": (0.0, 100.0), "fp_pct": (0.0, math.inf), "breakup_pct": (0.0, 100.0),
          "coverage_pct": (0.0, 100.0), "pos_rmse_m": (0.0, math.inf), "vel_rmse_mps": (0.0, math.inf),
          "hota": (0.0, 1.0), "idf1": (0.0, 1.0), "mota": (-math.inf, 1.0), "gospa": (0.0, math.inf)}
"""Range of each score: a confidence interval is clipped to it (FP % per car seen can exceed 100)."""
MAIN_SCORES = ("tp_pct", "fp_pct", "breakup_pct", "coverage_pct", "pos_rmse_m", "vel_rmse_mps", "hota", "mota",
               "idf1", "gospa")
LABELS = {"tp_pct": "TP [%]", "fp_pct": "FP [%]", "breakup_pct": "break-ups [%]", "coverage_pct": "coverage [%]",
          "pos_rmse_m": "position RMSE [m]", "vel_rmse_mps": "velocity RMSE [m/s]", "hota": "HOTA", "mota": "MOTA",
          "idf1": "IDF1", "gospa": "GOSPA"}
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
    percentages of those sums, beside the thesis's Tables 4.3 and 5.4."""
    if not set(THESIS_COUNTS) <= set(df.columns):
        return []
    ok = df[(df["scenario"] == scenario) & (df["status"] == "ok")]
    rows = []
    for cell, g in ok.groupby(["tracker", *grid_keys], sort=False, dropna=False):
        cell = cell if isinstance(cell, tuple) else (cell,)
        seen, tracked, false, relab = (int(g[c].sum()) for c in THESIS_COUNTS)
        pct = [100.0 * x / seen if seen else math.nan for x in (tracked, false, relab)]
        rows.append([f"{cell[0]} (ours)", *cell[1:], len(g), seen, tracked, false, *pct])
    pad = [""] * len(grid_keys)
    rows += [[f"thesis {table}: {name}", *pad, "–", *("–" if v is None else v for v in vals)]
             for table, name, *vals in THESIS_TABLES]
    head = ["tracker", *[f"`{k}`" for k in grid_keys], "runs", "cars seen", "correctly tracked", "falsely tracked",
            "TP %", "FP %", "break-ups %"]
    return ["### Thesis-table form (counts summed over the runs)", "",
            "Our rows: cars seen = cars hit by at least one beam, summed over the runs; TP % = 100 x cars "
            "correctly tracked / cars seen; FP % = 100 x false confirmed tracks / cars seen; break-ups % = 100 x "
            "cars relabelled at least once / cars seen (definitions in the README). The thesis rows are its "
            "published numbers on real QEW data, for orientation only: different data, different perception.",
            "", _md_table(head, rows), ""]


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
            for k, v in zip(grid_keys, point):
                sel = sel[sel[k] == v]
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
            sel = s[s["tracker"] == tracker]
            for k, v in zip(others, point):
                sel = sel[sel[k] == v]
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


def _score_tables(sub, scenario: str, grid_keys, rep: Report) -> list[str]:
    """Markdown lines of one scenario's summary ``sub``: the overview (mean ± CI half-width of every main
    score per cell) and one table per score; their names are added to ``rep.tables``."""
    scores = [s for s in MAIN_SCORES if s in set(sub["score"])]
    cells = sub.drop_duplicates(subset=["tracker", *grid_keys])[["tracker", *grid_keys, "runs", "failed"]]
    rows = []
    for _, cell in cells.iterrows():
        sel = sub[sub["tracker"] == cell["tracker"]]
        for k in grid_keys:
            sel = sel[sel[k] == cell[k]]
        row = [cell["tracker"], *[cell[k] for k in grid_keys], cell["runs"], cell["failed"]]
        for score in scores:
            r = sel[sel["score"] == score].iloc[0]
            half = (r["ci_hi"] - r["ci_lo"]) / 2
            row.append(f"{_fmt(r['mean'])} ± {_fmt(half)}" if np.isfinite(half) else _fmt(r["mean"]))
        rows.append(row)
    md = ["### Overview (per-run mean ± 95 % CI half-width)", "",
          _md_table(["tracker", *[f"`{k}`" for k in grid_keys], "runs", "failed", *scores], rows), ""]
    rep.tables.append(f"{scenario}/overview")
    for score in scores:
        s = sub[sub["score"] == score]
        rows = [[r["tracker"], *[r[k] for k in grid_keys], r["n"], r["mean"], r["sd"],
                 f"[{_fmt(r['ci_lo'])}, {_fmt(r['ci_hi'])}]"] for _, r in s.iterrows()]
        md += [f"### {LABELS.get(score, score)} (`{score}`)", "",
               _md_table(["tracker", *[f"`{k}`" for k in grid_keys], "n", "mean", "sd", "95 % CI"], rows), ""]
        rep.tables.append(f"{scenario}/{score}")
    return md


def _failed_runs(df) -> list[str]:
    """Markdown lines: the failed runs grouped by error."""
    err = df[df["status"] != "ok"]
    rows = [[f"`{t}`", m, len(g), g["run_id"].iloc[0]]
            for (t, m), g in err.groupby(["error_type", "error"], sort=False)]
    return ["## Failed runs", "", _md_table(["error", "message", "runs", "first run"], rows), ""]


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

    md = [f"# Campaign `{campaign.name}`", ""]
    if campaign.description:
        md += [campaign.description, ""]
    planned = campaign.n_runs
    md += [f"{rep.n_runs} of {planned} runs finished, {rep.n_failed} failed. "
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
    md += ["Statistics over the successful runs with a finite score: n, mean, sample standard deviation (sd) "
           "and the Student t 95 % confidence interval of the mean. Files: `results.parquet` (one row per run), "
           "`summary.csv` (these tables).", ""]

    for scenario in scenarios:
        sub = summary[summary["scenario"] == scenario]
        suffix = f"_{_slug(scenario)}" if len(scenarios) > 1 else ""
        md += [f"## Scenario `{scenario}`", ""]
        md += thesis_form(df, scenario, grid_keys) + _score_tables(sub, scenario, grid_keys, rep)
        md += ["### Plots", ""]
        p = plots / f"rmse_vs_time{suffix}.png"
        if _plot_rmse_vs_time(df, grid_keys, scenario, trackers, p):
            rep.plots.append(p)
            md += [f"![position RMSE vs time]({p.relative_to(out).as_posix()})", ""]
        if grid_keys:
            for key in grid_keys:
                p = plots / f"scores_vs_{_slug(key)}{suffix}.png"
                if _plot_scores_vs_key(summary, key, grid_keys, grid_values, scenario, trackers, p):
                    rep.plots.append(p)
                    md += [f"![scores vs {key}]({p.relative_to(out).as_posix()})", ""]
        else:
            p = plots / f"scores_by_tracker{suffix}.png"
            if _plot_scores_by_tracker(summary, scenario, trackers, p):
                rep.plots.append(p)
                md += [f"![scores by tracker]({p.relative_to(out).as_posix()})", ""]

    if rep.n_failed:
        md += _failed_runs(df)
    if planned > rep.n_runs:
        md += [f"{planned - rep.n_runs} runs are missing: `testbed campaign resume {out}` runs them.", ""]
    store.atomic_write_bytes(rep.path, "\n".join(md).encode())
    return rep
