"""Hardening of the `testbed` command line (issue 9): one-line errors and exit codes, output folders that are
replaced whole or marked INCOMPLETE, Ctrl-C and full disks that keep what was done, a viewer that checks
its recording and port and never outlives `testbed view`, one JPDA overflow line per run, `testbed check`."""
from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.pipeline import outdir
from roadtrack.testbed.cli.main import main

REPO = Path(__file__).resolve().parent.parent
FAST = ["--set", "sensor.lidar.azimuth_step_deg=1.0", "--quiet"]  # 11,520 rays per scan instead of 72,000
OVERFLOW = ["--set", "tracker.associator.method='enumerate'", "--set", "tracker.associator.gate_alpha=1e4"]


def _cli(capsys, *args: str) -> tuple[int, str, list[str]]:
    """(exit code, stdout, stderr lines) of ``testbed ARGS`` run in this process."""
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _run(out: Path, *extra: str, duration: float = 0.3) -> list[str]:
    return ["run", "cut_in_out", "--set", f"duration_s={duration}", *FAST, "--out", str(out), *extra]


def _siblings(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def _env(tmp_path: Path) -> dict:
    """A subprocess environment with its own (empty) home: rerun's first-use state is not the user's."""
    home = tmp_path / "home"
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"),
               XDG_DATA_HOME=str(home / ".local" / "share"), PYTHONPATH=str(REPO))
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return env


# --- one line, exit codes, --debug ------------------------------------------------------------------------------

def test_usage_errors_are_one_line_exit_2(capsys):
    for args in (["run"], ["run", "cut_in_out", "--bogus"], ["view", "x", "--port", "70000"], ["nope"]):
        code, _, err = _cli(capsys, *args)
        assert code == 2 and len(err) == 1 and err[0].startswith("error: testbed"), (args, err)


def test_an_unexpected_exception_is_one_line_and_debug_shows_its_traceback(capsys, monkeypatch):
    import roadtrack.testbed.scenario.spec
    from roadtrack import testbed

    def broken():
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(testbed.scenario.spec, "list_scenarios", broken)
    code, _, err = _cli(capsys, "scenarios")
    assert code == 1 and len(err) == 1 and "Traceback" not in "".join(err)
    assert err[0].startswith("error: internal error, ZeroDivisionError: division by zero")
    for args in (["--debug", "scenarios"], ["scenarios", "--debug"]):  # before or after the command
        code, _, err = _cli(capsys, *args)
        assert code == 1 and err[0].startswith("Traceback") and err[-1].startswith("error: internal error")


# --- output folders ------------------------------------------------------------------------------------------

