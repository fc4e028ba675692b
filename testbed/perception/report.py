"""`testbed perception SCENARIO`: the perception characterisation as markdown + PNG plots, and the measured
tracker settings written into a copy of the scenario file."""
from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np

from .characterise import RANGE_BINS, VIEW_BINS, VISIBLE_BINS, Characterisation
from ..config import ConfigError
from ..common.jsonio import json_text
from ..common.safe_io import refuse_link, save_figure, write_text
from ..common.stats import wilson

_THESIS_KEYS = (("cars_seen", "cars seen", "d"), ("cars_tracked", "tracked", "d"), ("false_tracks", "false", "d"),
                ("tp_pct", "TP %", ".1f"), ("fp_pct", "FP %", ".1f"), ("breakup_pct", "break-up %", ".1f"))
_OUR_KEYS = (("track_precision_pct", "prec. %", ".1f"), ("coverage_pct", "cover %", ".1f"),
             ("pos_rmse_m", "pos RMSE m", ".2f"), ("hota", "HOTA", ".3f"))


def _pd_figure(ch: Characterisation, out: Path, mid_r: np.ndarray) -> str:
    """pd.png: P_D against range (all, visible, occluded) and against the visible fraction."""
    import matplotlib.pyplot as plt

    vis = ch.vehicles["visible"] >= 0.5
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (label, where, colour, marker) in enumerate((("all in range", None, "k", "o"),
                                                        ("visible >= 50 %", vis, "g", "s"),
                                                        ("occluded (< 50 % visible)", ~vis, "r", "^"))):
        pd, n = ch.pd_by("range", RANGE_BINS, where)
        _pd_curve(ax[0], mid_r + (k - 1) * 0.6, pd, n, colour, marker, label, counts=k == 0)
    ax[0].set(xlabel="range [m]", ylabel="P_D", ylim=(-0.02, 1.08),
              title=f"P_D vs range (95 % Wilson bars; labels: vehicle-frames; bins with < {MIN_BIN} left out)")
    ax[0].title.set_fontsize(9)
    ax[0].legend(fontsize=8, loc="lower left")
    ax[0].grid(alpha=0.3)
    pd, n = ch.pd_by("visible", VISIBLE_BINS)
    mid_v = 0.5 * (VISIBLE_BINS[:-1] + np.minimum(VISIBLE_BINS[1:], 1.0))
    _pd_curve(ax[1], mid_v, pd, n, "b", "o", None, counts=True)
    ax[1].set(xlabel="visible fraction of the silhouette (range image)", ylabel="P_D", ylim=(-0.02, 1.08), xlim=(0, 1),
              title="P_D vs occlusion (95 % Wilson bars; labels: vehicle-frames)")
    ax[1].title.set_fontsize(9)
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, out / "pd.png", dpi=110)
    plt.close(fig)
    return "pd.png"


def _plots(ch: Characterisation, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    mid_r = 0.5 * (RANGE_BINS[:-1] + RANGE_BINS[1:])
    names = [_pd_figure(ch, out, mid_r)]
    if len(ch.detections.get("vehicle_id", ())):
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
        mid_a = 0.5 * (VIEW_BINS[:-1] + VIEW_BINS[1:])
        for a, key, bins, mid, xl in ((ax[0], "range", RANGE_BINS, mid_r, "range [m]"),
                                      (ax[1], "view", VIEW_BINS, mid_a, "view angle [deg] (0 end-on, 90 side)")):
            for which, c in (("box", "tab:blue"), ("centroid", "tab:orange")):
                e = ch.centre_error_by(key, bins, which)
                a.plot(mid, e["bias"], "-o", color=c, ms=4, label=f"{which}: bias along line of sight")
                a.plot(mid, e["spread"], "--s", color=c, ms=4, label=f"{which}: spread (RMS)")
            a.axhline(0.0, color="grey", lw=0.8)
            a.set(xlabel=xl, ylabel="centre error [m]")
            a.grid(alpha=0.3)
        ax[0].set_title("centre error vs range")
        ax[1].set_title("centre error vs view angle")
        ax[0].legend(fontsize=7)
        fig.tight_layout()
        save_figure(fig, out / "centre_error.png", dpi=110)
        plt.close(fig)
        names.append("centre_error.png")

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.5))
    if ch.merge_curve:
        gaps = np.array(sorted(ch.merge_curve))
        ax[0].plot(gaps, [ch.merge_curve[g] for g in gaps], "m-o", ms=4)
    else:
        ax[0].text(0.5, 0.5, "no two cars side by side or nose to tail\nwithin the measured gaps", ha="center",
                   va="center", transform=ax[0].transAxes, fontsize=9, color="0.4")
    ax[0].set(xlabel="bumper-to-bumper gap [m]", ylabel="merge rate", ylim=(-0.02, 1.02),
              title="two cars in one detection vs gap")
    ax[0].grid(alpha=0.3)
    c = ch.clutter_per_frame
    top = int(max(c.max() if len(c) else 0, 3))  # at least 0..3 on the axis: a clutter-free run is not one bar
    if len(c):
        ax[1].hist(c, bins=np.arange(-0.5, top + 1.5), color="tab:red", alpha=0.8, rwidth=0.85)
    ax[1].set_xlim(-0.6, top + 0.6)
    ax[1].xaxis.set_major_locator(MaxNLocator(integer=True))
    ax[1].set(xlabel="clutter detections per frame", ylabel="frames",
              title=(f"clutter (mean {c.mean():.2f} / frame over {len(c)} frames)" if c.any() else
                     f"no clutter detection in any of the {len(c)} frames") if len(c) else "clutter (no frames)")
    fig.tight_layout()
    save_figure(fig, out / "merge_clutter.png", dpi=110)
    plt.close(fig)
    names.append("merge_clutter.png")
    return names


