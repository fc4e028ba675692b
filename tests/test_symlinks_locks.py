"""Planted symbolic links and concurrent writers (issue 16): no file the tool writes in a run, campaign or
perception folder is written through a symbolic link (locks, temporaries, final outputs, the recording):
each is refused in one line naming the link, exit 2 (1 once the run's work is done), and the link's target
is left as it was; a run folder is locked while a command writes it, so a second `testbed run` (or
`testbed perception`) into it is refused in one line naming the first one's pid, before any work."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from roadtrack.testbed.pipeline import outdir
from roadtrack.testbed.common import safe_io
from roadtrack.testbed.campaign import store
from roadtrack.testbed.cli.main import main
from roadtrack.testbed.config.strict import ConfigError

REPO = Path(__file__).resolve().parent.parent
FAST = ["--set", "sensor.lidar.azimuth_step_deg=1.0", "--quiet"]  # 11,520 rays per scan instead of 72,000
VICTIM_TEXT = "the victim's own content\n"
CAMPAIGN = """\
name = "links"
scenarios = ["cut_in_out"]
trackers = ["gnn-kf"]
seeds = 2

[overrides]
duration_s = 0.3
"sensor.lidar.azimuth_step_deg" = 1.0

[record]
full_seeds = [0]
"""
RECORDED, UNRECORDED = "cut_in_out--gnn-kf--s000", "cut_in_out--gnn-kf--s001"


def _cli(capsys, *args: str) -> tuple[int, str, list[str]]:
    """(exit code, stdout, stderr lines) of ``testbed ARGS`` run in this process."""
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _run(out: Path, duration: float = 0.3) -> list[str]:
    return ["run", "cut_in_out", "--set", f"duration_s={duration}", *FAST, "--no-record", "--out", str(out)]


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM_TEXT)
    return victim


def _plant(link: Path, target: str) -> None:
    if link.is_symlink() or link.is_file():
        link.unlink()
    link.symlink_to(target)


def _refused(code: int, err: list[str], link: str, target: str, exit_code: int = 2) -> str:
    """The one error line, checked: exit code, one line, naming the link and its target."""
    assert code == exit_code and len(err) == 1 and err[0].startswith("error: "), (code, err)
    assert f"{link} is a symbolic link (to {target}); refusing to write through it" in err[0], err
    assert "Traceback" not in err[0]
    return err[0]


@pytest.fixture
def no_simulation(monkeypatch):
    import roadtrack.testbed.pipeline.run
    from roadtrack import testbed

    def never(*args, **kwargs):
        raise AssertionError("a simulation ran")

    monkeypatch.setattr(testbed.pipeline.run, "run_scenario", never)


# --- run folders ----------------------------------------------------------------------------------------------

def test_out_that_is_a_link_is_refused_and_its_target_kept(capsys, tmp_path, no_simulation):
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "scores.json").write_text(VICTIM_TEXT)  # looks like an earlier run's folder
    link = tmp_path / "r"
    link.symlink_to(target)
    code, _, err = _cli(capsys, *_run(link))
    assert _refused(code, err, str(link), str(target)).startswith("error: --out: ")
    assert link.is_symlink() and [p.name for p in target.iterdir()] == ["scores.json"]
    assert (target / "scores.json").read_text() == VICTIM_TEXT
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "r"]


def test_a_link_in_an_earlier_runs_folder_is_refused(capsys, tmp_path, no_simulation):
    victim = _victim(tmp_path)
    out = tmp_path / "r"
    out.mkdir()
    (out / "truth.parquet").write_bytes(b"an earlier run's table")
    (out / "scores.json").symlink_to(victim)
    code, _, err = _cli(capsys, *_run(out))
    _refused(code, err, f"{out}/scores.json", str(victim))
    assert victim.read_text() == VICTIM_TEXT and (out / "scores.json").is_symlink()
    assert sorted(p.name for p in out.iterdir()) == ["scores.json", "truth.parquet"]


@pytest.mark.parametrize("name", [".r.lock", ".r.partial-{pid}", ".r.old-{pid}"])  # {pid}: this process's, at run
def test_a_link_at_the_lock_or_staged_folder_name_is_refused(capsys, tmp_path, no_simulation, name):
    name = name.format(pid=os.getpid())  # (not in the test's id: pytest-xdist's workers must collect the same ids)
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text(VICTIM_TEXT)
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / name).symlink_to(victim)
    code, _, err = _cli(capsys, *_run(runs / "r"))
    assert _refused(code, err, str(runs / name), str(victim)).startswith("error: --out: ")
    assert [p.name for p in victim.iterdir()] == ["keep.txt"] and (victim / "keep.txt").read_text() == VICTIM_TEXT
    assert sorted(p.name for p in runs.iterdir()) == [name]  # the link is left, nothing else written


def test_a_link_planted_at_incomplete_during_a_run_is_left_alone(capsys, tmp_path, monkeypatch):
    import roadtrack.testbed.pipeline.run
    from roadtrack import testbed

    victim = _victim(tmp_path)
    out = tmp_path / "r"

    def planting(scn, out_dir, **kwargs):
        Path(out_dir, "truth.parquet").write_bytes(b"frames before the failure")
        Path(out_dir, outdir.INCOMPLETE).symlink_to(victim)
        raise RuntimeError("boom")

    monkeypatch.setattr(testbed.pipeline.run, "run_scenario", planting)
    code, _, err = _cli(capsys, *_run(out))
    stage = tmp_path / f".r.partial-{os.getpid()}"
    line = _refused(code, err, str(stage / outdir.INCOMPLETE), str(victim), exit_code=1)
    assert line.startswith("error: RuntimeError: boom") and f"what was written is kept in {stage}/" in line
    assert victim.read_text() == VICTIM_TEXT
    assert not out.exists() and sorted(p.name for p in stage.iterdir()) == ["INCOMPLETE", "truth.parquet"]
    assert not (tmp_path / ".r.lock").exists()


def test_write_atomic_refuses_a_link_at_its_temporary_and_final_name(tmp_path):
    victim = _victim(tmp_path)
    target = tmp_path / "scores.json"
    tmp = safe_io.temp_name(target)
    for link in (tmp, target):
        link.symlink_to(victim)
        for write in (lambda p: outdir.write_atomic(p, lambda t: t.write_text("new")),
                      lambda p: store.atomic_write_bytes(p, b"new")):
            with pytest.raises(ConfigError, match=re.escape(f"{link} is a symbolic link (to {victim}); refusing")):
                write(target)
            assert victim.read_text() == VICTIM_TEXT and link.is_symlink()
        link.unlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["victim.txt"]


def test_the_recording_is_never_written_through_a_link(tmp_path):
    from roadtrack.testbed.recording.recorder import Recorder

    victim = _victim(tmp_path)
    (tmp_path / "run.rrd").symlink_to(victim)
    with pytest.raises(ConfigError, match="run.rrd is a symbolic link"):
        Recorder(tmp_path / "run.rrd", "links")
    assert victim.read_text() == VICTIM_TEXT


def test_write_settings_never_follows_a_link(tmp_path):
    from roadtrack.testbed.perception.report import write_settings
    from roadtrack.testbed.scenario.spec import SCENARIO_DIR, read_toml

    data = read_toml(SCENARIO_DIR / "cut_in_out.toml")
    earlier = tmp_path / "earlier.toml"
    write_settings(data, {"seed": 3}, earlier, source="cut_in_out")  # a file the command may replace
    before = earlier.read_text()
    link = tmp_path / "measured.toml"
    link.symlink_to(earlier)
    with pytest.raises(ConfigError, match=f"{link} is a symbolic link"):
        write_settings(data, {"seed": 4}, link, source="cut_in_out")
    assert earlier.read_text() == before and link.is_symlink()


# --- campaign folders -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A complete two-run campaign folder, run 0 recorded (real runs, in this process)."""
    tmp = tmp_path_factory.mktemp("links")
    (tmp / "links.toml").write_text(CAMPAIGN)
    out = tmp / "done"
    assert main(["campaign", "run", str(tmp / "links.toml"), "--out", str(out), "--workers", "0", "--quiet"]) == 0
    assert (out / store.RECORDINGS_DIR / RECORDED / "run.rrd").is_file()
    return out


