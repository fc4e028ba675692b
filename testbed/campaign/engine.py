"""Campaign execution: one run in a worker (:func:`execute_run`), on a local process pool or on Dask.

Backends (chosen by :class:`EngineOptions`):

* ``local`` (default): ``concurrent.futures.ProcessPoolExecutor`` with ``spawn`` workers, ``workers``
  processes (default: the usable cores); ``workers = 0`` runs in the calling process (debugging);
* ``dask``: a ``distributed.Client`` on ``scheduler`` (``tcp://host:port``), or on a
  ``LocalCluster(n_workers=dask_local, threads_per_worker=1, processes=True)`` started for the campaign.

The numbers do not depend on the backend, the worker count or the completion order: every run is a pure
function of its :class:`~testbed.campaign.spec.RunSpec` (its seed comes from its key, see
:func:`~testbed.campaign.spec.run_seed`). At most ``2 x worker slots`` runs are in flight; finished runs
are written by this (the client) process, one atomic file each (:mod:`~testbed.campaign.store`), so
Dask workers need no shared file system unless runs are recorded in full (``record.full_seeds``: the
worker writes ``DIR/recordings/<run_id>/`` at the same path on its own machine).

Threads: open3d runs parts of a scan on OpenMP threads and builds the ray-casting scene on a TBB thread
pool, by default on every core, so one "single-threaded" run uses ~1.2 cores. A local-pool worker
therefore gets ``OMP_NUM_THREADS = cores // workers`` (at least 1; an ``OMP_NUM_THREADS`` the user set
wins, the command line's own default of 1 does not: testbed/common/threads.py) and, when ``workers x threads <= cores``, its own block of cores by CPU affinity, which TBB follows
(``sensors/lidar.py`` passes no ``nthreads`` to ``cast_rays``; affinity makes that knob unnecessary).
LocalCluster workers get ``OMP_NUM_THREADS=1`` from Dask's nanny and one core each. Results do not
depend on any of it.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..config import ConfigError, one_line
from ..common.errors import RunError, describe_os_error
from ..common.threads import THREAD_VARS, set_by_user
from . import store
from .spec import Campaign, RunSpec, for_tracker, plan, settings_tracker



def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def pin_process(cpus: list[int]) -> None:
    """Restrict every thread of this process, and the threads it starts later, to the cores ``cpus``."""
    if not hasattr(os, "sched_setaffinity"):
        return
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:
            pass


def _core_block(k: int, threads: int) -> list[int]:
    cores = sorted(os.sched_getaffinity(0))
    return sorted({cores[(k * threads + j) % len(cores)] for j in range(threads)})


PARENT_PID_VAR = "ROADTRACK_CAMPAIGN_PARENT"  # pid of the campaign process, for the LocalCluster workers


def die_with_parent(parent_pid: int | None = None) -> None:
    """Linux: have the kernel SIGKILL this process when its parent dies, whatever kills the parent (SIGKILL
    included), so a `kill -9` of `testbed campaign run` leaves no worker behind (they would otherwise run
    on, holding memory, the parent's stdout/stderr and multiprocessing's resource tracker, which lives as
    long as a process holds its pipe). ``parent_pid``: the pid the parent had; if the parent is already
    gone (reparented to init or a subreaper) the process exits at once.

    The signal follows the *thread* that started this process: pool workers are started by ``submit`` in
    the campaign's thread, LocalCluster workers by Dask's per-process watcher thread, both living as long
    as the pool or cluster does."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return
    if os.getppid() == 1 or (parent_pid is not None and os.getppid() != parent_pid):
        os._exit(1)  # the parent died before the request took effect


def dask_setup(worker) -> None:
    """Dask preload (``LocalCluster(preload=["testbed.campaign.engine"])``), run in each LocalCluster worker
    process: it dies with the campaign process (its parent) by SIGKILL, not only when Dask's own
    parent-alive pipe watcher thread gets the GIL."""
    pid = os.environ.get(PARENT_PID_VAR, "")
    die_with_parent(int(pid) if pid.isdigit() else None)


