"""Where campaign trials run: the trial function itself and the pools that run it.

:func:`execute_trial` is what a worker does with one trial: rebuild the
config from plain data, run it through :func:`bench.trial.run.run_trial`
(log and ``result.json`` only, no figures) with the ground-truth recorder
outermost, and return plain data. It creates its own PyBullet world, so it
runs the same in a local process, on a Dask worker or in the parent.

Pools: :class:`LocalPool` (a ``ProcessPoolExecutor`` whose workers a
forkserver forks with the trial code already imported, one BLAS/OpenMP
thread each so trials do not fight for cores, each dying with the campaign),
:class:`DaskPool` (a ``distributed`` scheduler; workers must see the same
filesystem), :class:`InlinePool` (the parent itself, one trial at a time —
what the real bus needs).
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing
import os
import signal
import socket
import threading
import time
import traceback
import uuid
from contextlib import ExitStack
from pathlib import Path
from typing import Any, Iterable, Protocol

from bench.campaign.rates import fault_onset
from bench.config.models import TrialConfig
from bench.core.log import TrialLog
from bench.core.requirements import lowest
from bench.rig.emulated import VirtualRig
from bench.rig.serving import rig_kind
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from drivers.errors import ExitCode

__all__ = ["DaskPool", "InlinePool", "LocalPool", "Pool", "THREAD_ENV", "execute_trial", "segment_end_s", "start_forkserver",
           "worker_init"]

THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMEXPR_NUM_THREADS": "1"}


# ---------------------------------------------------------------------------
# The trial, in a worker
# ---------------------------------------------------------------------------


def segment_end_s(log: TrialLog, segment: str) -> float | None:
    """When ``segment`` (its settle included) ended, on the trial's clock (s since its first
    reading, as the monitor's alarms); None when the trial never ran it."""
    if segment not in log.segment_names or not len(log):
        return None
    rows = (log.segment == log.segment_names.index(segment)).nonzero()[0]
    return float(log.time[rows[-1]] - log.time[0]) if rows.size else None


def _columns(outcome) -> dict[str, float]:
    tip, entry = outcome.tip_deviation_mm, outcome.entry_deviation_mm
    return {"tip_dx_mm": tip[0], "tip_dy_mm": tip[1], "tip_dz_mm": tip[2],
            "entry_dx_mm": entry[0], "entry_dy_mm": entry[1], "entry_dz_mm": entry[2],
            "depth_dev_mm": outcome.depth_deviation_mm, "angle_dev_deg": outcome.angle_deviation_deg}


#: The camera figures a campaign trial keeps (bench.core.seen.camera_summary's, mm and degrees).
CAMERA_METRICS = ("tip_deviation_mm", "angle_deviation_deg", "encoder_gap_mm", "uncertainty_mm",
                  "encoder_uncertainty_mm", "flag", "problem")


def judged_on_the_cameras(cfg: TrialConfig) -> TrialConfig:
    """A trial on a servo bus (the emulated or the real rig: no simulator truth) with cameras is
    judged on the cameras' tip, as seed 000 judged its robot (Table 3): its placement and its
    placement's requirements (``acceptance.by: camera``). A simulator's trial keeps its config: its
    truth judges it, the cameras' figures beside."""
    if cfg.cameras is None or cfg.backend.kind != "dynamixel" or cfg.acceptance.by == "camera":
        return cfg
    return cfg.model_copy(update={"acceptance": cfg.acceptance.model_copy(update={"by": "camera"})})


def _judged(res) -> tuple[Any, str, str]:
    """(the placement a campaign judges, what it was judged on, why there is none) of a trial."""
    if res.basis == "sim":  # the backend's truth: placement judged where the joints really were
        return res.true_outcome, "sim", ""
    if res.judged_by == "camera":
        missing = "" if res.outcome is not None or not res.completed else (
            "the cameras did not measure the tip: " + ((res.camera or {}).get("problem") or "?"))
        return res.outcome, "camera", missing
    return res.outcome, "measured", ""