@pytest.fixture
def folder(finished, tmp_path) -> Path:
    return Path(shutil.copytree(finished, tmp_path / "c"))


@pytest.mark.parametrize("name, redo", [
    (store.LOCK_FILE, None),
    (store.RESULTS_FILE, None),
    (f"{store.RUNS_DIR}/{UNRECORDED}.parquet", None),
    (f"{store.RUNS_DIR}/.{UNRECORDED}.parquet.tmp-{{pid}}", UNRECORDED),  # the temporary of a run to redo
    (f"{store.RECORDINGS_DIR}/{RECORDED}/run.rrd", RECORDED),  # rerun would truncate it
    (f"{store.RECORDINGS_DIR}/{RECORDED}/scores.json", RECORDED),
])
def test_resume_refuses_a_link_in_the_campaign_folder(capsys, folder, tmp_path, name, redo):
    name = name.format(pid=os.getpid())  # {pid}: this process's (not in the id, which every xdist worker must share)
    victim = _victim(tmp_path)
    if redo:  # a run to do again: its run file gone
        store.run_path(folder, redo).unlink()
    _plant(folder / name, "../" * name.count("/") + "../victim.txt")
    code, _, err = _cli(capsys, "campaign", "resume", str(folder), "--workers", "0", "--quiet")
    _refused(code, err, str(folder / name), "../" * name.count("/") + "../victim.txt")
    assert victim.read_text() == VICTIM_TEXT and (folder / name).is_symlink()