def init_worker(threads: int | None, counter=None, parent_pid: int | None = None) -> None:
    """Local-pool worker start-up: thread limits (before open3d loads), no rerun analytics, Ctrl-C and SIGHUP
    (a terminal's, sent to its whole process group) left to the parent (which stops the campaign and
    terminates the workers; SIGTERM keeps its default action: the pool ends its workers with it), and, with
    ``counter`` (a shared int), pinning of the k-th worker to its own block of ``threads`` cores: open3d's
    ray-casting scene build runs on a TBB thread pool that ignores OMP_NUM_THREADS but follows the CPU
    affinity; death with the parent (pid ``parent_pid``)."""
    if threads is not None:
        for var in THREAD_VARS:
            if not set_by_user(var):  # the command line's default of 1 gives way to the worker's share
                os.environ[var] = str(threads)
    if counter is not None and threads and hasattr(os, "sched_setaffinity"):
        with counter.get_lock():
            k = counter.value
            counter.value += 1
        pin_process(_core_block(k, threads))
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    die_with_parent(parent_pid)


def make_task(campaign: Campaign, run: RunSpec, out_dir: str | Path | None, sensing_cache: bool = True
              ) -> dict[str, Any]:
    """Everything a worker needs for one run, as plain picklable data. ``sensing_cache``: read and store the
    sensed frames in ``out_dir``/sensing (testbed.sensing.cache), so each traffic is sensed once."""
    from ..scenario.spec import apply_overrides

    src = next(s for s in campaign.scenarios if s.name == run.scenario)
    record_dir = None
    if run.record_full and out_dir is not None:
        record_dir = str(store.recording_dir(Path(out_dir).resolve(), run.run_id))
    return dict(run_id=run.run_id, run_index=run.run_index, campaign=campaign.name, scenario=run.scenario,
                tracker=run.tracker, params=dict(run.params), columns=dict(run.columns),
                grid_index=".".join(map(str, run.grid_index)), seed_index=run.seed_index, seed=run.seed,
                scenario_data=apply_overrides(src.data, for_tracker(campaign.overrides, run.tracker)),
                record_dir=record_dir,
                sensing_cache=str(Path(out_dir).resolve() / store.SENSING_DIR)
                if out_dir is not None and sensing_cache else None)


def _where(err: BaseException) -> str:
    frames = traceback.extract_tb(err.__traceback__)
    if not frames:
        return ""
    f = frames[-1]
    return f"{Path(f.filename).name}:{f.lineno} in {f.name}"


def _scalar(value: Any) -> float | str:
    """A summary value as a results cell: numbers (and booleans) as float64, None as NaN, else text."""
    import numbers

    if value is None:
        return float("nan")
    if isinstance(value, numbers.Real):  # includes bool and numpy scalars
        return float(value)
    return str(value)


