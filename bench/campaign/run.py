"""Fault-injection campaigns: a spec planned into trials, run in parallel, stored, resumable.

``create_campaign`` turns a spec (:mod:`bench.campaign.spec`) into a campaign
directory holding ``campaign.db`` (:mod:`bench.campaign.store`) with every
trial pending. ``run_campaign`` runs whatever is missing on a pool
(:mod:`bench.campaign.execute`): local processes by default, a Dask cluster
given a scheduler address, the parent alone for the real servo bus. Only
the parent writes the database, one transaction per finished trial, after
moving the trial's run directory from ``trials/.staging`` to
``trials/<trial name>`` — so a trial is recorded whole or not at all, a
killed campaign loses at most the trials in flight, and a resumed one runs
each missing trial once and leaves one log directory per trial.

One process writes a campaign directory at a time: ``run`` and ``resume`` hold its
lock (:mod:`bench.campaign.lock`), which the kernel drops if the holder is killed.

Ctrl-C stops submitting, cancels what has not started, lets the trials in
flight finish and records them; a second Ctrl-C abandons those (they go
back to pending). Nothing is marked done that did not finish.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import shutil
import signal
import sqlite3
import threading
import time
import uuid
from collections import deque
from concurrent.futures import CancelledError
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

from bench.campaign.execute import DaskPool, InlinePool, LocalPool, Pool, execute_trial
from bench.campaign.lock import CampaignBusy, CampaignLock
from bench.campaign.report import write_campaign_report
from bench.campaign.spec import find_axes, load_campaign_spec, plan_trials, resolve_base
from bench.campaign.store import METRIC_COLUMNS, CampaignStore, CampaignStoreError
from drivers.errors import CampaignError

__all__ = ["CampaignBusy", "CampaignError", "CampaignProgress", "CampaignSummary", "DB_NAME",
           "create_campaign", "export_csv", "rerun_trial", "run_campaign", "summarize"]

DB_NAME = "campaign.db"
TRIALS_DIR = "trials"
STAGING = ".staging"


@dataclass
class CampaignProgress:
    """What a progress display needs after each event."""

    planned: int
    to_run: int
    finished: int = 0  # this session
    failed: int = 0  # finished, not passed (this session)
    errors: int = 0  # this session
    in_flight: int = 0
    last: Optional[dict[str, Any]] = None


@dataclass
class CampaignSummary:
    db: Path
    planned: int
    completed: int  # trials with a recorded result (status done)
    passed: int
    errors: int
    pending: int
    interrupted: bool = False
    wall_s: float = 0.0
    ran: int = 0  # trials finished by this session
    pool: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def reason(self) -> str:
        """Why the campaign is not complete, in one line ("" when every trial has a result)."""
        if self.completed == self.planned:
            return ""
        parts = []
        if self.interrupted:
            parts.append("interrupted")
        if self.errors:
            parts.append(f"{self.errors} trial(s) ended in an error (their messages: "
                         f"`hilbench campaign export`)")
        if self.pending:
            parts.append(f"{self.pending} trial(s) not run")
        return "; ".join(parts) + f"; continue with `hilbench campaign resume {self.db.parent}`"

    def as_json(self) -> dict[str, Any]:
        return {"db": str(self.db), "planned": self.planned, "completed": self.completed,
                "passed": self.passed, "errors": self.errors, "reason": self.reason}


# ---------------------------------------------------------------------------
# Creating
# ---------------------------------------------------------------------------


def default_out(name: str, root: Path = Path("runs") / "campaigns") -> Path:
    return root / f"{dt.datetime.now().strftime('%Y%m%d-%H%M%S')}-{name}"


def create_campaign(spec_path: Path | str, out: Path | str | None = None) -> Path:
    """Plan a spec into ``out/campaign.db`` (every trial pending); return the campaign directory.

    The database appears whole or not at all (written aside, then renamed).
    """
    spec = load_campaign_spec(spec_path)
    out = Path(out) if out is not None else default_out(spec.name)
    db = out / DB_NAME
    if db.exists():
        raise CampaignError(f"{out} already holds a campaign; continue it with "
                            f"`hilbench campaign resume {out}` or choose another --out")
    trials = plan_trials(spec)
    out.mkdir(parents=True, exist_ok=True)
    with CampaignLock(out):
        if db.exists():  # another process made it meanwhile
            raise CampaignError(f"{out} already holds a campaign; continue it with "
                                f"`hilbench campaign resume {out}` or choose another --out")
        _write_plan(spec, spec_path, trials, out)
    return out


def _write_plan(spec: Any, spec_path: Path | str, trials: list, out: Path) -> None:
    db = out / DB_NAME
    tmp = out / f".{DB_NAME}.{os.getpid()}.part"
    for p in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
        p.unlink(missing_ok=True)
    axes = find_axes(spec)
    meta = {
        "name": spec.name, "description": spec.description, "seed": spec.seed,
        "spec": spec.model_dump(mode="json"), "spec_file": str(Path(spec_path).resolve()),
        "spec_text": Path(spec_path).read_text(), "base_config": str(resolve_base(spec)),
        "axes": [{"label": a.label, "fault": a.fault, "param": a.param, "kind": a.kind,
                  "args": list(a.args)} for a in axes],
        "backend": trials[0].config["backend"]["kind"], "max_attempts": spec.max_attempts,
        "acceptance": trials[0].config["acceptance"], "target": trials[0].config["target"],
        "created": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }
    with CampaignStore(tmp, create=True) as store:
        store.add_trials(trials, meta)
    os.replace(tmp, db)


def open_store(campaign_dir: Path | str) -> CampaignStore:
    db = Path(campaign_dir) / DB_NAME
    if not db.is_file():
        raise CampaignError(f"no campaign in {campaign_dir} ({DB_NAME} not found); "
                            "start one with `hilbench campaign run SPEC --out DIR`")
    try:
        return CampaignStore(db)
    except CampaignStoreError as e:
        raise CampaignError(str(e)) from None


# ---------------------------------------------------------------------------
# Running
# ---------------------------------------------------------------------------


class _Interrupts:
    """First Ctrl-C sets a flag (finish what is in flight); the second raises KeyboardInterrupt."""

    def __init__(self) -> None:
        self.count = 0
        self._old: Any = None
        self._installed = False

    def _handler(self, signum: int, frame: Any) -> None:
        self.count += 1
        if self.count >= 2:
            signal.signal(signal.SIGINT, self._old)
            raise KeyboardInterrupt

    def __enter__(self) -> "_Interrupts":
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
            self._installed = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self._installed and self.count < 2:
            signal.signal(signal.SIGINT, self._old)


def make_pool(backend: str, to_run: int, workers: int | None, scheduler: str | None,
              notes: list[str], emulate: bool = False) -> Pool:
    """Local processes (default: one per core), a Dask cluster, or this process for the one bus
    (emulated rigs on the virtual clock are one a trial, each in its worker)."""
    if backend == "dynamixel" and not emulate:
        if (workers or 1) > 1 or scheduler:
            notes.append("the real backend has one servo bus: trials run one at a time in this "
                         "process (workers=1)")
        return InlinePool()
    if scheduler:
        return DaskPool(scheduler)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    n = workers or cores
    if n < 1:
        raise CampaignError(f"--workers must be >= 1, got {n}")
    return LocalPool(max(1, min(n, to_run)))


def _stage_root(campaign_dir: Path) -> Path:
    return campaign_dir / TRIALS_DIR / STAGING


def _commit(store: CampaignStore, campaign_dir: Path, row: dict, result: dict, stage: Path) -> None:
    """Move the trial's run directory into place, then record the result in one transaction."""
    run_dir = result.get("run_dir")
    if result["status"] == "done" and run_dir and Path(run_dir).is_dir():
        final = campaign_dir / TRIALS_DIR / row["name"]
        if final.exists():  # left by an earlier attempt whose result was never recorded
            shutil.rmtree(final)
        os.replace(run_dir, final)
        result = {**result, "log_path": str((final / "trial.npz").relative_to(campaign_dir))}
    store.finish(row["id"], result)
    shutil.rmtree(stage, ignore_errors=True)


