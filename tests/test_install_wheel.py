"""A plain install (issue 31.6): roadtrack's wheel, installed into a fresh venv and run from outside the checkout,
finds its shipped scenarios and campaigns by name, runs one, and says in one line that its first run compiles
the numba kernels; ``testbed warmup`` compiles them ahead (ROADTRACK_FULL=1, about two minutes).

How, offline and in well under a minute (the reduced version):
* the wheel is built by ``pip wheel --no-deps --no-build-isolation --no-index`` from a copy of the packaging
  inputs (pyproject.toml, README.md, the three packages and the two data folders, links kept), so the checkout
  gets no build/ folder and no stale build output can slip in;
* the fresh venv (``python -m venv --without-pip``) gets the wheel by this environment's pip (``pip --python``,
  ``--no-deps --no-index``); the dependencies (numpy, open3d, highway-env, ... about 1.5 GB, minutes to
  download) are not installed again: a ``.pth`` file appends this environment's site-packages to the new venv's
  ``sys.path``, after its own site-packages. A ``.pth`` line only adds a folder: the ``.pth`` files in that folder,
  such as an editable install's finder of this checkout, are not run. The test checks that ``roadtrack.testbed``,
  ``roadtrack.sensors`` and ``roadtrack.trackers`` are imported from the new venv's site-packages, and runs every
  command with no PYTHONPATH, from a folder outside the checkout, through the venv's own ``testbed`` script;
* the wheel puts nothing at the top level of site-packages but ``roadtrack/`` and its ``.dist-info`` (issue 31.1:
  PyPI's ``trackers`` is another project's top-level package);
* the run is short (0.5 s of cut_in_out with the thesis pipeline, whose kernels compile in about 20 s of CPU;
  the full stack's take about 40 s, in the slow test).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FULL = bool(os.environ.get("ROADTRACK_FULL"))
TOPS = ("testbed", "sensors", "trackers")
"""The repository's package folders; installed as roadtrack.testbed, roadtrack.sensors, roadtrack.trackers."""
PACKAGING = ("pyproject.toml", "README.md", *TOPS, "scenarios", "campaigns")
NOTE = "note: compiling the sensors' numba kernels"
SHORT = ["--set", "duration_s=0.5", "--set", "sensor.pipeline=thesis", "--no-record", "--no-plot", "--quiet"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    source = tmp_path_factory.mktemp("source") / "roadtrack"
    source.mkdir()
    for name in PACKAGING:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, source / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))
        else:
            shutil.copy2(src, source / name)
    dist = tmp_path_factory.mktemp("dist")
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                          "--no-index", "-w", str(dist), str(source)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    (found,) = dist.glob("roadtrack-*.whl")
    return found


