"""``testbed reproduce NAME``: regenerate a paper's figures and numbers (PNG + markdown, ours beside the paper's).

Each reproduction is a module of this package with one entry point::

    run(out_dir: Path, *, quick: bool = False, seed: int = 0, progress: bool = True) -> Path

which writes ``out_dir/summary.md`` and its PNG figures and returns the summary's path. ``quick`` is the
reduced run (fewer Monte Carlo runs and steps; for CI and a first look), ``progress`` shows tqdm bars.
The full reports are committed in ``docs/results/reproduce/<NAME>/``.

Methods run on the same draws are compared by paired statistics (testbed/common/stats.py: McNemar for lost runs,
paired t or paired bootstrap intervals for differences of errors), and every comparison table names its test. A
quick run states a verdict only where its own intervals or tests carry it (with its n); otherwise it prints
"indicative (n runs): not a verdict" (testbed/reproduce/markdown.py: ``verdict``).

Quick forms, wall time of ``time testbed reproduce NAME --quick`` (Python start included; measured on the shared
2-core machine; thesis-highway on one core, ``taskset -c 0``):

    seed-000 8 s; seed-001 14 s; seed-002 5 s; seed-003 9 s; seed-000-highway 12 s; seed-002-highway 17 s;
    thesis-highway 33 s; thesis-2.1 21-24 s (28 s with four variants before); thesis-4.6.1 47 s; thesis-5.1 43-45 s
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable

# name -> (module, one-line description); modules are imported on use.
REPRODUCTIONS: dict[str, tuple[str, str]] = {
    "seed-000": ("roadtrack.testbed.reproduce.seed000.points", "paper 000: one car in a convoy with mixed measurements; gating, "
                 "PDAF and the windowed KS integral test"),
    "seed-002": ("roadtrack.testbed.reproduce.seed002.study", "paper 002 (Powers & Pao): track-loss detection by KS tests on "
                 "gated-measurement counts"),
    "seed-000-highway": ("roadtrack.testbed.reproduce.seed000.highway", "paper 000 on the highway: one car of a close "
                         "LiDAR-seen convoy (gaps 0.25-4 m, full and thesis pipelines); mixing fraction, gating and "
                         "the KS integral test"),
    "seed-002-highway": ("roadtrack.testbed.reproduce.seed002.highway", "paper 002's KS track regime detector on the highway: "
                         "delay after a forced loss and a sensor dropout, false alarms while tracking, per tracker, "
                         "against the track score's deletion"),
    "thesis-highway": ("roadtrack.testbed.reproduce.thesis.highway", "thesis Tables 4.3 and 5.4 on highway_benchmark: every "
                       "named tracker, 5 seeds, full and thesis pipelines, intervals and paired differences"),
    "thesis-2.1": ("roadtrack.testbed.reproduce.thesis.sec21", "thesis §2.1.6: PDA-SVSF against PDA-KF under model error, one "
                   "target; both PDA-SVSF forms, two loss criteria, sensitivity to the open choices"),
    "thesis-4.6.1": ("roadtrack.testbed.reproduce.thesis.sec461", "thesis §4.6.1 (Tables 4.1-4.2): JPDA-GVBL-SVSF against JPDA-KF, "
                     "three manoeuvring cars in clutter"),
    "thesis-5.1": ("roadtrack.testbed.reproduce.thesis.sec51", "thesis §5.6.1 (Table 5.1): APDA-SVSF, PDA-SVSF and PDA-KF on a "
                   "highly manoeuvring target in dense clutter"),
    "seed-001": ("roadtrack.testbed.reproduce.seed001.study", "paper 001: PDA against the all-neighbours weights linear in "
                 "distance; one target, two crossing and two parallel targets, loss against separation"),
    "seed-003": ("roadtrack.testbed.reproduce.seed003.study", "paper 003: symmetric measurement equations (sum of powers, sum of "
                 "products) with an EKF, 2 and 3 targets"),
}


def entry(name: str) -> Callable[..., Path]:
    """The ``run`` function of reproduction ``name`` (KeyError naming the known ones if unknown)."""
    if name not in REPRODUCTIONS:
        raise KeyError(f"unknown reproduction {name!r}; known: {', '.join(REPRODUCTIONS)}")
    return importlib.import_module(REPRODUCTIONS[name][0]).run