def test_unusable_out_is_refused_before_any_simulation(capsys, tmp_path, monkeypatch):
    import roadtrack.testbed.pipeline.run
    from roadtrack import testbed

    def never(*args, **kwargs):
        raise AssertionError("a simulation ran")

    monkeypatch.setattr(testbed.pipeline.run, "run_scenario", never)
    a_file = tmp_path / "a_file"
    a_file.write_text("mine\n")
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine\n")
    (user / "tracks.parquet").write_text("not a run's\n")
    for out, message in ((a_file, "is a file, not a folder"), (a_file / "sub", f"{a_file} is a file"),
                         (user, "holds other files (notes.txt); choose another --out")):
        code, _, err = _cli(capsys, *_run(out))
        assert code == 2 and len(err) == 1 and err[0].startswith("error: --out: ") and message in err[0], err
    assert a_file.read_text() == "mine\n" and sorted(p.name for p in user.iterdir()) == ["notes.txt", "tracks.parquet"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_rerun_replaces_the_folder_and_a_failure_marks_it_incomplete(capsys, tmp_path):
    out = tmp_path / "r"
    # 1. recorded run, JPDA clusters over max_events, per-track PDA there: one warning line for the whole run,
    # the fallbacks counted on the summary line and in scores.json
    code, stdout, err = _cli(capsys, *_run(out, *OVERFLOW, "--set", "tracker.associator.max_events=3",
                                           "--set", "tracker.associator.on_overflow='pda'", duration=1.0))
    assert code == 0, err
    jpda = [line for line in err if "JPDA" in line]
    assert len(jpda) == 1 and jpda[0].startswith("warning: JPDA: ") and "frames exceeded max_events" in jpda[0], err
    clusters = int(jpda[0].split("(")[1].split(" clusters")[0])
    assert f", {clusters} association fallbacks" in stdout
    assert json.loads((out / "scores.json").read_text())["association_fallbacks"] == clusters
    assert {"run.rrd", "scores.json", "truth.parquet"} <= {p.name for p in out.iterdir()}
    # 2. the same folder without a recording: the earlier run.rrd must not survive beside the new tables
    code, _, err = _cli(capsys, *_run(out, "--no-record"))
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["detections.parquet", "diagnostics.parquet", "events.parquet",
                                                    "scores.json", "timeline.png", "tracks.parquet", "truth.parquet"]
    # 3. a run that fails at frame 2: its tables (frames 0, 1) replace the folder, marked INCOMPLETE
    code, _, err = _cli(capsys, *_run(out, *OVERFLOW, "--set", "tracker.associator.max_events=1", "--set",
                                      "tracker.associator.on_overflow='raise'", duration=1.0))
    assert code == 1 and len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith("error: JPDAOverflowError: ") and "(the run stopped at frame 2 (t = 0.2 s); the " \
        f"tables of the frames before it are in {out}/, marked INCOMPLETE)" in err[0], err
    assert sorted(pd.read_parquet(out / "truth.parquet").frame.unique()) == [0, 1]
    assert not (out / "scores.json").exists() and (out / "run.rrd").is_file()
    assert "JPDAOverflowError" in (out / "INCOMPLETE").read_text()
    assert _siblings(out) == []


def test_failures_outside_the_frame_loop_say_what_was_kept(capsys, tmp_path, monkeypatch):
    import roadtrack.testbed.pipeline.run
    from roadtrack import testbed

    def boom(*args, **kwargs):
        raise RuntimeError("boom")

    out = tmp_path / "r"
    monkeypatch.setattr(testbed.pipeline.run, "score_tables", boom)  # after the last frame
    code, _, err = _cli(capsys, *_run(out, "--no-record"))
    assert code == 1 and len(err) == 1 and "(;" not in err[0]
    assert err[0] == f"error: RuntimeError: boom (the run had done its 4 frames; the tables of the frames before " \
                     f"it are in {out}/, marked INCOMPLETE)"
    assert (out / "truth.parquet").is_file() and (out / "INCOMPLETE").is_file()
    monkeypatch.setattr(testbed.pipeline.run, "sensing_setup", boom)  # before the first frame: nothing written
    code, _, err = _cli(capsys, *_run(out, "--no-record"))
    assert code == 1 and len(err) == 1
    assert err[0] == f"error: RuntimeError: boom (nothing was written ({out} is unchanged))"
    assert (out / "INCOMPLETE").is_file() and _siblings(out) == []


def test_a_full_disk_is_one_last_line_and_leaves_no_half_written_file(capsys, tmp_path, monkeypatch):
    from roadtrack.testbed.pipeline.tables import TableLog

    def full(self, path):
        Path(path).write_bytes(b"PAR1 half")  # what a writer leaves when the disk fills mid-file
        raise OSError(errno.ENOSPC, "Error writing bytes to file")  # pyarrow's: no file name

    out = tmp_path / "r"
    monkeypatch.setattr(TableLog, "write", full)
    code, _, err = _cli(capsys, *_run(out, "--no-record"))
    assert code == 1 and len(err) == 1
    assert err[0].startswith(f"error: {out}/truth.parquet: no space left on device (free some space and run "
                             f"again) (the run had done its 4 frames; the tables could not be written (no space "
                             f"left on device); nothing was written"), err
    assert not out.exists() and not list(tmp_path.iterdir())  # no half-written file, no partial folder


def _first_rerun_error_time(stderr: str) -> float:
    """The time (seconds since the epoch) of rerun's first log line about the full disk (its file writer died)."""
    import datetime

    m = re.search(r"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d+)Z\S*\s.*No space left on device", stderr)
    assert m, stderr
    return datetime.datetime.fromisoformat(m.group(1)).replace(tzinfo=datetime.timezone.utc).timestamp()


STALL_S = 10.0
CLI_WITH_STALL = ("import runpy; import roadtrack.testbed.recording.recorder as r; "
                  f"r.CLOSE_STALL_S = {STALL_S}; runpy.run_module(\"roadtrack.testbed.cli.main\", run_name=\"__main__\", "
                  "alter_sys=True)")
"""``python -m roadtrack.testbed.cli.main`` (argv as given) with CLOSE_STALL_S = STALL_S (read when the recording closes)."""


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare")
def test_a_full_disk_under_rerun_ends_with_our_line(tmp_path):
    """A real full disk (a 256 kB tmpfs in a private mount namespace): rerun logs its file-writer errors, ours
    is the last line and names the cause, within CLOSE_STALL_S (and the run's last frames) of rerun's first
    error: rerun 0.41 sometimes blocks forever in flush() or disconnect() once its file writer died (seen in
    fresh-clone CI), and the recording is then given up on instead of hanging the run. The run is
    ``python -m roadtrack.testbed.cli.main`` with the stall bound set to STALL_S (10 s, not the default 30 s: on a
    full disk the file cannot grow, so a blocked rerun is given up on the same way, 20 s sooner)."""
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=1m tmpfs {tmp_path}"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip("no private tmpfs mount here")
    script = (f"mount -t tmpfs -o size=256k tmpfs {tmp_path} && cd {REPO} && {sys.executable} -c '{CLI_WITH_STALL}' "
              f"{' '.join(_run(tmp_path / 'r', duration=1.0))}; echo rc=$?; ls -a {tmp_path}/r")
    # generous timeout: on a fresh checkout this may be the first run that compiles the numba kernels (20-60 s)
    child = subprocess.Popen(["unshare", "-rm", "sh", "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env=_env(tmp_path), start_new_session=True)
    try:
        out, err = child.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        os.killpg(child.pid, signal.SIGKILL)
        out, err = child.communicate()
        pytest.fail(f"the run on a full disk did not end within 240 s: {err[-2000:]}")
    ended = time.time()
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"error: {tmp_path}/r/run.rrd: no space left on device"), err
    assert "rc=1" in out and "INCOMPLETE" in out.split()
    assert "Traceback" not in err
    assert ended - _first_rerun_error_time(err) < STALL_S + 30.0, err


def test_write_atomic_and_stale_partial_folders(tmp_path):
    target = tmp_path / "scores.json"
    target.write_text("old")

    def half(tmp: Path):
        tmp.write_text("ne")
        raise OSError(errno.ENOSPC, "disk full")

    with pytest.raises(OSError) as info:
        outdir.write_atomic(target, half)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(target)
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["scores.json"]
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / f".r.partial-{dead.pid}").mkdir()  # a killed run's
    (tmp_path / f".q.old-{dead.pid}").mkdir()
    (tmp_path / f".r.partial-{os.getppid()}").mkdir()  # a live process's: kept
    stage = outdir.Staging(tmp_path / "r")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["scores.json", f".r.partial-{os.getppid()}", stage.tmp.name, ".r.lock"])  # .r.lock: runs/r is locked
    stage.discard()


