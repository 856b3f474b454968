"""One prepared trial end to end: build the backend -> run the plan -> record the run directory.

Everything that can be wrong with a trial (the config, the URDF, the target, the plan) was
found by :func:`bench.trial.plan.prepare`, which also loaded what the run applies (the
calibration, the faults, the limits, the interlocks, the checked plan). This module only
builds, runs and records; whatever happens during the run, the log so far is saved.
"""

from __future__ import annotations

import contextlib
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.config.models import ConfigError
from bench.core.interrupts import NO_SIGNALS, TrialInterrupted
from bench.core.log import TrialLog
from bench.core.record import new_run_dir
from bench.core.result import PreparedTrial, TrialError, TrialResult
from bench.core.truth import GroundTruth
from bench.core.runner import Interruptible, Runner, abort_reason, safe_now
from bench.faults import apply_faults
from bench.monitor.build import build_monitor
from bench.monitor.monitor import Watched
from bench.report.trial import write_trial_report
from bench.rig.backends import make_backend
from bench.rig.serving import bus_rig_kind
from bench.trial.cameras import BackendReading, TrialCaptures, open_cameras
from bench.trial.plan import aimed_plan
from bench.trial.record import finish_record, trial_metadata
from drivers import ActuatorError, Actuators, ActuatorsWrapper
from drivers.capabilities import SafeStopReport, ServoInfo, StartWarnings, TruePosition, find_capability
from drivers.link import is_virtual_port
from drivers.timing import CpuWithheld, LoopPriority

__all__ = ["TrialHooks", "run_trial"]


@dataclass
class TrialHooks:
    """What a caller adds to a trial: how it is told and reported, and what it wraps.

    ``progress`` hears the fraction of the current segment; ``phase`` what the trial is doing
    ("connecting", "planning", each segment's name, "report"). ``interrupts`` (a
    :class:`bench.core.interrupts.SignalGuard`) turns stop signals into
    :class:`TrialInterrupted`, raised once the actuators are safe and the record written.
    ``report=False`` writes only the log, the record and ``result.json`` (no figures).
    ``backend``: an already-open backend to run on (a comparison's homed rig) instead of
    building the config's; ``wrap``: the outermost layer around the fault stack (a campaign's
    ground-truth recorder)."""

    note: str = ""
    report: bool = True
    gui: bool = False
    progress: Optional[Callable[[float], None]] = None
    phase: Optional[Callable[[str], None]] = None
    interrupts: Interruptible = NO_SIGNALS
    backend: Optional[Callable[[PreparedTrial], Actuators]] = None
    wrap: Optional[Callable[[Actuators], Actuators]] = None

    def tell(self, what: str) -> None:
        if self.phase is not None:
            self.phase(what)


def run_trial(prep: PreparedTrial, out: Path, hooks: Optional[TrialHooks] = None) -> TrialResult:
    """Run one prepared trial and write its run directory; the log is saved on every exit path."""
    hooks = hooks or TrialHooks()
    interrupts = hooks.interrupts
    interrupts.check()
    log = TrialLog(list(prep.robot.joint_names), metadata=trial_metadata(prep, hooks.note))
    out_existed = Path(out).exists()
    with interrupts.deferred():  # a run directory is never left without its journal
        run_dir = new_run_dir(out, prep.config.name)
        log.journal_to(run_dir)
    with _loop_priority(prep, log):
        backend, act, truth = _build(prep, hooks, run_dir, log, Path(out), out_existed)
        interrupted = _run(prep, hooks, act, backend, log, run_dir)
    with interrupts.deferred():
        _note_safe_stop(log, backend)
        if interrupted is None and interrupts.interrupted:  # noted while stopping safely
            interrupted = TrialInterrupted(interrupts.signum)
            _abort_once(log, abort_reason(interrupted))
        res = finish_record(run_dir, log, prep, truth)
    try:
        if interrupted is not None:
            raise interrupted
        if hooks.report:
            hooks.tell("report")
            write_trial_report(res, log, prep)
        interrupts.check()
    except KeyboardInterrupt as e:  # the record is complete; the report can be rebuilt from it
        e.run_dir = run_dir
        e.safe_stop = _safe_stop_report(backend) or "the actuators were never enabled"
        raise
    return res


@contextlib.contextmanager
def _loop_priority(prep: PreparedTrial, log: TrialLog):
    """A paced trial (a servo bus, real or emulated) runs ahead of the browser and other jobs on the
    bench computer, where the OS allows; the log says what it got. A simulator's loop has no
    deadline, so it keeps its priority and never crowds the machine."""
    if prep.config.backend.kind != "dynamixel" or is_virtual_port(prep.config.backend.port):
        yield  # a virtual clock's deadlines do not depend on the machine either
        return
    withheld = CpuWithheld()  # what the machine withheld from the loop: the record says it
    with LoopPriority() as priority:
        log.metadata["loop_priority"] = priority.got
        try:
            with withheld:
                yield
        finally:
            log.metadata["loop_cpu_waited_s"] = withheld.waited_s
            log.metadata["loop_cpu_stolen_s"] = withheld.stolen_s


