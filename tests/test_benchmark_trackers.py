"""benchmarks/bench_trackers.py --quick: correctness only (our JPDA marginals equal Stone Soup 1.9.1's to 1e-9, the
event count equals brute force, the script runs and prints its ratios). Timings are never asserted."""
from __future__ import annotations

import importlib.util
import itertools
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stonesoup")

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_trackers.py"
TOL = 1e-9


@pytest.fixture(scope="module")
def bench():
    """The benchmark as a module named `benchmark_trackers` (its file name would shadow the `trackers` package)."""
    spec = importlib.util.spec_from_file_location("benchmark_trackers", PATH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["benchmark_trackers"] = mod
    spec.loader.exec_module(mod)
    yield mod
    sys.modules.pop("benchmark_trackers", None)


def brute_force_events(gated: np.ndarray) -> int:
    """Joint events by listing every source (clutter or a track) of every measurement."""
    T, M = gated.shape
    n = 0
    for src in itertools.product(range(-1, T), repeat=M):
        used = [t for t in src if t >= 0]
        if len(used) == len(set(used)) and all(t < 0 or gated[t, j] for j, t in enumerate(src)):
            n += 1
    return n


def test_event_count_equals_brute_force(bench):
    rng = np.random.default_rng(3)
    for _ in range(30):
        T, M = rng.integers(1, 5), rng.integers(0, 6)
        gated = rng.random((T, M)) < 0.5
        assert bench.count_events(gated) == brute_force_events(gated)  # exact integers


def test_quick_run_agrees_and_prints_ratios(bench, capsys):
    results, trackers, agree = bench.run(quick=True, budget_s=0.0, tracker_names=["jpda-kf"], scans=3)
    out = capsys.readouterr().out
    assert agree
    assert [(r.T, r.M) for r in results] == [(10, 20), (6, 9), (8, 12), (11, 17)]
    assert all(r.gates_equal and r.worst <= TOL for r in results), [r.diff for r in results]
    for r in results[:2]:  # scene and 6 x 9: checked against Stone Soup's plain JPDA, not only its EHM
        assert {f"{m} vs JPDA" for m in bench.jpda_methods()} <= set(r.diff) and "JPDA" in r.ss_scan
    big = results[-1]
    assert big.clusters == 1 and big.events > 10_000  # one genuine 11 x 17 cluster
    ratios = re.findall(r"\b\d+(?:\.\d)?x(?=\s|$)", out, flags=re.M)  # "346x", "1.4x"; not "10x20"
    assert len(ratios) >= 2 * 2 * len(results)  # vs EHM and EHM2 at least, scan and association levels
    assert "marginal probabilities equal Stone Soup's" in out
    assert [t.name.split(" ")[0] for t in trackers] == ["jpda-kf"] * len(trackers)
    assert all(not t.error and t.covered >= 0.9 for t in trackers), [t.error for t in trackers]


def test_script_imports_the_trackers_package_not_itself():
    """Run as a script, benchmarks/ is sys.path[0] and benchmarks/bench_trackers.py would shadow `trackers`."""
    proc = subprocess.run([sys.executable, str(PATH), "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "--quick" in proc.stdout