def run_campaign(campaign_dir: Path | str, workers: int | None = None, scheduler: str | None = None,
                 progress: Optional[Callable[[CampaignProgress], None]] = None,
                 notify: Optional[Callable[[str], None]] = None, report: bool = True) -> CampaignSummary:
    """Run every missing trial (pending, left running, or errored with attempts left).

    The campaign directory's lock is held throughout (:mod:`bench.campaign.lock`): a second
    run or resume of it refuses with :class:`CampaignBusy` while this one lives.
    """
    campaign_dir = Path(campaign_dir)
    if not (campaign_dir / DB_NAME).is_file():
        open_store(campaign_dir)  # refuses, saying there is no campaign there
    with CampaignLock(campaign_dir):
        return _run_locked(campaign_dir, workers, scheduler, progress, notify, report)


def _run_locked(campaign_dir: Path, workers: int | None, scheduler: str | None,
                progress: Optional[Callable[[CampaignProgress], None]],
                notify: Optional[Callable[[str], None]], report: bool) -> CampaignSummary:
    t0 = time.perf_counter()
    say = notify or (lambda msg: None)
    store = open_store(campaign_dir)
    notes: list[str] = []
    interrupted = False
    ran = 0
    pool_desc = ""
    try:
        meta = store.meta()
        todo = store.missing(int(meta.get("max_attempts", 2)))
        planned = store.counts()["planned"]
        state = CampaignProgress(planned=planned, to_run=len(todo))
        shutil.rmtree(_stage_root(campaign_dir), ignore_errors=True)  # leftovers of a killed run
        if progress:
            progress(state)
        if todo:
            emulate = bool(meta.get("spec", {}).get("emulate"))
            pool = make_pool(meta.get("backend", "pybullet"), len(todo), workers, scheduler, notes, emulate)
            pool_desc = pool.description
            for n in notes:
                say(n)
            queue = deque(todo)
            in_flight: dict[Any, tuple[dict, Path]] = {}
            limit = pool.workers + (0 if isinstance(pool, InlinePool) else 1)
            abandon = False
            with _Interrupts() as stop:
                try:
                    stopping = False
                    while (queue and not stop.count) or in_flight:
                        while queue and not stop.count and len(in_flight) < limit:
                            row = store.trial(queue.popleft())
                            stage = _stage_root(campaign_dir) / f"{row['name']}-{uuid.uuid4().hex[:8]}"
                            store.mark_running(row["id"])
                            task = {"id": row["id"], "name": row["name"], "config": row["config"],
                                    "stage": str(stage), "report": False, "emulate": emulate}
                            try:
                                fut = pool.submit(task)
                            except BrokenProcessPool:  # a worker died: a fresh pool for the rest
                                pool.close(abandon=True)
                                pool = make_pool("pybullet", len(queue) + 1, workers, None, [])
                                fut = pool.submit(task)
                            in_flight[fut] = (row, stage)
                        if stop.count and not stopping:
                            stopping = interrupted = True
                            for fut in pool.cancel(list(in_flight)):
                                store.release([in_flight.pop(fut)[0]["id"]])
                            say(f"stopping: {len(in_flight)} trial(s) in flight will finish "
                                "(Ctrl-C again to abandon them)")
                        state.in_flight = len(in_flight)
                        for fut in pool.wait(list(in_flight), timeout=0.25):
                            row, stage = in_flight.pop(fut)
                            try:
                                result = pool.result(fut)
                            except CancelledError:
                                store.release([row["id"]])
                                continue
                            except BrokenProcessPool as e:
                                result = {"status": "error", "error": f"worker process died: {e}"}
                            except Exception as e:  # the pool failed, not the trial
                                result = {"status": "error", "error": f"{type(e).__name__}: {e}"}
                            _commit(store, campaign_dir, row, result, stage)
                            ran += 1
                            state.finished += 1
                            state.errors += result["status"] == "error"
                            state.failed += result["status"] == "done" and not result.get("passed")
                            state.in_flight = len(in_flight)
                            state.last = {"id": row["id"], "name": row["name"], **{
                                k: result.get(k) for k in ("status", "passed", "reason", "error")}}
                            if progress:
                                progress(state)
                except KeyboardInterrupt:
                    interrupted = abandon = True
                finally:
                    if in_flight:
                        pool.cancel(list(in_flight))
                        store.release([row["id"] for row, _ in in_flight.values()])
                        abandon = True
                    pool.close(abandon=abandon)
        counts = store.counts()
        if ran or interrupted:
            session = {"ended": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
                       "wall_s": round(time.perf_counter() - t0, 3), "pool": pool_desc, "ran": ran,
                       "interrupted": interrupted}
            store.set_meta(sessions=[*meta.get("sessions", []), session])
    finally:
        store.close()
    summary = CampaignSummary(campaign_dir / DB_NAME, counts["planned"], counts["done"], counts["passed"],
                              counts["error"], counts["pending"] + counts["running"], interrupted,
                              time.perf_counter() - t0, ran, pool_desc, notes)
    if report and counts["done"]:

        write_campaign_report(campaign_dir)
    return summary


