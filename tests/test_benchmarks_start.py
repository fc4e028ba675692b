"""Every benchmark starts as documented (``.venv/bin/python benchmarks/bench_X.py``): run as a script, its folder
is sys.path[0], and no benchmark's name may shadow a package (benchmarks/trackers.py once shadowed `trackers`)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((REPO / "benchmarks").glob("*.py"))


def test_benchmark_names_cannot_shadow_a_package():
    assert SCRIPTS and all(p.name.startswith("bench_") for p in SCRIPTS), [p.name for p in SCRIPTS]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_each_benchmark_starts_and_shows_its_usage(script):
    proc = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=300,
                          cwd=REPO / "benchmarks")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.lstrip().startswith("usage:"), proc.stdout[:500]