# --- Ctrl-C -----------------------------------------------------------------------------------------------------

def test_ctrl_c_keeps_the_tables_and_a_readable_recording(tmp_path):
    from rerun.chunk import RrdReader

    from roadtrack.testbed.recording.recorder import static_size

    out = tmp_path / "r"
    (tmp_path / "static").mkdir()
    static = static_size(tmp_path / "static")  # what the recording holds before its first frame: known before the
    # run starts, so the run cannot end while it is measured (it did in the suite); 110 s: the run is still going
    # when the signal comes, under recorder.FOOTER_MAX_FRAMES frames so the recording is planned with its footer
    # the child starts with Ctrl-C's default action, as from a terminal: an ignored SIGINT is inherited, and a test
    # worker may have been left with one
    proc = subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli.main", *_run(out, duration=110.0)], cwd=REPO,
                            env=_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    rrd = tmp_path / f".r.partial-{proc.pid}" / "run.rrd"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if rrd.is_file() and rrd.stat().st_size > static + 100_000:  # frames are in
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before the signal: nothing was interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1, err
    assert lines[0].startswith("interrupted: the run stopped at frame ") and \
        f"the tables of the frames before it are in {out}/, marked INCOMPLETE" in lines[0]
    assert len(pd.read_parquet(out / "truth.parquet").frame.unique()) >= 1
    assert "interrupted" in (out / "INCOMPLETE").read_text() and not (out / "scores.json").exists()
    assert sum(ch.num_rows for ch in RrdReader(str(out / "run.rrd")).stream()) > 0
    assert _siblings(out) == []


# --- testbed view -----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    import rerun as rr

    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    rec = rr.RecordingStream("roadtrack-test", recording_id="t")
    rec.save(str(path))
    rng = np.random.default_rng(0)
    for i in range(20):
        rec.set_time("frame", sequence=i)
        rec.log("world/lidar", rr.Points3D(rng.normal(size=(5000, 3)).astype(np.float32)))
    rec.flush()
    rec.disconnect()
    return path