def _build(prep: PreparedTrial, hooks: TrialHooks, run_dir: Path, log: TrialLog, out: Path,
           out_existed: bool) -> tuple[Actuators, Actuators, GroundTruth]:
    """The backend (inactive), the stack the trial drives (the prepared faults around it, the
    ground-truth recorder around them, the caller's wrap outermost) and the recorder. Refused
    before anything moved: the run directory is removed."""
    backend = None
    try:  # from the first step after the run directory exists, a signal leaves it a record
        hooks.tell("connecting")
        if hooks.backend is not None:
            backend = hooks.backend(prep)
        else:
            backend = make_backend(prep.config, prep.robot, hooks.gui, calibration=prep.calibration)
        act = backend
        if prep.config.cameras is not None and find_capability(backend, TruePosition) is None:
            act = BackendReading(backend)  # where an emulated rig's cameras see the joints
        if prep.faults:  # a fault the backend cannot host is refused here
            act = apply_faults(act, prep.faults, np.random.default_rng(prep.config.seed))
        truth = GroundTruth(act)  # where the joints really are, where the backend knows it
        return backend, (hooks.wrap(truth) if hooks.wrap else truth), truth
    except (ActuatorError, ConfigError, TrialError, ValueError):
        if backend is not None:
            backend.close()
        log.close_journal()
        shutil.rmtree(run_dir, ignore_errors=True)  # refused before anything moved: nothing to keep
        if not out_existed:
            shutil.rmtree(out, ignore_errors=True)
        raise
    except BaseException as e:  # interrupted while the backend was being built
        with hooks.interrupts.deferred():
            if backend is not None:
                backend.close()
            log.event(0.0, "abort", abort_reason(e))
            finish_record(run_dir, log, prep)
        e.run_dir, e.safe_stop = run_dir, "the actuators were never enabled"
        raise


def _run(prep: PreparedTrial, hooks: TrialHooks, act: Actuators, backend: Actuators, log: TrialLog,
         run_dir: Path) -> Optional[BaseException]:
    """Run the prepared plan from the first reading; the actuators are always closed (their safe
    stop). Returns the interrupt that stopped it, if one did; other failures are logged."""
    interrupts = hooks.interrupts
    monitor = None if prep.monitor is None else build_monitor(prep.monitor, log)
    cameras = TrialCaptures(None, log)
    try:
        try:
            interrupts.check()
            servos = find_capability(act, ServoInfo)
            if servos is not None:
                log.metadata["servos"] = servos.servo_info()
                log.metadata["rig"] = bus_rig_kind(log.metadata.get("rig"), log.metadata["servos"])
            warned = find_capability(act, StartWarnings)
            if warned is not None and warned.start_warnings:
                log.metadata["warnings"] = list(warned.start_warnings)
            cameras = open_cameras(prep, act, log, _innermost(act, BackendReading))
            if not act.enabled:  # torque on first: a joint taking up its load moves while its
                act.enable()     # servo settles, and the plan starts from where it then holds
            hooks.tell("planning")
            segments = aimed_plan(prep, act.read().position)
            interrupts.check()  # a signal swallowed during the set-up still stops here
            checks = prep.interlocks if monitor is None else Watched(prep.interlocks, monitor)
            runner = Runner(act, prep.config.control_period, interlocks=checks,
                            on_trip=prep.config.safety.on_trip, progress=hooks.progress,
                            interrupts=interrupts, phase=cameras.phase(hooks.phase))
            if runner.run(segments, log).completed:
                cameras.settled(log)
        finally:
            with interrupts.deferred():  # the safe stop always runs to its end
                act.close()
                if monitor is not None:
                    log.metadata["monitor"] = monitor.summary()
                    monitor.close()
                cameras.finish(run_dir)
    except KeyboardInterrupt as e:
        _abort_once(log, abort_reason(e))
        return e
    except (ActuatorError, ValueError, ArithmeticError) as e:  # lost bus, hardware fault, bad command
        _abort_once(log, abort_reason(e))
    except BaseException as e:
        with interrupts.deferred():
            _abort_once(log, abort_reason(e))
            _note_safe_stop(log, backend)
            finish_record(run_dir, log, prep)
        raise
    return None


def _innermost(act: Actuators, kind: type):
    """The wrapper of type ``kind`` in the stack, if there is one."""
    layer = act
    while isinstance(layer, ActuatorsWrapper):
        if isinstance(layer, kind):
            return layer
        layer = layer.actuators
    return None


def _abort_once(log: TrialLog, reason: str) -> None:
    if not any(ev.kind == "abort" for ev in log.events):
        log.event(log.time[-1] if len(log) else 0.0, "abort", reason)


def _note_safe_stop(log: TrialLog, backend: Actuators) -> None:
    """Record how the actuators were left (the backend's own read-back where it has one)."""
    report = _safe_stop_report(backend)
    if report:  # on the backend's clock when it still reads (the stop came after the last row)
        log.event(safe_now(backend), "safe-stop", report)


def _safe_stop_report(backend: Optional[Actuators]) -> Optional[str]:
    """The backend's own account of its last safe stop, when it keeps one."""
    layer = None if backend is None else find_capability(backend, SafeStopReport)
    return None if layer is None else layer.safe_stop_report