def execute_run(task: dict[str, Any]) -> dict[str, Any]:
    """Run one campaign run and return its results row. Never raises for a failing run: an exception
    inside the scenario or the tracker becomes ``status = "error"`` with its type, one-line message and
    innermost frame; the scores are then missing (NaN)."""
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    import numpy as np

    from ..scenario.spec import apply_overrides, parse_scenario

    row: dict[str, Any] = dict(run_id=task["run_id"], run_index=task["run_index"], campaign=task["campaign"],
                               scenario=task["scenario"], tracker=task["tracker"])
    row.update(task["columns"])
    row.update(grid_index=task["grid_index"], seed_index=task["seed_index"], seed=task["seed"],
               status="ok", error_type="", error="", error_where="", warnings="")
    t0 = time.perf_counter()
    summary: dict[str, float] = {}
    n_frames, dt, series = 0, float("nan"), np.zeros(0)
    caught: list[warnings.WarningMessage] = []
    try:
        from ..pipeline.run import run_scenario

        from ..tracking.registry import is_named

        name = task["tracker"]
        data = apply_overrides(task["scenario_data"], {**for_tracker(task["params"], name),
                                                       "tracker.name": settings_tracker(name), "seed": task["seed"]})
        scn = parse_scenario(data)
        dt = scn.dt
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = run_scenario(scn, out_dir=task["record_dir"], record=task["record_dir"] is not None,
                               sensing_cache=task.get("sensing_cache"), tracker=name if is_named(name) else None,
                               label=name)
        summary = {k: _scalar(v) for k, v in res.summary().items()}
        n_frames = res.n_frames
        series = np.full(n_frames, np.nan)
        frames = np.asarray(res.scores.series_frames, dtype=np.int64)
        values = np.asarray(res.scores.series_pos_rmse_m, dtype=np.float64)
        ok = (frames >= 0) & (frames < n_frames)
        series[frames[ok]] = values[ok]
    except Exception as err:  # noqa: BLE001 - recorded, the campaign goes on
        row.update(status="error", error_type=type(err).__name__, error=one_line(err), error_where=_where(err))
    if caught:
        seen: dict[str, int] = {}
        for w in caught:
            key = f"{w.category.__name__}: {one_line(w.message)}"
            seen[key] = seen.get(key, 0) + 1
        row["warnings"] = "; ".join(f"{k} (x{n})" if n > 1 else k for k, n in list(seen.items())[:5])
    row["n_frames"] = n_frames
    row["dt_s"] = dt
    row["recorded"] = task["record_dir"] is not None and row["status"] == "ok"
    row.update(summary)
    row[store.SERIES_COLUMN] = series
    row.update({f"v_{k}": v for k, v in store.versions().items()})
    row["wall_s"] = time.perf_counter() - t0
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    row["finished_at"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    return row


# ------------------------------------------------------------------------------------------ backends


class InfrastructureError(RuntimeError):
    """A worker or the cluster failed (not the run itself): the campaign stops and can be resumed."""


class _InProcess:
    """workers = 0: run in this process, one at a time (for debugging with pdb / profilers)."""

    slots = 1
    description = "in this process"

    def submit(self, task):
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(execute_run(task))
        except BaseException as err:  # noqa: BLE001
            fut.set_exception(err)
        return fut

    def wait(self, futures, timeout):
        return {f for f in futures if f.done()}

    def result(self, fut):
        return fut.result()

    def close(self, abandon: bool) -> None:
        pass


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (unless it runs) with SIGHUP blocked: it ignores SIGINT and
    SIGTERM by itself, but a terminal's hangup, sent to the whole process group, would kill it, and the
    campaign's clean-up then printed a traceback per semaphore of the pool (which leaked)."""
    from multiprocessing import resource_tracker

    if not hasattr(signal, "SIGHUP") or not hasattr(signal, "pthread_sigmask"):
        resource_tracker.ensure_running()
        return
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})  # inherited by the tracker, for good
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


class _LocalPool:
    def __init__(self, workers: int, threads: int | None, pin: bool = True):
        ctx = multiprocessing.get_context("spawn")
        start_resource_tracker()  # before the pool's first semaphore registers with it
        pin = pin and threads is not None and workers * threads <= usable_cores() and hasattr(os, "sched_setaffinity")
        counter = ctx.Value("i", 0) if pin else None
        self.slots = workers
        self.description = f"local process pool, {workers} worker{'s' * (workers != 1)}" + (
            f", {threads} thread{'s' * (threads != 1)} each" if threads else "") + (", pinned" if pin else "")
        self.pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_worker,
                                           initargs=(threads, counter, os.getpid()))

    def submit(self, task):
        try:
            return self.pool.submit(execute_run, task)
        except cf.process.BrokenProcessPool as err:
            raise InfrastructureError(f"a worker process died ({one_line(err) or 'BrokenProcessPool'})") from None

    def wait(self, futures, timeout):
        done, _ = cf.wait(futures, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return done

    def result(self, fut):
        try:
            return fut.result()
        except cf.process.BrokenProcessPool as err:
            raise InfrastructureError(f"a worker process died ({one_line(err) or 'BrokenProcessPool'})") from None

    def close(self, abandon: bool) -> None:
        if abandon:
            for proc in list((getattr(self.pool, "_processes", None) or {}).values()):
                try:
                    proc.terminate()
                except Exception:  # noqa: BLE001 - already gone
                    pass
        self.pool.shutdown(wait=not abandon, cancel_futures=True)


def _local_cluster(n_workers: int):
    """``LocalCluster(n_workers, threads_per_worker=1, processes=True)`` without Dask's default
    ``MALLOC_TRIM_THRESHOLD_=65536`` in the workers: setting it switches off glibc's adaptive mmap
    threshold, so every large numpy temporary is mmap'ed and page-faulted afresh, which makes a roadtrack
    run ~40 % slower; and without the workers' statistical profiler (a stack sample every 10 ms that
    nobody reads here). Each worker runs :func:`dask_setup` as a preload: it dies with this process
    (PR_SET_PDEATHSIG). Dask's nanny also writes its pre-spawn variables (OMP_NUM_THREADS=1, ...) into
    this process's environment; they are put back afterwards so that later local pools are unaffected."""
    import logging

    import dask
    from distributed import LocalCluster

    saved = dict(os.environ)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                              "distributed.worker.profile.enabled": False}):
            return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                silence_logs=logging.ERROR, preload=[__name__],
                                env={"RERUN_ANALYTICS": "0", PARENT_PID_VAR: str(os.getpid())})
    finally:
        for key in set(os.environ) - set(saved):
            del os.environ[key]
        os.environ.update(saved)