def execute_trial(task: dict[str, Any]) -> dict[str, Any]:
    """Run one campaign trial; plain data in, plain data out (never raises for a bad trial)."""
    t0, c0 = time.perf_counter(), time.process_time()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    base = {"id": task["id"], "worker": worker}
    try:

        cfg = TrialConfig.model_validate(task["config"])
        with ExitStack() as rig:
            if task.get("emulate"):  # its emulated rig, here, on the virtual clock
                cfg = rig.enter_context(VirtualRig(cfg)).retarget(cfg)
            prep = prepare(judged_on_the_cameras(cfg))
            kind = rig_kind(prep.config)  # while its emulated rig serves: sim, emulated or real
            res = run_trial(prep, Path(task["stage"]), TrialHooks(report=bool(task.get("report", False))))
        measured = res.encoders
        outcome, truth, missing = _judged(res)
        log = TrialLog.load(res.log_path) if res.monitor else None
        metrics = {"outcome": outcome.as_dict() if outcome else None,
                   "measured": measured.as_dict() if measured else None,
                   "requirements": res.requirements,
                   "rig": kind}  # what the trial drove
        if res.camera is not None:  # the cameras' figures, whatever judged the placement
            metrics["camera"] = {k: res.camera.get(k) for k in CAMERA_METRICS}
        if res.monitor is not None:  # the twin beside it: when it flagged what, against the fault's start
            metrics["monitor"] = {"first_alarm_s": res.monitor["first_alarm_s"],
                                  "joints_named": [a["joint"] for a in res.monitor["alarms"]],
                                  "onset_s": fault_onset(cfg.faults),
                                  "insertion_end_s": segment_end_s(log, "insert")}
        worst, _ = lowest(res.requirements)
        return {**base, "status": "done", "completed": res.completed,
                "passed": bool(res.completed and outcome is not None and outcome.passed and not res.failing),
                "robustness": worst["robustness"] if worst else None,
                "worst": worst["name"] if worst else None,
                "reason": res.reason or missing, "columns": _columns(outcome) if outcome else {},
                "truth": truth, "metrics": metrics, "run_dir": str(res.run_dir),
                "duration_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    except Exception as e:  # a trial that cannot run is a result too (status error)
        last = traceback.extract_tb(e.__traceback__)[-1:] if e.__traceback__ else []
        where = f" at {Path(last[0].filename).name}:{last[0].lineno}" if last else ""
        return {**base, "status": "error", "error": f"{type(e).__name__}: {e}{where}",
                "duration_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def worker_init(lifeline: Any = None) -> None:
    """In each local worker: leave Ctrl-C to the parent, die with it, one thread for BLAS.

    A worker forked by the forkserver is the server's child, not the campaign's, and
    the server outlives a killed campaign while any worker holds its pipe; so besides
    the kernel's parent-death signal a watchdog thread waits on ``lifeline`` (the read
    end of a pipe only the campaign process can write) and ends the worker the moment
    that process is gone, trial in flight or not.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for k, v in THREAD_ENV.items():
        os.environ.setdefault(k, v)
    try:  # Linux: the kernel kills the worker if its parent dies (kill -9 included)
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if lifeline is not None:
        threading.Thread(target=_die_with, args=(lifeline,), daemon=True, name="lifeline").start()


def _die_with(lifeline: Any) -> None:
    try:
        while True:
            lifeline.recv()
    except BaseException:  # EOF: every writer (the campaign process) is gone
        os._exit(ExitCode.ORPHANED)


# ---------------------------------------------------------------------------
# Pools
# ---------------------------------------------------------------------------


class Pool(Protocol):
    workers: int
    description: str

    def submit(self, task: dict[str, Any]) -> Any: ...

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        """The futures among ``futures`` that are done, waiting up to ``timeout`` s for one."""

    def result(self, future: Any) -> dict[str, Any]: ...

    def cancel(self, futures: Iterable[Any]) -> set[Any]:
        """Cancel what has not started; return the futures that were cancelled."""

    def close(self, abandon: bool = False) -> None: ...


def _context() -> multiprocessing.context.BaseContext:
    """``forkserver`` with the trial code imported once in the server (workers fork ready to
    run, in ~10 ms instead of ~0.5 s of imports each), else ``spawn``. Neither copies the
    parent's state, so PyBullet is only ever created inside a worker."""
    try:
        ctx = multiprocessing.get_context("forkserver")
    except ValueError:  # pragma: no cover - platforms without fork
        return multiprocessing.get_context("spawn")
    ctx.set_forkserver_preload(["bench.campaign.worker_env", "bench.trial.run", "bench.core.truth", "bench.faults"])
    return ctx


def start_forkserver() -> float:
    """Start the forkserver (trial code imported once) now rather than at the first trial;
    the seconds it took. Lets a benchmark time the pools, not this one-off."""
    t0 = time.perf_counter()
    ctx = _context()
    if ctx.get_start_method() == "forkserver":
        with cf.ProcessPoolExecutor(1, mp_context=ctx) as ex:  # returns once the server has imported
            ex.submit(os.getpid).result()
    return time.perf_counter() - t0


class LocalPool:
    """Trials in ``workers`` processes on this machine (forked by the forkserver, else spawned)."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers
        self.description = f"{workers} local process{'es' if workers > 1 else ''}"
        # Workers start on demand and inherit the environment at that moment:
        # one BLAS/OpenMP thread each, restored for the parent on close.
        self._saved_env = {k: os.environ.get(k) for k in THREAD_ENV}
        os.environ.update(THREAD_ENV)
        ctx = _context()
        self._lifeline, self._alive = ctx.Pipe(duplex=False)
        self._ex = cf.ProcessPoolExecutor(max_workers=workers, initializer=worker_init,
                                          initargs=(self._lifeline,), mp_context=ctx)

    def submit(self, task: dict[str, Any]) -> cf.Future:
        return self._ex.submit(execute_trial, task)

    def wait(self, futures: Iterable[cf.Future], timeout: float) -> set[cf.Future]:
        done, _ = cf.wait(list(futures), timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return set(done)

    def result(self, future: cf.Future) -> dict[str, Any]:
        return future.result()

    def cancel(self, futures: Iterable[cf.Future]) -> set[cf.Future]:
        return {f for f in futures if f.cancel()}

    def close(self, abandon: bool = False) -> None:
        try:
            if abandon:
                for p in list(getattr(self._ex, "_processes", {}).values()):
                    p.terminate()
            self._ex.shutdown(wait=not abandon, cancel_futures=True)
        finally:
            self._alive.close()
            self._lifeline.close()
            for k, v in self._saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


class DaskPool:
    """Trials on a Dask ``distributed`` cluster (one trial per worker thread)."""

    def __init__(self, address: str, timeout: float = 30.0) -> None:
        try:
            from distributed import Client  # optional: only for a Dask cluster
        except ImportError:  # pragma: no cover - depends on the install
            raise RuntimeError("--scheduler needs dask.distributed: pip install 'needle-hil-bench[cluster]'") from None
        try:
            self._client = Client(address, timeout=timeout, set_as_default=False)
        except OSError as e:
            raise RuntimeError(f"cannot reach the Dask scheduler at {address!r}: {e}") from None
        self.workers = max(1, sum(self._client.nthreads().values()))
        self.description = f"Dask scheduler {address} ({self.workers} worker threads)"

    def submit(self, task: dict[str, Any]) -> Any:

        return self._client.submit(execute_trial, task, pure=False,
                                   key=f"{task['name']}-{uuid.uuid4().hex[:8]}")

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        futures = list(futures)
        deadline = time.monotonic() + timeout
        while True:
            done = {f for f in futures if f.done()}
            if done or time.monotonic() >= deadline:
                return done
            time.sleep(0.02)

    def result(self, future: Any) -> dict[str, Any]:
        return future.result()

    def cancel(self, futures: Iterable[Any]) -> set[Any]:
        futures = [f for f in futures if not f.done()]
        if futures:
            self._client.cancel(futures)
        return set(futures)

    def close(self, abandon: bool = False) -> None:
        self._client.close()


class InlinePool:
    """The parent process runs each trial itself when it is collected (the one-bus rig)."""

    workers = 1
    description = "this process, one trial at a time"

    def submit(self, task: dict[str, Any]) -> cf.Future:
        fut: cf.Future = cf.Future()
        fut.task = task  # type: ignore[attr-defined]
        return fut

    def wait(self, futures: Iterable[cf.Future], timeout: float) -> set[cf.Future]:
        for f in futures:
            if not f.done():
                f.set_running_or_notify_cancel()
                f.set_result(execute_trial(f.task))  # type: ignore[attr-defined]
                return {f}
        return set(futures)

    def result(self, future: cf.Future) -> dict[str, Any]:
        return future.result()

    def cancel(self, futures: Iterable[cf.Future]) -> set[cf.Future]:
        return {f for f in futures if f.cancel()}

    def close(self, abandon: bool = False) -> None:
        pass
