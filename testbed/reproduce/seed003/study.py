"""Reproduction of paper 003: symmetric measurement equations (sum of powers, sum of products) with an EKF.

    run(out_dir, *, quick=False, seed=0, progress=True) -> Path   writes summary.md and PNG figures

Parts (the paper's claims, and ours beside them, in summary.md):
  1. the analytic mean and covariance of the transformed noise (sensors.symmetric, closed forms for N = 2, 3)
     against Monte Carlo and against the general-N formulas the filter uses (trackers.sme);
  2. the paper's Monte Carlo (testbed.reproduce.seed003.sme_targets.paper_scenario: 3 targets, 20 s at T = 0.01 s, sigma = 5 m):
     the associated KF and the EKFs on sum of products and on sum of powers, labelled per step by the
     permutation of minimum squared error; RMSE per target over time (the paper's Fig. 2), one run (Fig. 1);
  3. ours only: the ordering against the initial covariance P0 (the printed P0 is undecodable, [D]), and N = 2.
Full: 100 runs (paper), 2e6 noise samples per covariance case (about 1.5 min of one core). Quick: 10 runs, 2e5
samples (9 s wall, measured with `time testbed reproduce seed-003 --quick`).
Streams: the runs of every filter and every P0 are the same seeded runs (common random numbers).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roadtrack.sensors.symmetric import FORMS, SymmetricSensor, monte_carlo_moments
from . import sme_targets as st
from ...common.safe_io import save_figure, write_text
from roadtrack.trackers.sme import symmetric_noise_covariance, symmetric_noise_mean
from ..markdown import table as md_table, verdict as shown_verdict
from ...common.stats import PAIRED_T, paired_t, wilson

FILTERS = ("kf", "products", "powers")
NAMES = {"kf": "KF (associated, linear)", "products": "EKF sum of products", "powers": "EKF sum of powers"}
COLOURS = {"kf": "k", "products": "tab:blue", "powers": "tab:red"}
DIVERGED_M = 5.0  # [D] a run diverged if a labelled final position error exceeds sigma = 5 m (KF: ~0.25 m)

# (N, positions, sigma): far apart, the paper's truth, negative, near-coincident, and the reference's sigma^2 = 4
COV_CASES = ((2, (3.0, 25.0), 5.0), (2, (-40.0, 10.0), 5.0), (2, (10.0, 10.1), 5.0),
             (3, (3.0, 25.0, 120.0), 5.0), (3, (50.0, 10.0, 120.0), 5.0), (3, (1.0, -2.0, 0.5), 2.0),
             (3, (10.0, 10.1, -3.0), 5.0))

P0_VARIANTS = (("default [D] = squared initial errors", st.PAPER_P0_DIAG),
               ("default / 4", tuple(v / 4 for v in st.PAPER_P0_DIAG)),
               ("default x 4", tuple(v * 4 for v in st.PAPER_P0_DIAG)),
               ("unmatched, unequal: diag(100, 400, 900, 100, 100, 100)", (100.0, 400.0, 900.0, 100.0, 100.0, 100.0)),
               ("printed digits read in pairs: diag(16, 25, 2, 64, 25, 90)", (16.0, 25.0, 2.0, 64.0, 25.0, 90.0)),
               ("equal position entries: diag(100, 100, 100, 25, 25, 25)", (100.0, 100.0, 100.0, 25.0, 25.0, 25.0)))


@dataclass(frozen=True)
class Settings:
    """runs: Monte Carlo runs of the main study and N = 2; p0_runs: per P0 variant; cov_samples: noise samples
    per covariance case; steps: scans of T = 0.01 s."""

    runs: int
    p0_runs: int
    cov_samples: int
    steps: int = 2000


def settings(quick: bool) -> Settings:
    return Settings(10, 10, 200_000) if quick else Settings(100, 100, 2_000_000)


# ------------------------------------------------------------------------------------- part 1
def covariance_rows(samples: int, seed: int) -> list[dict]:
    """One row per (case, form): Monte Carlo vs closed form (sensor) vs general formula (filter)."""
    rng = np.random.default_rng(np.random.SeedSequence((seed, 3)))  # 3: a stream apart from the runs' streams
    rows = []
    for n, x, sigma in COV_CASES:
        x = np.array(x)
        for form in FORMS:
            sen = SymmetricSensor(form, n, sigma)
            R, mean = sen.noise_covariance(x), sen.noise_mean(x)
            mc = monte_carlo_moments(sen, x, samples, rng)
            scale = np.sqrt(np.outer(np.diag(R), np.diag(R)))
            general = max(np.abs(symmetric_noise_covariance(x, form, sigma) - R).max() / np.abs(R).max(),
                          np.abs(symmetric_noise_mean(x, form, sigma) - mean).max() / np.abs(R).max() ** 0.5)
            rows.append(dict(n=n, x=tuple(x), sigma=sigma, form=form, samples=mc.n,
                             cov_z=float(np.abs((mc.cov - R) / mc.cov_se).max()),
                             cov_norm=float((np.abs(mc.cov - R) / scale).max()),
                             mean_z=float(np.abs((mc.mean - mean) / mc.mean_se).max()),
                             general=float(general), R=R, R_mc=mc.cov,
                             raw_z=float(np.abs(mc.raw_var - 1.0).max() / np.sqrt(2.0 / mc.n))))
    return rows


# ------------------------------------------------------------------------------------- part 2
@dataclass(frozen=True)
class MonteCarlo:
    """times (K + 1,); truth (K + 1, 2N); per filter: labelled estimates (R, K + 1, 2N), rmse (K + 1, N),
    diverged (R,) bool, exchanges (R,) label changes after 1 s, permuted (R,) bool: the slots end as a
    non-identity permutation of the targets; raw: the unlabelled SME estimates (R, K + 1, 2N) per form."""

    times: np.ndarray
    truth: np.ndarray
    est: dict
    rmse: dict
    diverged: dict
    exchanges: dict
    permuted: dict
    raw: dict


def monte_carlo(scn: st.LineTargets, n_runs: int, seed: int, forms=FORMS, bar=None) -> MonteCarlo:
    """KF and the SME EKFs on the same `n_runs` seeded runs of `scn`."""
    runs = st.simulate(scn, n_runs, seed)
    est, rmse, div, exch, permuted, raw = {}, {}, {}, {}, {}, {}
    one_second = int(round(1.0 / scn.dt))
    for name in ("kf",) + tuple(forms):
        if name == "kf":  # labelled by construction: no exchange, no permutation
            e = st.track_associated(scn, runs)
            exch[name], permuted[name] = np.zeros(n_runs, dtype=np.int64), np.zeros(n_runs, dtype=bool)
        else:
            raw[name] = st.track_symmetric(scn, runs, name)
            e, perm = st.labelled(raw[name], runs.truth)
            exch[name] = st.label_exchanges(perm, one_second)
            permuted[name] = (perm[:, -1] != np.arange(scn.n_targets)).any(axis=-1)
        est[name], rmse[name] = e, st.position_rmse(e, runs.truth)
        div[name] = st.diverged(e, runs.truth, DIVERGED_M)
        if bar is not None:
            bar.update(1)
    return MonteCarlo(scn.times, runs.truth, est, rmse, div, exch, permuted, raw)


def window_mean(mc: MonteCarlo, name: str, target: int, t0: float, t1: float) -> float:
    """Mean over t0 <= t <= t1 of the RMSE of `target` (0-based)."""
    k = (mc.times >= t0 - 1e-9) & (mc.times <= t1 + 1e-9)
    return float(mc.rmse[name][k, target].mean())


def kink(mc: MonteCarlo, name: str, target: int, t_cross: float) -> tuple[float, float]:
    """(peak EKF/KF RMSE ratio, its time) within 1 s of a crossing time."""
    k = np.flatnonzero(np.abs(mc.times - t_cross) <= 1.0)
    ratio = mc.rmse[name][k, target] / mc.rmse["kf"][k, target]
    i = int(np.argmax(ratio))
    return float(ratio[i]), float(mc.times[k[i]])


def per_run_rms(mc: MonteCarlo, name: str, target: int, t0: float = 1.0) -> np.ndarray:
    """(R,) RMS position error [m] of `target` per run over t >= t0 (labelled estimates): the per-run values the
    paired comparisons use (every filter runs on the same runs)."""
    k = mc.times >= t0 - 1e-9
    return np.sqrt(((mc.est[name][:, k, target] - mc.truth[None, k, target]) ** 2).mean(axis=1))


def share_below(mc: MonteCarlo, a: str, b: str, target: int, t0: float = 1.0) -> float:
    """Share of steps with t >= t0 at which RMSE_a <= RMSE_b for `target`."""
    k = mc.times >= t0 - 1e-9
    return float((mc.rmse[a][k, target] <= mc.rmse[b][k, target]).mean())


def p0_rows(scn: st.LineTargets, n_runs: int, seed: int, bar=None) -> list[dict]:
    """Target 1's mean RMSE over 1-20 s, the divergence rate and the per-run RMS over 1-20 s (runs_<filter>, for the
    paired ordering) of every filter, for each P0 variant: the same n_runs seeded runs under every P0, all variants
    filtered in one batch."""
    runs = st.simulate(scn, n_runs, seed)
    V = len(P0_VARIANTS)
    stacked = st.LineRuns(truth=runs.truth, z=np.tile(runs.z, (V, 1, 1)), sigma=runs.sigma)
    P0 = np.repeat(np.array([np.diag(p) for _, p in P0_VARIANTS], dtype=np.float64), n_runs, axis=0)
    k = scn.times >= 1.0 - 1e-9
    rows = [dict(label=label, p0=p0) for label, p0 in P0_VARIANTS]
    for name in FILTERS:
        if name == "kf":
            e = st.track_associated(scn, stacked, P0)
        else:
            e = st.labelled(st.track_symmetric(scn, stacked, name, P0), runs.truth)[0]
        for v, row in enumerate(rows):
            part = e[v * n_runs:(v + 1) * n_runs]
            row[f"rmse_{name}"] = float(st.position_rmse(part, runs.truth)[k, 0].mean())
            row[f"div_{name}"] = float(st.diverged(part, runs.truth, DIVERGED_M).mean())
            row[f"runs_{name}"] = np.sqrt(((part[:, k, 0] - runs.truth[None, k, 0]) ** 2).mean(axis=1))  # (R,)
        if bar is not None:
            bar.update(1)
    return rows


# -------------------------------------------------------------------------------------- figures
def _mark_crossings(ax, scn: st.LineTargets, target: int | None) -> None:
    for i, j, t in scn.crossing_times():
        mine = target is None or target in (i, j)
        ax.axvline(t, color="0.5", ls="--" if mine else ":", lw=0.8)
        ax.text(t, 1.0, f" {i + 1}-{j + 1}", transform=ax.get_xaxis_transform(), fontsize=7, va="top", color="0.4")


def example_run(mc: MonteCarlo) -> int:
    """The first run whose sum-of-powers slots end permuted (the paper's Fig. 1 case), else run 0."""
    form = "powers" if "powers" in mc.permuted else next(iter(mc.raw))
    hits = np.flatnonzero(mc.permuted[form])
    return int(hits[0]) if hits.size else 0


def figure_single_run(path: Path, scn: st.LineTargets, mc: MonteCarlo, run: int) -> None:
    """Fig. 1: truth and the unlabelled EKF slots of one run, both forms."""
    import matplotlib.pyplot as plt

    n = scn.n_targets
    fig, axes = plt.subplots(1, len(mc.raw), figsize=(11, 4), sharey=True, squeeze=False)
    for ax, form in zip(axes[0], sorted(mc.raw, reverse=True)):
        for i in range(n):
            ax.plot(mc.times, mc.truth[:, i], "k--", lw=1.0, label="truth" if i == 0 else None)
            ax.plot(mc.times, mc.raw[form][run, :, i], lw=1.2, label=f"EKF slot {i + 1}")
        _mark_crossings(ax, scn, None)
        slots = "slots end permuted" if mc.permuted[form][run] else "slots end in target order"
        ax.set_title(f"{NAMES[form]}: run {run}, unlabelled ({slots})", fontsize=9)
        ax.set_xlabel("time [s]")
        ax.set_ylim(-30, 240)
    axes[0][0].set_ylabel("position [m]")
    axes[0][0].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def figure_rmse(path: Path, scn: st.LineTargets, mc: MonteCarlo, targets: tuple[int, ...], n_runs: int) -> None:
    """Fig. 2 (target 1) or all targets: position RMSE over time, log-y, crossing times marked."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(targets), figsize=(5.2 * len(targets) + 1, 4), squeeze=False)
    for ax, tgt in zip(axes[0], targets):
        for name in FILTERS:
            ax.semilogy(mc.times[1:], mc.rmse[name][1:, tgt], color=COLOURS[name], lw=1.1, label=NAMES[name])
        _mark_crossings(ax, scn, tgt)
        ax.set_title(f"target {tgt + 1}: position RMSE over {n_runs} runs (EKF labelled per step)", fontsize=9)
        ax.set_xlabel("time [s]")
        ax.set_ylim(0.1, 100)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("RMSE [m]")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


# -------------------------------------------------------------------------------------- summary
def _f(v: float, digits: int = 3) -> str:
    return f"{v:.{digits}g}"


def _vec(v, brackets: str = "[]") -> str:
    return brackets[0] + ", ".join(f"{float(a):g}" for a in v) + brackets[1]


def _setup_lines(scn: st.LineTargets, s: Settings, seed: int, quick: bool) -> list[str]:
    x0, P0 = scn.initial_estimate
    crossings = ", ".join(f"{t:.1f} s" for _, _, t in scn.crossing_times())
    rows = [["targets N", "3 (formulation for any N; N = 2 also derived)", "3 (main); 2 (extra, ours)"],
            ["raw noise", "sigma_k^2 = diag(25 25 25)", f"sigma = {scn.sigma} m"],
            ["duration / sampling", "20 s / 0.01 s", f"{scn.steps * scn.dt:g} s / {scn.dt} s ({scn.steps} scans)"],
            ["Monte Carlo runs", "100", f"{s.runs}" + (f" (quick; {s.p0_runs} per P0 variant)" if quick else "")],
            ["truth X0", "printed \"3251201050\" (garbled)", f"{_vec(scn.x0)} reconstructed (crossings {crossings})"],
            ["initial estimate", "X̂0 = 0", _vec(x0)],
            ["P0", "printed \"diag 162502642590\" (undecodable)", f"diag{_vec(np.diag(P0), '()')} [D]"],
            ["process noise", "Q = 0", "Q = 0"],
            ["R in the EKF", "\"as calculated from the above expressions\"",
             "analytic R(x) at the predicted positions [D]"],
            ["labelling", "permutation of minimum sum of squared error", "per step, positions and velocities [D]"],
            ["seed", "–", str(seed)]]
    return (["## Set-up: the paper's and ours", ""] + md_table(["item", "paper 003", "ours"], rows)
            + ["Tags: [D] our default where the paper is silent or unreadable; \"reconstructed\" where the printed "
               "value is garbled and the reading is ours (see the notes at the end).", ""])


def _claim_stats(mc: MonteCarlo, scn: st.LineTargets) -> dict:
    """The numbers behind the claims table (target 1 unless stated)."""
    t_end = scn.steps * scn.dt
    away = (mc.times >= 14) & (mc.times <= 18)
    return dict(
        m={f: window_mean(mc, f, 0, 1.0, t_end) for f in FILTERS},
        paired={(a, b): paired_t(per_run_rms(mc, a, 0), per_run_rms(mc, b, 0))
                for a, b in (("kf", "products"), ("kf", "powers"), ("products", "powers"))},
        kf_low=min(share_below(mc, "kf", "products", 0), share_below(mc, "kf", "powers", 0)),
        prod_pow=share_below(mc, "products", "powers", 0),
        kinks=[(t, kink(mc, "products", 0, t), kink(mc, "powers", 0, t))
               for i, j, t in scn.crossing_times() if 0 in (i, j)],
        base={f: float(np.median(mc.rmse[f][away, 0] / mc.rmse["kf"][away, 0])) for f in FORMS},
        exch={f: float((mc.exchanges[f] > 0).mean()) for f in FORMS},
        perm={f: float(mc.permuted[f].mean()) for f in FORMS},
        div={f: float(mc.diverged[f].mean()) for f in FILTERS},
        per_target="; ".join(f"target {i + 1}: " + ", ".join(f"{f} {window_mean(mc, f, i, 1.0, t_end):.3f}"
                                                             for f in FILTERS) for i in range(scn.n_targets)))


def _pt(t) -> str:
    return f"{t.est:+.3f} m [{t.lo:+.3f}, {t.hi:+.3f}]"


def _claim_rows(mc: MonteCarlo, cov: list[dict], scn: st.LineTargets, quick: bool = False) -> list[list[str]]:
    """The claims table: (claim, paper, ours, verdict). A quick run states a verdict only where its own numbers
    carry it (an interval or test, or an event seen), else "indicative (n runs): not a verdict"."""
    c = _claim_stats(mc, scn)
    m, exch, perm, div, pt = c["m"], c["exch"], c["perm"], c["div"], c["paired"]
    worst = max(cov, key=lambda r: r["cov_z"])
    cz, cn = worst["cov_z"], max(r["cov_norm"] for r in cov)
    kink_txt = "; ".join(f"crossing at {t:.1f} s: products {p[0]:.2f} at {p[1]:.2f} s, powers {w[0]:.2f} at "
                         f"{w[1]:.2f} s" for t, p, w in c["kinks"])
    kinks_hold = all(p[0] > c["base"]["products"] and w[0] > c["base"]["powers"] for _, p, w in c["kinks"])
    kf_low = pt[("kf", "products")].below and pt[("kf", "powers")].below
    pp = pt[("products", "powers")]
    n = len(mc.diverged["kf"])
    div_k = max(int(mc.diverged[f].sum()) for f in FILTERS)
    div_lo, div_hi = wilson(div_k, n)
    rows = [  # (claim, paper, ours, verdict, supported)
        ["noise covariance (§III)", "analytic R \"verified\" by Monte Carlo (no numbers)",
         f"max abs(MC - analytic) = {cz:.2f} standard errors (in that case the raw noise's own sample variance "
         f"is {worst['raw_z']:.1f} SE off sigma^2), max {100 * cn:.2f} % of sqrt(R_aa R_bb) over {len(cov)} cases",
         "yes" if cz < 5 else "no", True],
        ["KF lowest (Fig. 2)", "RMSE(KF) < RMSE(EKF), target 1",
         f"mean RMSE 1-20 s: KF {m['kf']:.3f} m, products {m['products']:.3f} m, powers {m['powers']:.3f} m; "
         f"KF <= both EKFs at {100 * c['kf_low']:.1f} % of steps; per-run RMS 1-20 s, KF - products "
         f"{_pt(pt[('kf', 'products')])}, KF - powers {_pt(pt[('kf', 'powers')])} ({PAIRED_T}, {n} runs)",
         "yes" if kf_low else "no", kf_low or pt[("kf", "products")].above or pt[("kf", "powers")].above],
        ["products below powers (Fig. 2, §V)", "RMSE(products) < RMSE(powers)",
         f"mean {m['products']:.3f} vs {m['powers']:.3f} m; products <= powers at {100 * c['prod_pow']:.1f} % of "
         f"steps; per-run RMS 1-20 s, products - powers {_pt(pp)} ({PAIRED_T}, {n} runs; see the P0 table)",
         ("on average" if pp.below else "no") + ("" if not pp.below or c["prod_pow"] > 0.9 else ", not at every time"),
         pp.below or pp.above],
        ["kinks near the 5th and 10th s", "due to track label exchange",
         f"peak EKF/KF RMSE ratio within 1 s of target 1's crossings: {kink_txt}; away from crossings (14-18 s) "
         f"products {c['base']['products']:.2f}, powers {c['base']['powers']:.2f}", "yes" if kinks_hold else "partly",
         False],
        ["tracks without identity (Fig. 1)", "in some runs the filter follows the targets \"without identifying "
         "the particle\"", f"runs whose slots end as a permutation of the targets: products "
         f"{100 * perm['products']:.0f} %, powers {100 * perm['powers']:.0f} % (fixed by the labelling)",
         "yes" if max(perm.values()) > 0 else "not seen", max(perm.values()) > 0],
        ["track exchange at crossovers (Fig. 1, 2)", "\"may occur\"; the cause of the kinks",
         f"runs whose labelling changes after 1 s: products {100 * exch['products']:.0f} %, powers "
         f"{100 * exch['powers']:.0f} %", "yes" if max(exch.values()) > 0 else "not seen: slots keep their target "
         "through every crossing (the joint state carries the velocities), so the kinks are not label exchanges",
         max(exch.values()) > 0],
        ["EKF follows the truth", "\"tracks the positions very well\"",
         f"diverged runs (labelled final error > {DIVERGED_M:g} m): KF {100 * div['kf']:.0f} %, products "
         f"{100 * div['products']:.0f} %, powers {100 * div['powers']:.0f} % (most: {div_k}/{n}, Wilson 95 % "
         f"[{100 * div_lo:.0f}, {100 * div_hi:.0f}] %)", "yes" if max(div.values()) <= 0.05 else "partly",
         div_hi <= 0.05 or div_lo > 0.05],
        ["targets 2 and 3 similar", "\"similar results\" (not shown)", f"mean RMSE 1-20 s: {c['per_target']}",
         "see figure", True],
    ]
    return [r[:3] + [r[3] if r[3] == "see figure" else shown_verdict(r[3], quick=quick, supported=r[4], n=n)]
            for r in rows]


def _rmse_lines(mc: MonteCarlo, scn: st.LineTargets) -> list[str]:
    times = (0.5, 1.0, 4.4, 5.0, 10.0, 11.7, 15.0, 20.0)
    header = ["target", "filter"] + [f"t = {t:g} s" for t in times] + ["mean 1-20 s", "mean 0-20 s"]
    rows = []
    for i in range(scn.n_targets):
        for f in FILTERS:
            k = [int(round(t / scn.dt)) for t in times]
            rows.append([i + 1, NAMES[f]] + [_f(mc.rmse[f][j, i]) for j in k]
                        + [_f(window_mean(mc, f, i, 1.0, 20.0)), _f(window_mean(mc, f, i, 0.0, 20.0))])
    title = "## Our position RMSE [m] (the paper prints no numbers; its Fig. 2 shows target 1)"
    return [title, ""] + md_table(header, rows)


def _cov_lines(cov: list[dict]) -> list[str]:
    rows = [[r["n"], r["form"], _vec(r["x"], "()"), _f(r["sigma"]), f"{r['samples']:.0e}",
             f"{r['cov_z']:.2f}", f"{100 * r['cov_norm']:.3f}", f"{r['mean_z']:.2f}", f"{r['raw_z']:.2f}",
             f"{r['general']:.1e}"]
            for r in cov]
    head = ["N", "form", "positions x [m]", "sigma [m]", "samples", "max cov error [SE]",
            "max cov error [% of sqrt(R_aa R_bb)]", "max mean error [SE]", "raw noise variance error [SE]",
            "closed form vs general formula (rel.)"]
    ex = next(r for r in cov if r["n"] == 3 and r["form"] == "powers")
    detail = [[f"R[{a + 1},{b + 1}]", _f(ex["R"][a, b], 6), _f(ex["R_mc"][a, b], 6),
               f"{100 * (ex['R_mc'][a, b] / ex['R'][a, b] - 1):+.3f} %"] for a in range(3) for b in range(a, 3)]
    return (["## Transformed noise: analytic vs Monte Carlo (ours; the paper states agreement without numbers)", "",
             "Error of the sample covariance against the closed form (sensors/symmetric.py), in standard errors of "
             "the estimate (SE, from the sample spread of nu_a nu_b) and relative to the scale sqrt(R_aa R_bb); the "
             "same for the mean; then how far the sample variance of the raw position noise itself is from sigma^2, "
             "in its SE sqrt(2/n) (a large value there puts a large covariance error on the draws, not on the "
             "formula); the last column compares the closed forms with the general-N formulas the filter uses "
             "(trackers/sme.py).", ""] + md_table(head, rows)
            + [f"Entries at the paper's truth x = {_vec(ex['x'], '()')} m, sum of powers:", ""]
            + md_table(["entry", "analytic", "Monte Carlo", "difference"], detail))


def paired_order(row: dict) -> str:
    """The filters by mean RMSE, '<' where the paired t 95 % interval of the per-run RMS difference lies below 0
    (the same runs for every filter), '~' where it does not."""
    names = sorted(FILTERS, key=lambda f: row[f"rmse_{f}"])
    out = names[0]
    for a, b in zip(names, names[1:]):
        out += (" < " if paired_t(row[f"runs_{a}"], row[f"runs_{b}"]).below else " ~ ") + b
    return out


def _p0_lines(rows: list[dict], n_runs: int) -> list[str]:
    body = [[r["label"]] + [_f(r[f"rmse_{f}"]) for f in FILTERS] + [f"{100 * r[f'div_{f}']:.0f} %" for f in FILTERS]
            + [paired_order(r)] for r in rows]
    head = ["P0 (ours, all [D])", "KF", "products", "powers", "KF div.", "products div.", "powers div.",
            f"ordering (< : {PAIRED_T} of the per-run RMS below 0, ~ : not shown)"]
    return (["## Dependence on P0 (ours): target 1 mean RMSE 1-20 s [m] and diverged runs", "",
             f"{n_runs} runs each, the same runs for every row. The paper's P0 is unreadable, so its ordering claim "
             "is tested across readings. With equal position entries the EKF is permutation-equivariant: in exact "
             "arithmetic its slots would stay equal forever (the state x̂0 = 0 is symmetric); in floating point, "
             "rounding breaks the symmetry within a few scans and each run ends wherever that pushes it (so that row "
             "changes with the rounding, even with the batch layout).", ""] + md_table(head, body))


def _n2_lines(mc: MonteCarlo, scn: st.LineTargets) -> list[str]:
    rows = [[NAMES[f]] + [_f(window_mean(mc, f, i, 1.0, 20.0)) for i in range(2)]
            + [f"{kink(mc, f, 0, scn.crossing_times()[0][2])[0]:.2f}" if f != "kf" else "1",
               f"{100 * mc.diverged[f].mean():.0f} %"] for f in FILTERS]
    return (["## Two targets (ours; the paper derives N = 2 but simulates only N = 3)", "",
             f"x0 = {_vec(scn.x0)}, P0 = diag{_vec(scn.p0_diag, '()')} [D]; crossing at "
             f"{scn.crossing_times()[0][2]:.1f} s.", ""]
            + md_table(["filter", "target 1 mean RMSE 1-20 s [m]", "target 2", "peak RMSE ratio to KF near the crossing",
                      "diverged"], rows))


NOTES = [
    "## Notes: which numbers are whose",
    "",
    "- The paper prints no RMSE numbers: its claims are the qualitative statements in the first table, read off "
    "its Fig. 2 (target 1, 100 runs). Every number here is ours.",
    "- Reconstructed (the extracted text is garbled): the truth X0 = [3, 25, 120, 10, 5, 0] (the only digit "
    "reading in which all targets cross within 20 s; target 3 is then stationary although the text says all move "
    "left to right); the printed covariance matrices (our closed forms, checked above); the N = 3 sum of powers "
    "has a state-dependent noise mean E[nu] = [0, 3 sigma^2, 3 sigma^2 S_1], folded into h(x), although the "
    "paper calls the noise zero-mean.",
    "- [D] defaults: P0 (the ordering of the two forms is tested against it above), R evaluated at the "
    "prediction, labelling per step over positions and velocities, the divergence threshold "
    f"({DIVERGED_M:g} m).",
    "- To first order both forms carry the information of the labelled KF (H^T R^-1 H = I / sigma^2 wherever "
    "J is invertible); the EKFs lose to the KF through second-order noise terms and linearisation error, both "
    "largest where two positions meet and J is singular: the kinks.",
    "",
]


def run(out_dir: Path, *, quick: bool = False, seed: int = 0, progress: bool = True) -> Path:
    """Run the reproduction into `out_dir` (summary.md and PNGs); returns the summary's path."""
    import matplotlib

    matplotlib.use("Agg")
    from tqdm import tqdm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = settings(quick)
    scn3, scn2 = st.paper_scenario(3, s.steps), st.paper_scenario(2, s.steps)
    with tqdm(total=1 + 3 + 3 + 3, desc="seed-003", unit="stage", disable=not progress) as bar:
        cov = covariance_rows(s.cov_samples, seed)
        bar.update(1)
        mc3 = monte_carlo(scn3, s.runs, seed, bar=bar)
        p0 = p0_rows(scn3, s.p0_runs, seed, bar=bar)
        mc2 = monte_carlo(scn2, s.runs, seed, bar=bar)
    run0 = example_run(mc3)
    figure_single_run(out / "fig1_single_run.png", scn3, mc3, run0)
    figure_rmse(out / "fig2_rmse_target1.png", scn3, mc3, (0,), s.runs)
    figure_rmse(out / "rmse_all_targets.png", scn3, mc3, tuple(range(scn3.n_targets)), s.runs)
    figure_rmse(out / "rmse_two_targets.png", scn2, mc2, (0, 1), s.runs)
    md = ["# Reproduction of paper 003: symmetric measurement equations with an EKF", "",
          (f"**Quick run** (reduced: {s.runs} runs, {s.cov_samples:.0e} noise samples; the full report is in "
           "docs/results/reproduce/seed-003/). A verdict that this run's own intervals, tests or observed events do "
           "not carry reads \"indicative (n runs): not a verdict\"." if quick else "Full run."),
          f"Regenerate with `testbed reproduce seed-003{' --quick' if quick else ''} --seed {seed}`.", ""]
    md += _setup_lines(scn3, s, seed, quick)
    md += ["## The paper's claims and ours", "",
           f"Three targets, {s.runs} runs, P0 = default [D]. \"Paper\" is what paper 003 states; \"ours\" is measured "
           "here.", ""]
    md += md_table(["claim", "paper 003 (stated)", "ours (measured)", "holds?"], _claim_rows(mc3, cov, scn3, quick))
    md += _rmse_lines(mc3, scn3) + _cov_lines(cov) + _p0_lines(p0, s.p0_runs) + _n2_lines(mc2, scn2)
    md += ["## Figures", "",
           f"- `fig1_single_run.png`: truth (dashed) and the unlabelled EKF slots of run {run0}, the first run whose "
           "sum-of-powers slots end permuted if any (the paper's Fig. 1: the sum of powers, \"without identifying the "
           "particle\"); crossing times marked.",
           "- `fig2_rmse_target1.png`: target 1's position RMSE, KF vs both EKFs (the paper's Fig. 2); target 1's "
           "crossings dashed, the others dotted.",
           "- `rmse_all_targets.png`: the same for every target (the paper: \"similar\", not shown).",
           "- `rmse_two_targets.png`: N = 2 (ours).", ""]
    md += NOTES
    path = out / "summary.md"
    write_text(path, "\n".join(md))
    return path