class _Dask:
    def __init__(self, scheduler: str | None, n_local: int | None, pin: bool = True):
        from distributed import Client

        self.cluster = None
        if n_local:
            self.cluster = _local_cluster(n_local)
            self.client = Client(self.cluster)
            if pin and n_local <= usable_cores() and hasattr(os, "sched_setaffinity"):
                for k, addr in enumerate(sorted(self.client.scheduler_info()["workers"])):
                    self.client.run(pin_process, _core_block(k, 1), workers=[addr])
            self.description = f"Dask LocalCluster, {n_local} worker process{'es' * (n_local != 1)}"
        else:
            try:
                self.client = Client(scheduler, timeout="30s")
            except (OSError, TimeoutError) as err:
                raise InfrastructureError(f"Dask scheduler {scheduler}: {type(err).__name__}: {one_line(err)}") \
                    from None
            self.description = f"Dask scheduler {scheduler}"

    @property
    def slots(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def submit(self, task):
        return self.client.submit(execute_run, task, pure=False, key=f"roadtrack-run-{task['run_id']}-{time.time_ns()}")

    def wait(self, futures, timeout):
        from distributed import wait

        try:
            wait(list(futures), timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            pass
        except Exception:  # noqa: BLE001 - dask's own timeout type in some versions
            pass
        return {f for f in futures if f.done()}

    def result(self, fut):
        from distributed import KilledWorker

        try:
            return fut.result()
        except KilledWorker:
            raise  # attributable to this run: recorded as its error
        except Exception as err:  # noqa: BLE001 - cancelled, lost connection, ...
            raise InfrastructureError(f"Dask: {type(err).__name__}: {one_line(err)}") from None

    def close(self, abandon: bool) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()


SCHEDULER_TIMEOUT_S = 3.0  # seconds to connect to a Dask scheduler before giving up
SCHEDULER_FORMS = "tcp://host:port, host:port, tls://host:port, ws://host:port, wss://host:port or ucx://host:port"


def check_scheduler_address(address: str) -> None:
    """A ConfigError unless ``address`` is a Dask scheduler address (:data:`SCHEDULER_FORMS`)."""
    import importlib.util

    from distributed.comm import registry
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address, strict=False)
        if scheme == "inproc":
            raise ValueError("inproc:// addresses exist only inside one process")
        registry.get_backend(scheme)
        if scheme == "ucx" and importlib.util.find_spec("distributed_ucxx") is None:
            raise ValueError("ucx:// needs the distributed-ucxx package, which is not installed")
        host, port = parse_host_port(loc)
        if not host or not 0 < port < 65536:
            raise ValueError(f"{'no host' if not host else f'port {port} is not in 1..65535'}")
    except (ValueError, TypeError) as err:
        raise ConfigError("--scheduler", f"{address!r} is not a Dask scheduler address ({one_line(err)}); "
                          f"expected {SCHEDULER_FORMS}") from None


def check_scheduler(address: str, timeout: float = SCHEDULER_TIMEOUT_S) -> None:
    """Check ``address`` (a ConfigError if malformed) and that a Dask scheduler answers there within
    ``timeout`` seconds (a RunError if not): a full Dask handshake, before anything is written."""
    import asyncio
    import logging

    from distributed.comm import connect
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.security import Security

    check_scheduler_address(address)
    scheme, loc = parse_address(address, strict=False)
    if scheme != "ucx":  # tcp, tls, ws, wss: a refused port or an unknown host fails at once
        host, port = parse_host_port(loc)
        try:
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError as err:
            why = f"unknown host {host!r}" if isinstance(err, socket.gaierror) else describe_os_error(err)
            raise RunError(f"--scheduler {address}: cannot connect ({why}); start a Dask scheduler there "
                           "(`dask scheduler`) or check the address") from None

    async def probe() -> None:  # connect and the Dask handshake, within one deadline
        comm = await asyncio.wait_for(connect(address, timeout=timeout, **Security().get_connection_args("client")),
                                      timeout)
        await comm.close()

    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        asyncio.run(probe())
    except (OSError, TimeoutError) as err:  # timeout (also a listener that is not a Dask scheduler), refused
        why = one_line(err) or "nothing answered the Dask handshake"
        raise RunError(f"--scheduler {address}: no Dask scheduler answered within {timeout:g} s ({why}); start "
                       "one (`dask scheduler`) or check the address") from None
    except Exception as err:  # noqa: BLE001 - TLS settings, not a Dask scheduler, ...
        raise RunError(f"--scheduler {address}: cannot talk to a Dask scheduler there ({type(err).__name__}: "
                       f"{one_line(err)})") from None
    finally:
        quiet.setLevel(level)


@dataclass(frozen=True)
class EngineOptions:
    """Where runs execute: ``workers`` local processes (None: usable cores; 0: in this process), or Dask
    on ``scheduler`` or on a ``dask_local``-worker LocalCluster. ``threads``: OMP threads per local
    worker (None: cores // workers). ``pin``: give each local or LocalCluster worker its own cores
    (when they are enough), so that no run's helper threads compete with another worker. ``sensing_cache``: sense
    each traffic once into the campaign folder's ``sensing/`` and run every tracker on it (False: each run
    senses its own)."""

    workers: int | None = None
    scheduler: str | None = None
    dask_local: int | None = None
    threads: int | None = None
    pin: bool = True
    sensing_cache: bool = True

    def __post_init__(self) -> None:
        chosen = [x is not None for x in (self.scheduler, self.dask_local)]
        if sum(chosen) > 1 or (any(chosen) and self.workers is not None):
            raise ValueError("choose one of workers, scheduler, dask_local")
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")
        if self.dask_local is not None and self.dask_local < 1:
            raise ValueError(f"dask_local must be >= 1, got {self.dask_local}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")


def make_backend(opts: EngineOptions):
    if opts.scheduler is not None or opts.dask_local is not None:
        return _Dask(opts.scheduler, opts.dask_local, opts.pin)
    workers = usable_cores() if opts.workers is None else opts.workers
    if workers == 0:
        return _InProcess()
    threads = opts.threads if opts.threads is not None else max(1, usable_cores() // workers)
    return _LocalPool(workers, threads, opts.pin)


# ------------------------------------------------------------------------------------------ the loop


@dataclass(frozen=True)
class Outcome:
    """total: runs in the plan; before: finished before this call; ran: finished now; failed: runs
    with status error (all of them, old and new); interrupted: stopped (a signal or ``stop``); signum: the
    signal that stopped it (SIGINT: Ctrl-C, SIGTERM, SIGHUP; None if ``stop`` was set by the caller or
    it was not stopped); broken: why the backend failed (None if it did not)."""

    total: int
    before: int
    ran: int
    failed: int
    interrupted: bool = False
    broken: str | None = None
    signum: int | None = None

    @property
    def complete(self) -> bool:
        return self.before + self.ran == self.total


def _submit_order(runs: list[RunSpec], campaign: Campaign | None = None) -> list[RunSpec]:
    """Seed-major: every configuration's seed 0 first, then seed 1, ... so a stopped campaign has
    balanced partial results; with ``campaign``, the first run of each traffic to sense (its sensing key) goes
    first, so the workers sense different traffic at once and the other runs read it from the cache."""
    order = sorted(runs, key=lambda r: (r.seed_index, r.run_index))
    if campaign is None:
        return order
    keys = [_sensing_key(campaign, r) for r in order]
    first = {k: i for i, k in reversed(list(enumerate(keys)))}
    lead = set(first.values())
    return [order[i] for i in sorted(lead)] + [r for i, r in enumerate(order) if i not in lead]


def _sensing_key(campaign: Campaign, run: RunSpec) -> str:
    """The sensing key of a run (testbed.sensing.cache), or its run id when its scenario does not load."""
    from ..scenario.spec import apply_overrides, parse_scenario
    from ..sensing.cache import sensing_key

    task = make_task(campaign, run, None)
    try:
        data = apply_overrides(task["scenario_data"], {**for_tracker(task["params"], task["tracker"]),
                                                       "tracker.name": settings_tracker(task["tracker"]),
                                                       "seed": task["seed"]})
        return sensing_key(parse_scenario(data))
    except Exception:  # noqa: BLE001 - the run will report its own error
        return run.run_id


STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


class _StopOnSignals:
    """From the main thread: Ctrl-C (SIGINT), SIGTERM and SIGHUP set ``stop`` and keep the first one's number
    in ``signum``; that signal then gets its previous handler back, so a second one interrupts the clean-up
    (KeyboardInterrupt, or :class:`~testbed.common.errors.Terminated` under ``testbed``). An ignored SIGTERM or SIGHUP
    (``nohup``) stays ignored. :meth:`restore` puts every previous handler back."""

    def __init__(self, stop: threading.Event):
        self.stop = stop
        self.signum: int | None = None
        self.previous: dict[int, Any] = {}
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)):
            if sig == signal.SIGINT or signal.getsignal(sig) is not signal.SIG_IGN:
                self.previous[sig] = signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame) -> None:
        if self.signum is None:
            self.signum = signum
        self.stop.set()
        signal.signal(signum, self._handler(signum))

    def _handler(self, sig: int):
        old = self.previous.get(sig)
        return old if old is not None else signal.SIG_DFL

    def restore(self) -> None:
        for sig in self.previous:
            signal.signal(sig, self._handler(sig))
        self.previous = {}


