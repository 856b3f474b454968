"""One trial end to end: config -> checks -> backend -> plan -> run -> outcome -> run directory.

Everything that can be wrong with a trial (the config, the URDF, the target)
is checked by :func:`prepare` before a backend is built, so a bad trial never
moves anything. Whatever happens during the run, the log so far is saved.
"""

from __future__ import annotations

import datetime as dt
import json
import platform
import shutil
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.config.models import ConfigError, TrialConfig
from bench.kinematics.needle import NeedleTarget, UnreachableError
from bench.config.calibration import calibration_of, calibration_record
from bench.core.log import JOURNAL_META, JOURNAL_ROWS, TrialLog
from bench.core.outcome import NeedleOutcome, needle_outcome, settled_position
from bench.core.interrupts import NO_SIGNALS, TrialInterrupted
from bench.core.runner import Interruptible, Runner, Segment, abort_reason
from bench.trial.preflight import limits_of, needle_direction_problem, planned_path_trip
from drivers import Actuators, ActuatorError, JointLimits

PACKAGES = ("needle-hil-bench", "numpy", "pybullet", "ruckig", "dynamixel-sdk", "pyserial", "pydantic")


class TrialError(RuntimeError):
    """The trial could not start; nothing moved."""


@dataclass
class PreparedTrial:
    """A trial that passed every check that can be made before anything moves."""

    config: TrialConfig
    robot: object
    target: NeedleTarget
    q_entry: np.ndarray
    q_insert: np.ndarray


@dataclass
class TrialResult:
    run_dir: Path
    log_path: Path
    completed: bool
    reason: str
    outcome: Optional[NeedleOutcome]
    extra: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.completed and self.outcome is not None and self.outcome.passed

    @property
    def why_not(self) -> str:
        """Why the trial did not pass, in one line ("" when it passed)."""
        if self.passed:
            return ""
        if not self.completed:
            return f"stopped early: {self.reason}"
        if self.outcome is None:
            return "no settled insertion to measure"
        return f"outside the acceptance limits: {self.outcome.failures()}"

    def summary(self) -> dict:
        o = self.outcome
        return {
            "run_dir": str(self.run_dir),
            "tip_deviation_mm": o.tip_deviation_mm if o else None,
            "depth_deviation_mm": o.depth_deviation_mm if o else None,
            "angle_deviation_deg": o.angle_deviation_deg if o else None,
            "passed": self.passed,
            "completed": self.completed,
            "reason": self.why_not,
        }


def target_of(config: TrialConfig) -> NeedleTarget:
    t = config.target
    return NeedleTarget(np.array([t.x_mm, t.y_mm, t.z_mm]) * 1e-3, t.depth_mm * 1e-3,
                        np.radians(t.angle_deg), np.radians(t.tilt_deg))


def prepare(config: TrialConfig) -> PreparedTrial:
    """Check the URDF and solve the target; raise TrialError naming the problem."""
    from bench.kinematics.registry import get_robot

    robot = get_robot(config.robot)
    if not config.robot_urdf.is_file():
        raise TrialError(f"robot URDF not found: {config.robot_urdf} (urdf_dir: {config.urdf_dir})")
    for name in ("ct_gantry", "ct_bed", "phantom"):
        p = config.resolve(config.urdf_dir) / f"{name}.urdf"
        if not p.is_file():
            raise TrialError(f"scene URDF not found: {p} (urdf_dir: {config.urdf_dir})")
    target = target_of(config)
    try:
        q_insert = robot.ik(target)
    except UnreachableError as e:
        raise TrialError(f"target: {e}") from None
    q_entry = q_insert.copy()
    q_entry[robot.joint_names.index(robot.insertion_joint)] = 0.0
    prep = PreparedTrial(config, robot, target, q_entry, q_insert)
    problem = needle_direction_problem(robot, q_insert, config.target.angle_deg)
    if problem:
        raise TrialError(problem)
    _check_plan(prep)
    return prep