MIN_BIN = 5  # vehicle-frames a P_D bin needs to be drawn


def _pd_curve(ax, x, pd, n, colour, marker, label, counts: bool) -> None:
    """P_D per bin with its 95 % Wilson interval; bins with fewer than MIN_BIN vehicle-frames are gaps (the
    line does not join across them); ``counts`` labels each point with its vehicle-frames."""
    ok = n >= MIN_BIN
    y = np.where(ok, pd, np.nan)
    lo, hi = wilson(np.round(np.where(ok, pd, 0) * n), n)
    ax.plot(x, y, "-", color=colour, marker=marker, ms=4, label=label)
    yerr = np.maximum([y[ok] - lo[ok], hi[ok] - y[ok]], 0.0)  # rounding can put a bound 1 ulp past P_D
    ax.errorbar(x[ok], y[ok], yerr=yerr, fmt="none", ecolor=colour, elinewidth=0.9,
                capsize=2)
    if counts:
        for xi, yi, c in zip(x[ok], y[ok], n[ok]):
            ax.annotate(str(int(c)), (xi, yi), textcoords="offset points", xytext=(0, 6), fontsize=6, ha="center")


def _pd_table(ch: Characterisation) -> list[dict]:
    """P_D by 10 m range bin: all vehicles in range, visible >= 50 %, occluded."""
    bins = np.arange(0.0, ch.max_range_m + 10.0, 10.0)
    vis = ch.vehicles["visible"] >= 0.5
    pd_all, n = ch.pd_by("range", bins)
    pd_vis, _ = ch.pd_by("range", bins, vis)
    pd_occ, _ = ch.pd_by("range", bins, ~vis)
    return [dict(range=f"{bins[b]:.0f}-{min(bins[b + 1], ch.max_range_m):.0f}", n=int(n[b]), all=float(pd_all[b]),
                 visible=float(pd_vis[b]), occluded=float(pd_occ[b])) for b in range(len(bins) - 1) if n[b]]


def _fmt(v, spec: str) -> str:
    if isinstance(v, float) and not math.isfinite(v):
        return "-"
    return format(v, spec)


def _summary_lines(ch: Characterisation, s: dict) -> list[str]:
    """The headline table of the report."""
    return [
        f"{s['frames']} frames; {s['vehicle_frames']} vehicle-frames within {ch.max_range_m:.0f} m of the sensor.",
        "Measured against the scan's per-point truth labels (`testbed/perception/characterise.py` says how).", "",
        "| quantity | value |", "|---|---|",
        f"| ground precision / recall | {100 * s['ground_precision']:.2f} % / {100 * s['ground_recall']:.2f} % |",
        f"| P_D, all vehicles in range | {_fmt(s['pd_in_range'], '.3f')} |",
        f"| P_D, visible >= 50 % / occluded | {_fmt(s['pd_visible'], '.3f')} / {_fmt(s['pd_occluded'], '.3f')} |",
        f"| split rate (vehicle-frames with > 1 detection) | {_fmt(s['split_rate'], '.4f')} |",
        f"| merge rate (detections holding two vehicles) | {_fmt(s['merge_rate'], '.4f')} |",
        f"| clutter per frame (thesis's estimate) | {_fmt(s['clutter_per_frame'], '.3f')} |",
        f"| clutter per m^2: road within range / sensor disk | {_fmt(s['clutter_per_m2_road'], '.2e')} / "
        f"{_fmt(s['clutter_per_m2_disk'], '.2e')} |",
        f"| centre RMSE: box fit / centroid [m] | {_fmt(s['centre_rmse_box_m'], '.3f')} / "
        f"{_fmt(s['centre_rmse_centroid_m'], '.3f')} |",
        f"| box centre noise along / across the line of sight, std [m] | {_fmt(s['noise_along_std_m'], '.3f')} / "
        f"{_fmt(s['noise_across_std_m'], '.3f')} (bias along {_fmt(s['noise_along_bias_m'], '+.3f')}) |",
        f"| per-detection R calibration, mean e' R^-1 e (2 = calibrated) | {_fmt(s['r_nees_mean'], '.2f')} |",
        "",
    ]