# ---------------------------------------------------------------------------
# One trial again, and the table out
# ---------------------------------------------------------------------------


def rerun_trial(campaign_dir: Path | str, trial_id: int, out: Path | str | None = None,
                report: bool = True) -> dict[str, Any]:
    """Run one planned trial again, here, from its stored config and seed; compare with the record.

    The run directory goes to ``out`` (default ``<campaign>/reruns``); the
    database is not changed. ``identical`` is true when every stored metric
    matches exactly.
    """
    campaign_dir = Path(campaign_dir)
    with open_store(campaign_dir) as store:
        row = store.trial(trial_id)
        emulate = bool(store.meta().get("spec", {}).get("emulate"))
    out = Path(out) if out is not None else campaign_dir / "reruns"
    result = execute_trial({"id": row["id"], "name": row["name"], "config": row["config"],
                            "stage": str(out), "report": report, "emulate": emulate})
    if result["status"] != "done":
        raise CampaignError(f"trial {trial_id} could not run: {result.get('error')}")
    keys = ("completed", "passed", "reason")
    stored = {k: row[k] for k in METRIC_COLUMNS} | {k: row[k] for k in keys}
    stored["completed"] = None if row["completed"] is None else bool(row["completed"])
    stored["passed"] = None if row["passed"] is None else bool(row["passed"])
    again = {k: result["columns"].get(k) for k in METRIC_COLUMNS} | {k: result.get(k) for k in keys}
    return {"trial": trial_id, "name": row["name"], "seed": row["seed"], "run_dir": result["run_dir"],
            "stored_status": row["status"], "identical": row["status"] == "done" and stored == again,
            "stored": stored, "rerun": again}


def summarize(campaign_dir: Path | str) -> CampaignSummary:
    with open_store(campaign_dir) as store, _unreadable(campaign_dir):
        c = store.counts()
        return CampaignSummary(store.path, c["planned"], c["done"], c["passed"], c["error"],
                               c["pending"] + c["running"])


def export_csv(campaign_dir: Path | str, path: Path | str) -> Path:
    with open_store(campaign_dir) as store, _unreadable(campaign_dir):
        return store.export_csv(path)


@contextlib.contextmanager
def _unreadable(campaign_dir: Path | str) -> Iterator[None]:
    """A database that opens but does not hold a campaign's tables or JSON: one line, not a traceback."""
    try:
        yield
    except sqlite3.DatabaseError as e:
        raise CampaignError(f"{campaign_dir}: {DB_NAME} does not hold a campaign ({e})") from None
    except (ValueError, KeyError) as e:
        raise CampaignError(f"{campaign_dir}: {DB_NAME} holds a value that is not what the bench "
                            f"writes ({type(e).__name__}: {str(e)[:80]})") from None