class _Loop:
    """Submits pending runs to a backend (at most 2 per slot in flight) and writes each result as it arrives."""

    def __init__(self, campaign: Campaign, out: Path, backend, bar, failed: int, sensing_cache: bool = True):
        self.campaign, self.out, self.backend, self.bar = campaign, out, backend, bar
        self.sensing_cache = sensing_cache
        self.in_flight: dict[Any, RunSpec] = {}
        self.ran, self.failed = 0, failed

    def take(self, fut) -> None:
        run = self.in_flight.pop(fut)
        try:
            row = self.backend.result(fut)
        except InfrastructureError:
            raise
        except Exception as err:  # noqa: BLE001 - e.g. Dask KilledWorker: the run itself kills workers
            row = _error_row(self.campaign, run, err)
        store.write_run(self.out, row)
        self.ran += 1
        self.failed += row["status"] != "ok"
        self.bar.update(1)
        self.bar.set_postfix(failed=self.failed)

    def run(self, pending: list[RunSpec], stop: threading.Event) -> None:
        queue, exhausted = iter(pending), False
        while not stop.is_set():
            while not exhausted and len(self.in_flight) < 2 * self.backend.slots and not stop.is_set():
                run = next(queue, None)
                if run is None:
                    exhausted = True
                    break
                self.in_flight[self.backend.submit(make_task(self.campaign, run, self.out, self.sensing_cache))] = run
            if not self.in_flight:
                break
            for fut in self.backend.wait(set(self.in_flight), timeout=0.25):
                self.take(fut)
        if stop.is_set():  # keep whatever already finished
            for fut in [f for f in self.in_flight if f.done() and not f.cancelled()]:
                try:
                    self.take(fut)
                except InfrastructureError:
                    self.in_flight.pop(fut, None)