def _ablation_lines(ablation: dict[str, dict]) -> list[str]:
    """The false tracks each static-object method removes, scores in the thesis's form and ours."""
    lines = ["## Static objects: false tracks removed by each method", "",
              "The scenario's tracker run with each method switched off in turn. Left of the bar, the thesis's "
              "form (Tables 4.3, 5.4: per car seen); right, ours.", "",
              "| variant | " + " | ".join(h for _, h, _ in _THESIS_KEYS) + " || " +
              " | ".join(h for _, h, _ in _OUR_KEYS) + " |",
              "|---|" + "---|" * len(_THESIS_KEYS) + "|" + "---|" * len(_OUR_KEYS)]
    for name, sc in ablation.items():
        lines.append(f"| {name} | " + " | ".join(_fmt(sc[k], f) for k, _, f in _THESIS_KEYS) + " || " +
                     " | ".join(_fmt(sc[k], f) for k, _, f in _OUR_KEYS) + " |")
    ft = {k: v["false_tracks"] for k, v in ablation.items()}
    if all(k in ft for k in ("full", "no map ROI", "no moving-object test", "neither")):
        lines += ["", f"False confirmed tracks removed, each method on its own (the other off): the map ROI "
                  f"{ft['neither'] - ft['no moving-object test']}, the moving-object test "
                  f"{ft['neither'] - ft['no map ROI']}; both together {ft['neither'] - ft['full']} "
                  f"({ft['neither']} without either, {ft['full']} left with both).", ""]
    return lines


def write_report(ch: Characterisation, out: Path, ablation: dict[str, dict] | None = None,
                 settings: dict[str, float] | None = None, note: str = "") -> Path:
    """Write ``out``/report.md, summary.json and the PNG plots; return the markdown path."""
    out.mkdir(parents=True, exist_ok=True)
    plots = _plots(ch, out)
    s = ch.summary()
    lines = [f"# Perception characterisation: {ch.scenario}", ""]
    if note:
        lines += [note, ""]
    lines += _summary_lines(ch, s)
    if ch.rejected:
        lines += ["Clusters rejected by each selection test (all frames): " +
                  ", ".join(f"{k} {v}" for k, v in sorted(ch.rejected.items(), key=lambda kv: -kv[1])) + ".", ""]
    lines += ["![P_D](pd.png)", ""]
    pd_rows = _pd_table(ch)
    lines += ["| range [m] | vehicle-frames | P_D all | P_D visible >= 50 % | P_D occluded |", "|---|---|---|---|---|"]
    lines += [f"| {r['range']} | {r['n']} | {_fmt(r['all'], '.3f')} | {_fmt(r['visible'], '.3f')} | "
              f"{_fmt(r['occluded'], '.3f')} |" for r in pd_rows] + [""]
    if "centre_error.png" in plots:
        lines += ["![centre error](centre_error.png)", ""]
        rows = ["| range [m] | n | box bias | box spread | centroid bias | centroid spread |", "|---|---|---|---|---|---|"]
        eb, ec = ch.centre_error_by("range", RANGE_BINS, "box"), ch.centre_error_by("range", RANGE_BINS, "centroid")
        for b in range(len(RANGE_BINS) - 1):
            if eb["count"][b]:
                rows.append(f"| {RANGE_BINS[b]:.0f}-{RANGE_BINS[b + 1]:.0f} | {eb['count'][b]} | "
                            f"{_fmt(eb['bias'][b], '+.2f')} | {_fmt(eb['spread'][b], '.2f')} | "
                            f"{_fmt(ec['bias'][b], '+.2f')} | {_fmt(ec['spread'][b], '.2f')} |")
        lines += rows + [""]
    lines += ["![merge and clutter](merge_clutter.png)", ""]
    if ch.merge_curve:
        lines += ["| gap [m] | " + " | ".join(f"{g:g}" for g in sorted(ch.merge_curve)) + " |",
                  "|---|" + "---|" * len(ch.merge_curve),
                  "| merge rate | " + " | ".join(_fmt(ch.merge_curve[g], ".2f") for g in sorted(ch.merge_curve)) + " |",
                  ""]
    if ablation:
        lines += _ablation_lines(ablation)
    if settings:
        lines += ["## Measured tracker settings", "",
                  "`testbed perception --write-settings FILE` writes these into a copy of the scenario:", ""]
        lines += [f"- `{k} = {v}`" for k, v in settings.items()] + [""]
    md = out / "report.md"
    write_text(md, "\n".join(lines))
    doc = dict(summary=s, merge_curve={str(k): v for k, v in ch.merge_curve.items()}, rejected=ch.rejected,
               ablation=ablation or {}, pd_by_range=pd_rows, settings=settings or {})
    write_text(out / "summary.json", json_text(doc, indent=2, default=float) + "\n")
    return md


