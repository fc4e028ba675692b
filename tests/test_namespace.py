"""One installed name, roadtrack (issue 31.1): PyPI's `trackers` (Roboflow's multi-object tracking, 2.6.1, in the
test extra of pyproject.toml) and roadtrack live in one environment, and even in one process.

Every check runs in a subprocess started in a temporary folder with no PYTHONPATH: from the repository root, the
checkout's own trackers/ folder would be on sys.path (``python -m pytest`` puts the working directory there) and
would hide PyPI's package; an installed user never has it there.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PYPI_TRACKERS = "2.6.1"


def _env() -> dict[str, str]:
    return {**{k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, "RERUN_ANALYTICS": "0"}


@pytest.fixture(scope="module")
def pypi_trackers() -> str:
    try:
        version = metadata.version("trackers")
    except metadata.PackageNotFoundError:
        pytest.fail(f"PyPI's trackers=={PYPI_TRACKERS} is not installed: it is in the test extra (bin/setup installs it)")
    assert version == PYPI_TRACKERS, version
    return version


def test_import_trackers_is_pypis_and_roadtrack_trackers_is_ours_in_one_process(pypi_trackers, tmp_path):
    code = ("import json, trackers, roadtrack.trackers as ours\n"
            "print(json.dumps(dict(theirs=trackers.__file__, sort=hasattr(trackers, 'SORTTracker'),\n"
            "    ours=ours.__file__, name=ours.__name__, make=hasattr(ours, 'make_tracker'),\n"
            "    ours_sort=hasattr(ours, 'SORTTracker'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=_env(),
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.splitlines()[-1])
    theirs = Path(got["theirs"])
    assert theirs.parts[-3:] == ("site-packages", "trackers", "__init__.py")  # installed: not our trackers/ folder
    assert theirs != REPO / "trackers" / "__init__.py"  # (bin/setup's .venv may lie inside the checkout)
    assert theirs == Path(metadata.distribution("trackers").locate_file("trackers/__init__.py"))
    assert got["sort"] and not got["ours_sort"]  # their SORT tracker class; ours has none
    assert Path(got["ours"]) == REPO / "trackers" / "__init__.py" and got["name"] == "roadtrack.trackers"
    assert got["make"]


def test_a_smoke_run_works_beside_pypis_trackers(pypi_trackers, tmp_path):
    """The `testbed` script of this environment, with PyPI's trackers installed: a 2 s run of cut_in_out with
    nn-kf, from outside the checkout; then the same run in a process that imported PyPI's trackers first."""
    testbed = Path(sys.executable).parent / "testbed"
    args = ["run", "cut_in_out", "--set", "duration_s=2", "--tracker", "nn-kf", "--no-record", "--no-plot",
            "--quiet", "--out"]
    run = subprocess.run([str(testbed), *args, str(tmp_path / "a")], capture_output=True, text=True, cwd=tmp_path,
                         env=_env(), timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    scores = json.loads((tmp_path / "a" / "scores.json").read_text())
    assert scores["tracker"] == "nn-kf" and scores["scores"]["cars_seen"] == 3, scores["scores"]
    assert scores["scores"]["cars_tracked"] >= 1, scores["scores"]
    code = ("import sys, trackers\nfrom roadtrack.testbed.cli.main import main\n"
            f"code = main({[*args, str(tmp_path / 'b')]!r})\n"
            "print(code, sys.modules['trackers'] is trackers, hasattr(trackers, 'SORTTracker'))")
    both = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=_env(),
                          timeout=900)
    assert both.returncode == 0 and both.stdout.split()[-3:] == ["0", "True", "True"], both.stderr[-2000:]
    again = json.loads((tmp_path / "b" / "scores.json").read_text())
    assert again["scores"] == scores["scores"]  # the same seeded run: PyPI's package changed nothing