def _check_plan(prep: PreparedTrial) -> None:
    """Refuse a plan that would run longer than MAX_PLAN_S from home (a typo, not a trial),
    or whose path from home, followed perfectly, would trip the trial's interlocks."""
    from bench.config.models import MAX_PLAN_S
    from trajectories import TrajectoryError

    limits = planned_limits(prep)
    try:
        segments = plan(prep, prep.robot.chain.home, limits.velocity)
    except (TrajectoryError, ValueError) as e:
        raise TrialError(f"plan: {e}") from None
    total = sum(s.trajectory.duration + s.settle for s in segments)
    if not total <= MAX_PLAN_S:
        raise TrialError(f"plan: the trial would last {total:.0f} s from home, more than the "
                         f"{MAX_PLAN_S:.0f} s allowed; raise plan.velocity_scale or "
                         f"plan.acceleration_scale, or shorten plan.settle_s")
    if not prep.config.safety.refuse_planned_trips:
        return
    trip = planned_path_trip(segments, interlocks_for(prep, limits), prep.config.control_period)
    if trip is not None:
        raise TrialError(trip.message())


def planned_limits(prep: PreparedTrial) -> JointLimits:
    """The joint limits the backend will have: the robot's, with the backend's overrides."""
    return limits_of(prep.robot.chain.rows, getattr(prep.config.backend, "joints", None))


def make_backend(prep: PreparedTrial, gui: bool = False) -> Actuators:
    """The configured backend, inactive (reading allowed, commands refused)."""
    cfg = prep.config
    if cfg.backend.kind == "pybullet":
        from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings, SceneObject

        b = cfg.backend
        chain = prep.robot.chain
        limits = planned_limits(prep)
        effort, velocity = limits.effort.tolist(), limits.velocity.tolist()
        d = cfg.resolve(cfg.urdf_dir)
        scene = [SceneObject(d / "ct_gantry.urdf", collide=b.gantry_in_physics),
                 SceneObject(d / "ct_bed.urdf"), SceneObject(d / "phantom.urdf")]
        settings = PyBulletSettings(
            robot_urdf=cfg.robot_urdf, joint_names=prep.robot.joint_names, scene=scene,
            physics_hz=b.physics_hz, control_period=cfg.control_period, max_effort=effort,
            max_velocity=velocity, position_gain=b.position_gain, velocity_gain=b.velocity_gain,
            initial_position=chain.home, gui=gui, safe_stop=b.safe_stop,
            solver_iterations=b.solver_iterations)
        return PyBulletActuators(settings)
    if cfg.backend.kind == "dynamixel":
        return make_dynamixel_backend(prep)
    raise ConfigError(f"backend.kind: unknown backend {cfg.backend.kind!r}")


def make_dynamixel_backend(prep: PreparedTrial) -> Actuators:
    """The Dynamixel backend from a config (ports, IDs, models, transmissions)."""
    from bench.config.models import model_number
    from drivers.dynamixel.backend import (
        DynamixelActuators, DynamixelSettings, ServoSettings, UltrasonicSettings,
    )

    b = prep.config.backend
    cal = calibration_of(prep.config)  # zero offsets and ultrasonic mapping, if the config names one
    rows = prep.robot.chain.rows
    servos = [ServoSettings(joint=n, id=sc.id, model=model_number(sc.model), mode=sc.mode,
                            ratio=sc.ratio, offset=cal.offset(n, sc.offset) if cal else sc.offset,
                            current_limit_a=sc.current_limit_a,
                            gains=(sc.position_p, sc.position_i, sc.position_d))
              for n, sc in b.servos.items()]
    ultra = None
    if b.ultrasonic is not None:
        from bench.kinematics.arc_train import epsilon_from_d2

        u = b.ultrasonic
        standoff = u.standoff_mm * 1e-3
        params = prep.robot.params
        opts = u.sensor_options()
        ultra = UltrasonicSettings(port=u.port, joint=u.joint, baud=u.baud,
                                   median_window=u.median_window, stale_after_s=u.stale_after_s,
                                   rate_hz=u.rate_hz, range_m=opts["range_m"],
                                   no_target_m=opts["no_target_m"],
                                   to_joint=lambda d: float(epsilon_from_d2(
                                       cal.d2(d, standoff) if cal else d - standoff, params)))
    settings = DynamixelSettings(
        port=b.port, baud=b.baud, servos=servos, joint_names=prep.robot.joint_names,
        lower=[r.lower for r in rows], upper=[r.upper for r in rows],
        velocity=[r.velocity for r in rows], effort=[r.effort for r in rows],
        return_delay_us=b.return_delay_us, fast_sync_read=b.fast_sync_read, retries=b.retries,
        timeout_s=b.timeout_ms * 1e-3 if b.timeout_ms else None,
        safe_stop=b.safe_stop, reboot_on_hardware_error=b.reboot_on_hardware_error,
        ultrasonic=ultra)
    return DynamixelActuators(settings)