def test_view_refuses_a_corrupt_recording(capsys, tmp_path, recording):
    data = recording.read_bytes()
    cases = {"random.rrd": np.random.default_rng(1).bytes(4096), "text.rrd": b"not a recording\n" * 10,
             "truncated.rrd": data[: len(data) // 2], "empty.rrd": b""}
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        code, _, err = _cli(capsys, "view", str(tmp_path / name), "--web", "--port", "1")
        assert code == 2 and len(err) == 1, (name, err)
        assert err[0].startswith(f"error: {tmp_path / name}: ") and "run the scenario again" in err[0], err


def test_view_refuses_a_port_in_use(capsys, recording):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _, err = _cli(capsys, "view", str(recording), "--web", "--port", str(port))
    assert code == 2 and err == [f"error: --port: port {port} is in use (another `testbed view`?): pass --port "
                                 f"with a free one"]


def _children(pid: int) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                stat = Path(f"/proc/{d}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d))
    return out


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _wait(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.1)
    return False


def _serving(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
    except OSError:
        return False
    return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux: /proc and PR_SET_PDEATHSIG")
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL])
def test_view_leaves_no_server_behind(tmp_path, recording, signum):
    env = _env(tmp_path)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli.main", "view", str(recording), "--port", str(port)],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert _wait(lambda: _serving(port), 30), "the viewer did not start"
        servers = _children(proc.pid)
        assert len(servers) == 1
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == (128 + signum if signum != signal.SIGKILL else -signum)
    assert _wait(lambda: not Path(f"/proc/{servers[0]}").exists() or
                 "Z" in Path(f"/proc/{servers[0]}/stat").read_text().rsplit(")", 1)[1].split()[0], 10)
    assert _wait(lambda: _port_free(port), 10)
    assert "Welcome to Rerun" not in err  # the analytics banner of rerun's first use
    if signum == signal.SIGTERM:
        assert '"analytics_enabled":false' in (tmp_path / "home/.config/rerun/analytics.json").read_text()


# --- testbed check ----------------------------------------------------------------------------------------------

def test_check_validates_scenarios_and_campaigns(capsys, tmp_path):
    code, out, err = _cli(capsys, "check", "cut_in_out", "--set", "duration_s=2")
    assert code == 0 and err == [] and out.strip() == ("cut_in_out: scenario 'cut_in_out' OK: 21 frames (2 s at "
                                                       "10 Hz), 4 vehicles, 72,000 rays per scan, tracker jpda-kf")
    code, out, err = _cli(capsys, "check", str(REPO / "campaigns" / "smoke.toml"))
    assert code == 0 and err == [] and "campaign 'smoke' OK: " in out and " runs (" in out
    bad = tmp_path / "bad.toml"
    for text in ('name = "x"\nduration_s = -1\n', "= broken", 'scenarios = ["nope"]\ntrackers = ["jpda-kf"]\nseeds = 1\n'):
        bad.write_text(text)
        code, out, err = _cli(capsys, "check", str(bad))
        assert code == 2 and out == "" and len(err) == 1 and err[0].startswith("error: "), (text, err)


def test_jpda_overflows_are_counted_once_per_run():
    """The run's counter: warnings of each oversize cluster swallowed, one summary warning at the end."""
    from roadtrack.testbed.pipeline.run import JPDAOverflows
    from roadtrack.trackers import JPDAOverflowWarning

    def step(sizes):
        for t, m in sizes:
            w = JPDAOverflowWarning(f"JPDA cluster of {t} tracks and {m} measurements exceeds max_events=3")
            w.tracks, w.measurements = t, m
            warnings.warn(w)
        return len(sizes)

    counter = JPDAOverflows()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert [counter.call(step, s) for s in ([(3, 4)], [], [(9, 14), (2, 2)])] == [1, 0, 2]
        assert caught == []
        counter.report()
    assert [str(w.message) for w in caught] == ["JPDA: 2 frames exceeded max_events (3 clusters, the largest 9 "
                                                "tracks x 14 measurements); those clusters used per-track PDA"]


def test_a_reader_that_leaves_early_is_not_an_error():
    """`testbed trackers | head -1` (issue 31): the reader closes the pipe; the command stops quietly with exit
    code 0 instead of 'error: broken pipe' and 1."""
    proc = subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli", "trackers"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader leaves after one line
    rc = proc.wait(timeout=120)
    err = proc.stderr.read().decode()
    assert first.startswith(b"nn-kf") and rc == 0 and err == "", (rc, err)