# ---------------------------------------------------------------------- writing a scenario file
def dumps_toml(data: dict) -> str:
    """TOML text of a scenario dict (tables, arrays of tables, inline tables in arrays; no dates)."""
    lines: list[str] = []
    _emit_table(data, [], lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_scalar(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_scalar(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def _is_table_array(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _emit_table(table: dict, path: list[str], lines: list[str]) -> None:
    for k, v in table.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_key(k)} = {_scalar(v)}")
    for k, v in table.items():
        if isinstance(v, dict):
            lines += ["", "[" + ".".join(_key(p) for p in path + [k]) + "]"]
            _emit_table(v, path + [k], lines)
        elif _is_table_array(v):
            for item in v:
                lines += ["", "[[" + ".".join(_key(p) for p in path + [k]) + "]]"]
                _emit_table(item, path + [k], lines)


SETTINGS_MARK = "# written by testbed perception --write-settings"  # the first line of a settings file
_LEGACY_MARK = "with the tracker settings measured by `testbed perception` ("  # its first line before the mark


def written_settings(path: Path) -> bool:
    """Whether the regular file ``path`` starts with the first line of a file :func:`write_settings` wrote."""
    with open(path, "rb") as f:
        first = f.read(4096).split(b"\n", 1)[0].decode("utf-8", "replace")
    return first.startswith(SETTINGS_MARK) or (first.startswith("# ") and _LEGACY_MARK in first)


def check_settings_path(text: str) -> Path:
    """The ``--write-settings`` file ``text``, checked before any work: a new file in an existing folder, or
    a settings file this command wrote earlier (replaced); never a folder or another file (ConfigError)."""
    key = "--write-settings"
    if not text.strip():
        raise ConfigError(key, "is empty; give a file path, e.g. measured.toml")
    path = Path(text).expanduser()
    if path.is_dir() or text.endswith(("/", os.sep)):
        what = "is a folder" if path.is_dir() else "ends with '/' (a folder)"
        raise ConfigError(key, f"{text} {what}; give a file path, e.g. {Path(text) / 'measured.toml'}")
    if not path.parent.is_dir():
        raise ConfigError(key, f"folder {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise ConfigError(key, f"cannot write in folder {path.parent} (permission denied); choose another file")
    refuse_link(path, key, text)  # never written through (safe_io), so refused before any work
    if not path.exists():
        return path
    if not stat.S_ISREG(path.stat().st_mode):
        raise ConfigError(key, f"{text} is not a regular file; choose another file")
    try:
        ours = written_settings(path)
    except OSError as err:
        raise ConfigError(key, f"{text}: cannot read it ({os.strerror(err.errno).lower() if err.errno else err}); "
                          "choose another file") from None
    if not ours:
        raise ConfigError(key, f"{text} exists and was not written by `testbed perception --write-settings`; it "
                          "is left unchanged: choose another file, or remove it first")
    return path


def _comment(text: str) -> str:
    """``text`` fit for a TOML comment: control characters (a newline would end it) escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def write_settings(scenario_data: dict, settings: dict[str, float], path: Path, source: str) -> None:
    """Write ``scenario_data`` with the dotted ``settings`` applied to ``path`` (a new scenario file, or one
    this function wrote earlier: :func:`check_settings_path`), atomically, its first line :data:`SETTINGS_MARK`."""
    from ..pipeline.outdir import write_atomic
    from ..scenario.spec import apply_overrides
    from ..world import parse_scenario

    path = check_settings_path(str(path))  # again: the file may have appeared during the characterisation
    data = apply_overrides(scenario_data, settings)
    parse_scenario(data)  # never write a file that does not load
    head = (f"{SETTINGS_MARK}: {_comment(source)} with the tracker settings it measured "
            f"({', '.join(f'{k} = {v}' for k, v in settings.items())}).\n")
    text = head + dumps_toml(data)
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))  # never a half-written scenario file