def plan(prep: PreparedTrial, q_start: np.ndarray, limits_velocity: np.ndarray) -> list[Segment]:
    """home -> entry pose -> insertion along the needle axis -> retract."""
    from trajectories import LSPB, Limits, RuckigOnline, RuckigTrajectory

    p = prep.config.plan
    vmax = limits_velocity * p.velocity_scale
    amax = vmax * p.acceleration_scale
    jmax = amax * p.jerk_scale
    dt_ctrl = prep.config.control_period

    def traj(a: np.ndarray, b: np.ndarray):
        if p.trajectory == "lspb":
            return LSPB(a, b, vmax, amax)
        if p.trajectory == "ruckig":
            return RuckigTrajectory(a, b, Limits(vmax, amax, jmax))
        return RuckigOnline(a, b, Limits(vmax, amax, jmax), dt_ctrl)

    segs = [Segment("approach", traj(q_start, prep.q_entry), p.settle_s),
            Segment("insert", traj(prep.q_entry, prep.q_insert), p.settle_s)]
    if p.retract:
        segs.append(Segment("retract", traj(prep.q_insert, prep.q_entry), 0.0))
    return segs


def interlocks_for(prep: PreparedTrial, act: Actuators | JointLimits):
    """The configured interlocks for this robot and backend (None when disabled).

    ``act``: the backend, or the limits it will have (to replay a plan before it exists)."""
    from bench.core.safety import (
        GantryClearanceInterlock, Interlocks, JointLimitInterlock, StaleDataInterlock,
        TrackingErrorInterlock, VelocityLimitInterlock,
    )

    s = prep.config.safety
    if not s.enabled:
        return None
    names = list(prep.robot.joint_names)
    kinds = [r.kind for r in prep.robot.chain.rows]
    lim = act if isinstance(act, JointLimits) else act.limits
    tol = s.joint_limit_tolerance
    bound = [np.radians(s.tracking_error_deg) if k == "revolute" else s.tracking_error_mm * 1e-3
             for k in kinds]
    checks = [JointLimitInterlock(lim.lower - tol, lim.upper + tol, names, kinds=kinds),
              VelocityLimitInterlock(lim.velocity, names, s.velocity_factor, kinds=kinds),
              TrackingErrorInterlock(bound, names, kinds=kinds)]
    if s.stale_data:
        checks.append(StaleDataInterlock())
    if s.gantry_margin_mm > 0:
        checks.append(GantryClearanceInterlock(prep.robot, s.gantry_margin_mm * 1e-3,
                                               lookahead_s=s.gantry_lookahead_s))
    return Interlocks(checks)


def package_versions() -> dict[str, str]:
    out = {}
    for name in PACKAGES:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = "not installed"
    out["python"] = platform.python_version()
    return out


def new_run_dir(out: Path, name: str) -> Path:
    """A fresh, dated directory for one run, always inside ``out``."""
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out)
    base = out / f"{stamp}-{name}"
    if base.resolve().parent != out.resolve():
        raise TrialError(f"name {name!r} would put the run outside {out}")
    run_dir, i = base, 1
    while run_dir.exists():
        i += 1
        run_dir = base.with_name(f"{base.name}-{i}")
    run_dir.mkdir(parents=True)
    return run_dir