def run_campaign(campaign: Campaign, out_dir: str | Path, engine: EngineOptions | None = None,
                 quiet: bool = False, retry_errors: bool = False,
                 say: Callable[[str], None] | None = None, stop: threading.Event | None = None,
                 backend=None) -> Outcome:
    """Run every run of ``campaign`` that ``out_dir`` does not hold yet (with ``retry_errors`` also
    those that failed), writing each as it finishes, then rebuild ``results.parquet``.

    Ctrl-C (SIGINT), SIGTERM or SIGHUP (when called from the main thread) or setting ``stop`` stops
    submitting, keeps what finished, abandons the runs in flight and returns with ``interrupted`` (and the
    signal in ``signum``). ``backend`` (from
    :func:`make_backend`) reuses already started workers, e.g. warm ones in a benchmark; it is then
    left open unless runs had to be abandoned. (Local-pool workers die with the thread that first
    submitted to the pool, see :func:`die_with_parent`: reuse a backend only while that thread lives.)

    ``out_dir`` is locked (:func:`~testbed.campaign.store.locked`) for the whole call: a second process
    running or resuming the same folder gets a ConfigError. Damaged run files are set aside and run again,
    with a warning line each (``say``).
    """
    say = say or (lambda text: print(text, file=sys.stderr))
    out = Path(out_dir)
    try:
        (out / store.RUNS_DIR).mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        bad = out if not out.is_dir() else out / store.RUNS_DIR
        raise ConfigError(str(bad), "not a folder; move it away") from None
    with store.locked(out):
        return _run_locked(campaign, out, engine, quiet, retry_errors, say, stop, backend)