@pytest.mark.parametrize("name", ["report.md", "summary.csv", f"{store.PLOTS_DIR}/rmse_vs_time.png"])
def test_report_refuses_a_link_in_the_campaign_folder(capsys, folder, tmp_path, name):
    victim = _victim(tmp_path)
    (folder / store.PLOTS_DIR).mkdir()
    target = "../" * name.count("/") + "../victim.txt"
    _plant(folder / name, target)
    code, _, err = _cli(capsys, "campaign", "report", str(folder))
    _refused(code, err, str(folder / name), target)
    assert victim.read_text() == VICTIM_TEXT and (folder / name).is_symlink()


def test_report_refuses_a_plots_folder_that_is_a_link(capsys, folder, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (folder / store.PLOTS_DIR).symlink_to(elsewhere)
    code, _, err = _cli(capsys, "campaign", "report", str(folder))
    _refused(code, err, str(folder / store.PLOTS_DIR), str(elsewhere))
    assert list(elsewhere.iterdir()) == []


def test_campaign_out_that_is_a_link_is_refused(capsys, tmp_path):
    (tmp_path / "links.toml").write_text(CAMPAIGN)
    target = tmp_path / "elsewhere"
    target.mkdir()
    (tmp_path / "c").symlink_to(target)
    code, _, err = _cli(capsys, "campaign", "run", str(tmp_path / "links.toml"), "--out", str(tmp_path / "c"),
                        "--workers", "0", "--quiet")
    _refused(code, err, str(tmp_path / "c"), str(target))
    assert list(target.iterdir()) == []


# --- the run-folder lock --------------------------------------------------------------------------------------

def _wait_for_pid(path: Path, pid: int, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        with_pid = path.is_file() and path.read_text().strip() == str(pid)
        if with_pid:
            return
        time.sleep(0.05)
    raise AssertionError(f"{path} never held pid {pid} (exit {proc.poll()})")


def test_a_second_run_into_a_folder_being_written_is_refused(capsys, tmp_path):
    out = tmp_path / "r"
    first = subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli.main", *_run(out, duration=6.0)], cwd=REPO,
                             env=dict(os.environ, PYTHONPATH=str(REPO), RERUN_ANALYTICS="0"),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_pid(tmp_path / ".r.lock", first.pid, first)
        refusal = (f"error: --out: {out} is being written by another testbed process (pid {first.pid}); wait for "
                   "it to end or choose another --out")
        code, _, err = _cli(capsys, *_run(out))
        assert code == 2 and err == [refusal]
        code, _, err = _cli(capsys, "perception", "cut_in_out", "--duration", "0.3", "--no-ablation",
                            "--no-merge-sweep", "--quiet", "--out", str(out))
        assert code == 2 and err == [refusal]
        assert first.poll() is None  # refused while the first one ran
        stdout, stderr = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == 0, stderr
    assert f"wrote scores.json, truth.parquet" in stdout and (out / "scores.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]  # the lock file went with its holder


def test_a_killed_writer_leaves_no_stale_lock(tmp_path):
    code = ("import sys, time\nfrom roadtrack.testbed.pipeline.outdir import Staging\nstage = Staging(sys.argv[1])\n"
            "print('locked', flush=True)\ntime.sleep(60)\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "r")], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline() == "locked\n"
        with pytest.raises(ConfigError, match=f"being written by another testbed process \\(pid {holder.pid}\\)"):
            outdir.Staging(tmp_path / "r")
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
    assert (tmp_path / ".r.lock").read_text() == f"{holder.pid}\n"  # left by the killed process, unlocked
    stage = outdir.Staging(tmp_path / "r")  # the kernel released its lock
    assert (tmp_path / ".r.lock").read_text() == f"{os.getpid()}\n"
    stage.discard()
    assert list(tmp_path.iterdir()) == []  # the killed one's partial folder and lock file are gone too