def run_trial(config: TrialConfig, out: Path, gui: bool = False,
              progress: Optional[Callable[[float], None]] = None,
              backend_factory: Optional[Callable[[PreparedTrial], Actuators]] = None,
              wrap: Optional[Callable[[Actuators], Actuators]] = None,
              note: str = "", report: bool = True,
              interrupts: Interruptible = NO_SIGNALS,
              phase: Optional[Callable[[str], None]] = None) -> TrialResult:
    """Run one trial and write its run directory; the log is saved on every exit path.

    ``phase`` hears what the trial is doing ("connecting", "planning", each segment's
    name, "report"), for a progress display.

    ``report=False`` writes only the log and ``result.json`` (no figures), for campaigns.
    ``interrupts`` (a :class:`bench.core.interrupts.SignalGuard`) turns stop signals into
    :class:`TrialInterrupted`, raised once the actuators are safe and the record written.
    """
    tell = phase or (lambda _: None)
    prep = prepare(config)
    interrupts.check()
    log = TrialLog(list(prep.robot.joint_names), metadata=_metadata(prep, note))
    out_existed = Path(out).exists()
    with interrupts.deferred():  # a run directory is never left without its journal
        run_dir = new_run_dir(out, config.name)
        log_path = run_dir / "trial.npz"
        log.journal_to(run_dir)
    backend = None
    tell("connecting")
    try:
        backend = (backend_factory or (lambda p: make_backend(p, gui)))(prep)
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
            _finish_record(run_dir, log, log_path, prep)
        e.run_dir, e.safe_stop = run_dir, "the actuators were never enabled"
        raise
    interrupted: Optional[BaseException] = None
    try:
        try:
            interrupts.check()
            if hasattr(backend, "servo_info"):
                log.metadata["servos"] = backend.servo_info()
            if getattr(getattr(backend, "settings", None), "warnings", None):
                log.metadata["warnings"] = list(backend.settings.warnings)
            tell("planning")
            q_start = act.read().position
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
            _finish_record(run_dir, log, log_path, prep)
        raise
    with interrupts.deferred():
        _note_safe_stop(log, backend)
        if interrupted is None and interrupts.interrupted:  # noted while stopping safely
            interrupted = TrialInterrupted(interrupts.signum)
            _abort_once(log, abort_reason(interrupted))
        res = _finish_record(run_dir, log, log_path, prep)
    try:
        if interrupted is not None:
            raise interrupted
        if report:
            from bench.report.trial import write_trial_report

            tell("report")
            write_trial_report(res, log, prep)
        interrupts.check()
    except KeyboardInterrupt as e:  # the record is complete; the report can be rebuilt from it
        e.run_dir = run_dir
        e.safe_stop = getattr(backend, "safe_stop_report", None) or "the actuators were never enabled"
        raise
    return res


def _wrapped(backend: Actuators, prep: PreparedTrial,
             wrap: Optional[Callable[[Actuators], Actuators]]) -> Actuators:
    """The backend inside the config's fault wrappers (a fault it cannot host is refused)."""
    act = backend
    if prep.config.faults:
        from bench.faults import apply_faults, parse_faults

        specs = parse_faults(prep.config.faults, prep.robot.joint_names)
        act = apply_faults(act, specs, np.random.default_rng(prep.config.seed))
    return wrap(act) if wrap else act


def _metadata(prep: PreparedTrial, note: str) -> dict:
    config = prep.config
    return {
        "config": json.loads(config.model_dump_json()),
        "config_file": str(config.source) if config.source else None,
        "calibration": calibration_record(config),  # path and content, or None
        "robot": config.robot, "backend": config.backend.kind, "seed": config.seed,
        "start_time": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(), "note": note,
        "target": {"entry_m": prep.target.entry.tolist(), "depth_m": prep.target.depth,
                   "angle_rad": prep.target.angle, "tilt_rad": prep.target.tilt},
        "q_entry": prep.q_entry.tolist(), "q_insert": prep.q_insert.tolist(),
        "control_period": config.control_period,
    }


def _abort_once(log: TrialLog, reason: str) -> None:
    if not any(ev.kind == "abort" for ev in log.events):
        log.event(log.time[-1] if len(log) else 0.0, "abort", reason)


def _note_safe_stop(log: TrialLog, backend: Actuators) -> None:
    """Record how the actuators were left (the backend's own read-back where it has one)."""
    report = getattr(backend, "safe_stop_report", None)
    if report:
        log.event(log.time[-1] if len(log) else 0.0, "safe-stop", report)