def _run_locked(campaign: Campaign, out: Path, engine: EngineOptions | None, quiet: bool, retry_errors: bool,
                say: Callable[[str], None], stop: threading.Event | None, backend) -> Outcome:
    from tqdm import tqdm

    warn = lambda text: say(f"warning: {text}")  # noqa: E731
    runs = plan(campaign)
    finished = store.finished_runs(out, clean=True, warn=warn)
    keep = {rid for rid, status in finished.items() if status == "ok" or not retry_errors}
    cached = (engine or EngineOptions()).sensing_cache
    pending = _submit_order([r for r in runs if r.run_id not in keep], campaign if cached else None)
    before = len(runs) - len(pending)
    failed = sum(1 for rid in keep if finished[rid] == "error")
    if not pending:
        store.consolidate(out, clean=True, warn=warn)
        return Outcome(len(runs), before, 0, failed)

    stop = stop or threading.Event()
    signals = _StopOnSignals(stop)
    own_backend = backend is None
    broken: str | None = None
    loop = None
    try:
        if own_backend:
            backend = make_backend(engine or EngineOptions())
        if not quiet:
            say(f"{campaign.name}: {len(pending)} of {len(runs)} runs to do on {backend.description}")
        bar = tqdm(total=len(runs), initial=before, unit="run", desc=campaign.name, disable=quiet or None,
                   file=sys.stderr, dynamic_ncols=True, smoothing=0.05)
        bar.set_postfix(failed=failed)
        loop = _Loop(campaign, out, backend, bar, failed, (engine or EngineOptions()).sensing_cache)
        loop.run(pending, stop)
    except InfrastructureError as err:
        broken = str(err)
    finally:
        try:
            if loop is not None:
                loop.bar.close()
            abandon = (loop is not None and bool(loop.in_flight)) or stop.is_set() or broken is not None
            if backend is not None and (own_backend or abandon):
                backend.close(abandon=abandon)
            store.consolidate(out, clean=True, warn=warn)
        finally:  # a stop signal during the clean-up only sets stop (a second one of a kind interrupts it)
            signals.restore()
    ran, failed = (loop.ran, loop.failed) if loop is not None else (0, failed)
    return Outcome(len(runs), before, ran, failed, interrupted=stop.is_set(), broken=broken, signum=signals.signum)


def _error_row(campaign: Campaign, run: RunSpec, err: BaseException) -> dict[str, Any]:
    import numpy as np

    row: dict[str, Any] = dict(run_id=run.run_id, run_index=run.run_index, campaign=campaign.name,
                               scenario=run.scenario, tracker=run.tracker)
    row.update(run.columns)
    row.update(grid_index=".".join(map(str, run.grid_index)), seed_index=run.seed_index, seed=run.seed,
               status="error", error_type=type(err).__name__, error=one_line(err), error_where="", warnings="",
               n_frames=0, dt_s=float("nan"), recorded=False)
    row[store.SERIES_COLUMN] = np.zeros(0)
    row.update({f"v_{k}": "" for k in store.versions()})
    row.update(wall_s=float("nan"), worker="", finished_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    return row