def _install(wheel: Path, folder: Path) -> Path:
    """A fresh venv in ``folder`` with the wheel installed (no dependencies) and this environment's site-packages
    appended to its sys.path; returns the venv's bin folder."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True, timeout=120)
    python = folder / "bin" / "python"
    out = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                          "--no-index", str(wheel)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                          capture_output=True, text=True, check=True, timeout=60).stdout.strip()
    # this environment's site-packages, and those it sees through a .pth of its own (an environment layered on another)
    deps = dict.fromkeys([sysconfig.get_path("purelib"), sysconfig.get_path("platlib"),
                          *(p for p in sys.path if Path(p).name == "site-packages")])
    (Path(site) / "roadtrack_test_deps.pth").write_text("".join(f"{p}\n" for p in deps))
    return folder / "bin"


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory) -> Path:
    return _install(wheel, tmp_path_factory.mktemp("venv") / "v")


def _env() -> dict[str, str]:
    drop = ("PYTHONPATH", "NUMBA_CACHE_DIR", "PYTHONHOME")
    return {**{k: v for k, v in os.environ.items() if k not in drop}, "RERUN_ANALYTICS": "0"}


def _testbed(bin_dir: Path, *args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([str(bin_dir / "testbed"), *args], capture_output=True, text=True, cwd=cwd, env=_env(),
                          timeout=timeout)


def _names(folder: Path) -> list[str]:
    return sorted(p.stem for p in folder.glob("*.toml"))


def test_the_wheel_carries_every_shipped_scenario_and_campaign(wheel):
    with zipfile.ZipFile(wheel) as z:
        for kind in ("scenarios", "campaigns"):
            prefix = f"roadtrack/testbed/_shipped/{kind}/"
            inside = sorted(n[len(prefix):-5] for n in z.namelist() if n.startswith(prefix) and n.endswith(".toml"))
            assert inside == _names(REPO / kind) and len(inside) >= 5, kind
            for name in inside:  # the files themselves, not links
                assert z.read(f"{prefix}{name}.toml") == (REPO / kind / f"{name}.toml").read_bytes(), name


def test_the_wheel_carries_every_file_of_the_packages(wheel):
    """Every file of testbed/, sensors/ and trackers/ (through the _shipped links; the HTML replay's template, ...)
    is in the wheel under roadtrack/: a data file left out of pyproject.toml's package-data, or a sub-package left
    out of its package list, fails here, not after an install."""
    ours = set()
    for top in TOPS:
        for folder, dirs, files in os.walk(REPO / top, followlinks=True):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            rel = Path("roadtrack") / Path(folder).relative_to(REPO)
            ours |= {(rel / f).as_posix() for f in files if not f.endswith((".pyc", ".nbi", ".nbc"))}
    with zipfile.ZipFile(wheel) as z:
        missing = sorted(ours - set(z.namelist()))
    assert not missing and len(ours) > 100, missing


def test_the_wheel_installs_one_top_level_name_roadtrack(wheel):
    """Nothing of ours at the top level of site-packages (issue 31.1): roadtrack/ (no __init__.py: an implicit
    namespace package) holding testbed/, sensors/ and trackers/, and the .dist-info folder."""
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"roadtrack", f"{wheel.name.split('-')[0]}-{wheel.name.split('-')[1]}.dist-info"}, tops
    assert {n.split("/")[1] for n in names if n.startswith("roadtrack/")} == set(TOPS)
    assert "roadtrack/__init__.py" not in names and not [n for n in names if n.split("/")[0] in TOPS]


def test_the_installed_package_is_what_runs(venv, tmp_path):
    code = ("from roadtrack import testbed, sensors, trackers; import importlib.util as u, sys\n"
            "print(*(m.__file__ for m in (testbed, sensors, trackers)), sep='\\n')\n"
            "print(*(u.find_spec(t) for t in ('testbed', 'sensors')), file=sys.stderr)")
    out = subprocess.run([str(venv / "python"), "-c", code], capture_output=True, text=True, cwd=tmp_path,
                         env=_env(), timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stderr.split() == ["None", "None"]  # no top-level testbed or sensors anywhere on sys.path
    site = venv.parent / "lib"
    paths = out.stdout.split()
    assert [Path(p).parent.name for p in paths] == list(TOPS) and len(paths) == 3, paths
    for path in paths:
        assert Path(path).is_relative_to(site) and not Path(path).is_relative_to(REPO), path
        assert Path(path).parent.parent.name == "roadtrack", path


def test_testbed_scenarios_lists_the_shipped_ones_and_campaigns_are_found_by_name(venv, tmp_path):
    listed = _testbed(venv, "scenarios", cwd=tmp_path)
    assert listed.returncode == 0 and listed.stderr == "", listed.stderr
    assert [line.split()[0] for line in listed.stdout.splitlines()] == _names(REPO / "scenarios")
    assert "INVALID" not in listed.stdout
    check = _testbed(venv, "check", "smoke", cwd=tmp_path)
    assert check.returncode == 0 and check.stdout.startswith("smoke: campaign 'smoke' OK: 8 runs"), check.stderr
    missing = _testbed(venv, "run", "nowhere", cwd=tmp_path)
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1
    assert missing.stderr.startswith("error: nowhere: no such scenario file (shipped: convoy, cut_in_out,")


def test_a_shipped_scenario_runs_by_name_and_the_first_run_notes_the_compilation(venv, tmp_path):
    first = _testbed(venv, "run", "cut_in_out", *SHORT, "--out", str(tmp_path / "a"), cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    assert [line for line in first.stderr.splitlines() if line.startswith(NOTE)] == [
        line for line in first.stderr.splitlines() if "numba" in line] and first.stderr.count(NOTE) == 1
    scores = json.loads((tmp_path / "a" / "scores.json").read_text())
    assert scores["scenario"] == "cut_in_out" and scores["scores"]["cars_seen"] == 3, scores
    cache = next((venv.parent / "lib").glob("python3*/site-packages/roadtrack/sensors/__pycache__"))
    assert list(cache.glob("raycast.*.nbi")) and list(cache.glob("perception_jit.*.nbi"))  # numba's cache, writable
    again = _testbed(venv, "run", "cut_in_out", *SHORT, "--out", str(tmp_path / "b"), cwd=tmp_path)
    assert again.returncode == 0 and NOTE not in again.stderr, again.stderr[-2000:]
    assert json.loads((tmp_path / "b" / "scores.json").read_text())["scores"] == scores["scores"]


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="compiles every kernel in a fresh install (about two minutes): ROADTRACK_FULL=1")
def test_testbed_warmup_in_a_fresh_install_leaves_nothing_to_compile(wheel, tmp_path):
    venv = _install(wheel, tmp_path / "v")
    warm = _testbed(venv, "warmup", cwd=tmp_path, timeout=1200)
    assert warm.returncode == 0, warm.stderr[-2000:]
    summary = warm.stdout.splitlines()[-1]
    assert summary.startswith("warm-up: ") and "numba kernels cached" in summary and NOTE not in warm.stderr
    n, compiled = summary.split()[1], summary.split("(")[1].split()[0]
    assert int(n) >= 10 and compiled == n, summary  # everything compiled now, in the fresh install
    assert str(venv.parent / "lib") in summary  # the cache is the installed package's __pycache__
    run = _testbed(venv, "run", "cut_in_out", "--set", "duration_s=2", "--no-record", "--no-plot", "--quiet",
                   "--out", str(tmp_path / "r"), cwd=tmp_path)
    assert run.returncode == 0 and NOTE not in run.stderr, run.stderr[-2000:]
    ms = float(run.stdout.split(" ms/frame")[0].split()[-1])
    assert ms < 1000, run.stdout  # steady state (compiling inside the run: 1547 ms/frame over a whole run)