def _finish_record(run_dir: Path, log: TrialLog, log_path: Path, prep: PreparedTrial) -> TrialResult:
    """The log, record.json and result.json on disk; the journal removed once they are."""
    log.flush()
    log.save(log_path)
    write_record(run_dir, log_path)
    log.close_journal()
    res = result_from_log(run_dir, log, prep)
    write_result_json(res)
    return res


def status_from_log(log: TrialLog) -> tuple[bool, str]:
    """(completed, why it stopped early) from the log's events alone."""
    kinds = [e.kind for e in log.events]
    if "done" in kinds:
        return True, ""
    for e in reversed(log.events):
        if e.kind == "abort":
            return False, e.message
        if e.kind == "interlock":
            return False, f"interlock {e.message}"
    return False, "the log ends before the plan did"


def result_from_log(run_dir: Path, log: TrialLog, prep: PreparedTrial) -> TrialResult:
    """The trial's result computed from its log, identically at the end of a trial and later."""
    cfg = prep.config
    outcome = None
    try:
        q_final = settled_position(log, "insert")
        outcome = needle_outcome(prep.robot, q_final, prep.target,
                                 cfg.acceptance.position_mm, cfg.acceptance.angle_deg)
    except (KeyError, ValueError):
        pass
    completed, reason = status_from_log(log)
    return TrialResult(Path(run_dir), Path(run_dir) / "trial.npz", completed, reason, outcome)


def write_result_json(res: TrialResult) -> None:
    summary = res.summary()
    summary.update({"completed": res.completed, "reason": res.reason,
                    "outcome": res.outcome.as_dict() if res.outcome else None})
    (res.run_dir / "result.json").write_text(json.dumps(summary, indent=2) + "\n")


def sha256_of(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_record(run_dir: Path, log_path: Path) -> Path:
    """record.json: the log's checksum, so a report is only ever rebuilt from the true log."""
    rec = {"log": log_path.name, "sha256": sha256_of(log_path), "bytes": log_path.stat().st_size}
    path = Path(run_dir) / "record.json"
    path.write_text(json.dumps(rec, indent=2) + "\n")
    return path


def load_record(run_dir: Path) -> tuple[TrialLog, PreparedTrial]:
    """The log and the prepared trial of a run directory, after checking the log's checksum."""
    run_dir = Path(run_dir)
    rec_path = run_dir / "record.json"
    if not rec_path.is_file() and (run_dir / JOURNAL_META).is_file():
        recover_run(run_dir)
    if not rec_path.is_file():
        raise TrialError(f"{run_dir} has no record.json: not a trial run directory")
    rec = json.loads(rec_path.read_text())
    log_path = run_dir / rec["log"]
    if not log_path.is_file():
        raise TrialError(f"{log_path} is missing")
    if sha256_of(log_path) != rec["sha256"]:
        raise TrialError(f"{log_path.name} does not match the checksum in record.json: "
                         f"the log was modified after the trial")
    log = TrialLog.load(log_path)
    try:
        config = TrialConfig.model_validate(log.metadata["config"])
    except Exception as e:  # a record written by an incompatible version
        raise TrialError(f"the config stored in {log_path.name} is not readable: {e}") from None
    return log, prepare(config)


def recover_run(run_dir: Path) -> Path:
    """trial.npz and record.json of a trial whose process was killed, from its journal."""
    log = TrialLog.recover(run_dir)
    if not any(e.kind in ("done", "abort") for e in log.events):
        log.event(log.time[-1] if len(log) else 0.0, "abort",
                  "the trial's process ended without saving its log (killed?); "
                  "recovered from the journal")
    log_path = Path(run_dir) / "trial.npz"
    log.save(log_path)
    write_record(run_dir, log_path)
    for name in (JOURNAL_ROWS, JOURNAL_META):
        (Path(run_dir) / name).unlink(missing_ok=True)
    return log_path


def rebuild_report(run_dir: Path) -> TrialResult:
    """Write the report of a run directory again, from its record alone."""
    from bench.report.trial import write_trial_report

    log, prep = load_record(run_dir)
    res = result_from_log(run_dir, log, prep)
    write_trial_report(res, log, prep)
    return res
