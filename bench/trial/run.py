"""One trial end to end: config -> checks -> backend -> plan -> run -> outcome -> run directory.

Everything that can be wrong with a trial (the config, the URDF, the target)
is checked by :func:`prepare` before a backend is built, so a bad trial never
moves anything. Whatever happens during the run, the log so far is saved.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.config.models import ConfigError, TrialConfig
from bench.core.interrupts import NO_SIGNALS, TrialInterrupted
from bench.core.log import TrialLog
from bench.core.record import new_run_dir
from bench.core.result import PreparedTrial, TrialError, TrialResult
from bench.core.runner import Interruptible, Runner, abort_reason
from bench.faults import apply_faults, parse_faults
from bench.report.trial import write_trial_report
from bench.rig.backends import make_backend
from bench.trial.plan import interlocks_for, plan, prepare
from bench.trial.record import finish_record, trial_metadata
from drivers import ActuatorError, Actuators
from drivers.capabilities import SafeStopReport, ServoInfo, StartWarnings, find_capability

__all__ = ["run_trial"]


def run_trial(config: TrialConfig, out: Path, gui: bool = False,
              progress: Optional[Callable[[float], None]] = None,
              backend_factory: Optional[Callable[[PreparedTrial], Actuators]] = None,
              wrap: Optional[Callable[[Actuators], Actuators]] = None,
              note: str = "", report: bool = True,
              interrupts: Interruptible = NO_SIGNALS,
              phase: Optional[Callable[[str], None]] = None,
              plan_start: Optional[np.ndarray] = None) -> TrialResult:
    """Run one trial and write its run directory; the log is saved on every exit path.

    ``phase`` hears what the trial is doing ("connecting", "planning", each segment's
    name, "report"), for a progress display.

    ``report=False`` writes only the log and ``result.json`` (no figures), for campaigns.
    ``interrupts`` (a :class:`bench.core.interrupts.SignalGuard`) turns stop signals into
    :class:`TrialInterrupted`, raised once the actuators are safe and the record written.
    ``plan_start``: plan from this pose instead of the first reading, so that a comparison runs
    the rig's very plan on the sim.
    """
    tell = phase or (lambda _: None)
    prep = prepare(config)
    interrupts.check()
    log = TrialLog(list(prep.robot.joint_names), metadata=trial_metadata(prep, note))
    out_existed = Path(out).exists()
    with interrupts.deferred():  # a run directory is never left without its journal
        run_dir = new_run_dir(out, config.name)
        log_path = run_dir / "trial.npz"
        log.journal_to(run_dir)
    backend = None
    tell("connecting")
    try:
        backend = (backend_factory or (lambda p: make_backend(p.config, p.robot, gui)))(prep)
        act = _wrapped(backend, prep, wrap)
    except (ActuatorError, ConfigError, TrialError, ValueError):
        if backend is not None:
            backend.close()
        log.close_journal()
        shutil.rmtree(run_dir, ignore_errors=True)  # refused before anything moved: nothing to keep
        if not out_existed:
            shutil.rmtree(out, ignore_errors=True)
        raise
    except BaseException as e:  # interrupted while the backend was being built
        with interrupts.deferred():
            if backend is not None:
                backend.close()
            log.event(0.0, "abort", abort_reason(e))
            finish_record(run_dir, log, log_path, prep)
        e.run_dir, e.safe_stop = run_dir, "the actuators were never enabled"
        raise
    interrupted: Optional[BaseException] = None
    try:
        try:
            interrupts.check()
            servos = find_capability(act, ServoInfo)
            if servos is not None:
                log.metadata["servos"] = servos.servo_info()
            warned = find_capability(act, StartWarnings)
            if warned is not None and warned.start_warnings:
                log.metadata["warnings"] = list(warned.start_warnings)
            tell("planning")
            q_start = act.read().position if plan_start is None else np.asarray(plan_start, dtype=float)
            segments = plan(prep, q_start, act.limits.velocity)
            interlocks = interlocks_for(prep, act)  # built (and imported) before anything moves
            interrupts.check()  # a signal swallowed during the set-up still stops here
            runner = Runner(act, config.control_period, interlocks=interlocks,
                            on_trip=config.safety.on_trip, progress=progress, interrupts=interrupts,
                            phase=phase)
            runner.run(segments, log)
        finally:
            with interrupts.deferred():  # the safe stop always runs to its end
                act.close()
    except KeyboardInterrupt as e:
        interrupted = e
        _abort_once(log, abort_reason(e))
    except (ActuatorError, ValueError, ArithmeticError) as e:  # lost bus, hardware fault, bad command
        _abort_once(log, abort_reason(e))
    except BaseException as e:
        with interrupts.deferred():
            _abort_once(log, abort_reason(e))
            _note_safe_stop(log, backend)
            finish_record(run_dir, log, log_path, prep)
        raise
    with interrupts.deferred():
        _note_safe_stop(log, backend)
        if interrupted is None and interrupts.interrupted:  # noted while stopping safely
            interrupted = TrialInterrupted(interrupts.signum)
            _abort_once(log, abort_reason(interrupted))
        res = finish_record(run_dir, log, log_path, prep)
    try:
        if interrupted is not None:
            raise interrupted
        if report:

            tell("report")
            write_trial_report(res, log, prep)
        interrupts.check()
    except KeyboardInterrupt as e:  # the record is complete; the report can be rebuilt from it
        e.run_dir = run_dir
        e.safe_stop = _safe_stop_report(backend) or "the actuators were never enabled"
        raise
    return res


def _wrapped(backend: Actuators, prep: PreparedTrial,
             wrap: Optional[Callable[[Actuators], Actuators]]) -> Actuators:
    """The backend inside the config's fault wrappers (a fault it cannot host is refused)."""
    act = backend
    if prep.config.faults:

        specs = parse_faults(prep.config.faults, prep.robot.joint_names)
        act = apply_faults(act, specs, np.random.default_rng(prep.config.seed))
    return wrap(act) if wrap else act


def _abort_once(log: TrialLog, reason: str) -> None:
    if not any(ev.kind == "abort" for ev in log.events):
        log.event(log.time[-1] if len(log) else 0.0, "abort", reason)


def _note_safe_stop(log: TrialLog, backend: Actuators) -> None:
    """Record how the actuators were left (the backend's own read-back where it has one)."""
    report = _safe_stop_report(backend)
    if report:
        log.event(log.time[-1] if len(log) else 0.0, "safe-stop", report)


def _safe_stop_report(backend: Optional[Actuators]) -> Optional[str]:
    """The backend's own account of its last safe stop, when it keeps one."""
    layer = None if backend is None else find_capability(backend, SafeStopReport)
    return None if layer is None else layer.safe_stop_report
