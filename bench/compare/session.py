"""Run one plan N times on the sim backend and on the real (or emulated) rig, then compare.

The sim counterpart of a lab config is the same trial — name, robot, target,
plan, control rate, acceptance, safety and faults — with the backend replaced
by the PyBullet defaults, so both backends run the same plan.

The rig's repeats follow the paper's protocol: every repeat starts from home.
Before each repeat the needle is withdrawn and the arm brought home at the
plan's speed and held there until every joint has arrived (0.2° / 0.2 mm, the
train 0.5° as its sensor resolves it, for 0.5 s, at most 5 s), in the same driver session as the trial that
follows; between repeats the servos hold (``safe_stop: hold``) so the arm
does not drop. The config's own
safe stop is applied after the last repeat and whenever the session ends
early (a repeat that stopped, an error, Ctrl-C).

Nothing moves before every check has passed: the config, the target, and on
real hardware the ports (named in the error when missing). With ``emulate``
the emulator (``hilbench emulate``) runs once, in a child process, for all
repeats. It shares the host's CPU with the trials, and a starved emulator
looks like a lost bus (``CommunicationError``) or a silent sensor (the
stale-data interlock); a repeat lost that way is run again, up to
``retries`` times, and the lost attempt is listed in the report. On real
hardware (``retries`` 0 by default) a repeat that stops ends the session.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.compare.analysis import Comparison, compare_logs
from bench.compare.prediction import Prediction, prediction
from bench.compare.report import write_compare_report
from bench.config.models import ConfigError, PyBulletBackendConfig, TrialConfig
from bench.core.interrupts import NO_SIGNALS
from bench.core.log import TrialLog
from bench.core.record import new_run_dir
from bench.core.result import TrialError
from bench.core.runner import Interruptible, Runner, Segment
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend
from bench.rig.emulated import EmulatorProcess
from bench.trial.plan import prepare
from bench.trial.run import run_trial
from drivers import ActuatorError, Actuators, BenchError, CommunicationError
from drivers.errors import CompareError
from trajectories import LSPB

__all__ = ["CompareError", "LostAttempt", "SessionResult", "check_real_ports", "home_rig",
           "run_comparison", "sim_counterpart"]

#: Bus retries per transaction against the emulator (the most a config allows), so that a
#: busy host's pauses of up to about 0.2 s do not end a repeat.
EMULATED_RETRIES = 20

HOME_TOLERANCE_RAD = np.radians(0.2)  #: at home: every revolute joint within this (rad) ...
#: ... a revolute joint whose servo integrates (Position I Gain > 0) within this: about one encoder
#: tick, the hunt of a holding servo. Its integrator takes the sag out over seconds; a repeat that
#: starts before it has is planned from a pose the servo is still leaving, and its first command
#: meets an integrator charged for home, a kick no sim started at rest can show ...
HOME_INTEGRATING_RAD = np.radians(0.1)
HOME_TOLERANCE_M = 0.2e-3  #: ... and every slide within this (m) ...
HOME_SENSED_RAD = np.radians(0.5)  #: ... a joint read by the ultrasonic sensor (1 mm of d2) within this ...
HOME_STILL_S = 0.5  #: ... for this long (s) ...
HOME_TIMEOUT_S = 15.0  #: ... or at most this long after the homing move (s)

ProgressFn = Callable[[str, float], None]  # (what is running, fraction of the whole session)


@dataclass(frozen=True)
class LostAttempt:
    """A rig repeat that stopped early and was run again."""

    repeat: int
    run_dir: str
    reason: str


@dataclass
class SessionResult:
    out_dir: Path
    comparison: Comparison
    sim_runs: list[Path]
    real_runs: list[Path]
    lost: list[LostAttempt] = field(default_factory=list)
    emulated: bool = False
    notes: list[str] = field(default_factory=list)
    #: With a servo model: the ideal sim against the rig, and how much better the model predicts it.
    ideal: Optional[Comparison] = None
    prediction: Optional[Prediction] = None
    #: How the rig was left at the end, in its backend's words ("" if it never moved).
    safe_stop: str = ""


def sim_counterpart(config: TrialConfig, servo_model: str = "ideal") -> TrialConfig:
    """The same trial on the PyBullet backend with its default settings (validated); with a
    ``servo_model``, the sim runs the rig's servo table (models, gains, transmissions) through it."""
    data = json.loads(config.model_dump_json())
    rig = data["backend"]
    data["backend"] = json.loads(PyBulletBackendConfig().model_dump_json())
    if servo_model != "ideal":
        data["backend"].update(servo_model=servo_model, servos=rig.get("servos", {}),
                               ultrasonic=rig.get("ultrasonic"))
    try:
        return TrialConfig.model_validate({**data, "source": config.source})
    except Exception as e:  # pydantic's message, one line
        raise ConfigError(f"{config.source or config.name}: no sim counterpart: "
                          f"{str(e).splitlines()[0]}") from None


def check_real_ports(config: TrialConfig) -> None:
    """Every port of the rig exists and is readable and writable, else CompareError naming it."""
    b = config.backend
    if b.kind != "dynamixel":
        raise CompareError(f"{config.source or config.name}: the real side needs backend.kind: "
                           f"dynamixel (this config is {b.kind})")
    ports = [("backend.port", "servo bus", b.port)]
    if b.ultrasonic is not None:
        ports.append(("backend.ultrasonic.port", "ultrasonic sensor", b.ultrasonic.port))
    for field_name, what, port in ports:
        if not os.path.exists(port):
            raise CompareError(f"{field_name}: {what} port {port} not found (is the adapter plugged "
                               f"in?); nothing moved. Rehearse without hardware with --emulate")
        if not os.access(port, os.R_OK | os.W_OK):
            raise CompareError(f"{field_name}: no read/write permission on {what} port {port}; "
                               f"nothing moved")


def _with_safe_stop(config: TrialConfig, safe_stop: str) -> TrialConfig:
    return config.model_copy(update={"backend": config.backend.model_copy(update={"safe_stop": safe_stop})})


def home_rig(config: TrialConfig, log_path: Optional[Path] = None) -> Actuators:
    """Withdraw the needle, bring the arm home at the plan's speed and hold it there until
    it has arrived (:func:`_hold_until_home`).

    Returns the config's backend still enabled and holding home, for the trial
    that follows to run in the same session (no hand-over between two drivers,
    in which the arm would relax). The caller closes it; on an error it is
    closed here. The homing log is saved to ``log_path``.
    """

    prep = prepare(config)
    robot = prep.robot
    home = robot.chain.home
    ins = robot.joint_names.index(robot.insertion_joint)
    p = config.plan
    act = make_backend(prep.config, prep.robot)
    log = TrialLog(list(robot.joint_names), metadata={"purpose": "homing before a repeat",
                                                        "robot": config.robot})
    try:
        act.enable()
        q0 = act.read().position
        vmax = act.limits.velocity * p.velocity_scale
        amax = vmax * p.acceleration_scale
        withdrawn = q0.copy()
        withdrawn[ins] = home[ins]
        segs = [Segment("withdraw", LSPB(q0, withdrawn, vmax, amax), 0.0),
                Segment("home", LSPB(withdrawn, home, vmax, amax), 0.0)]
        Runner(act, config.control_period).run(segs, log)
        tol = np.array([_home_tolerance(config, name, row.kind)
                        for name, row in zip(robot.joint_names, robot.chain.rows)])
        u = getattr(config.backend, "ultrasonic", None)
        if u is not None:
            tol[list(robot.joint_names).index(u.joint)] = HOME_SENSED_RAD
        log.metadata["home_reached_s"] = _hold_until_home(act, home, tol, config.control_period, log)
    except BaseException:
        act.close()
        raise
    finally:
        if log_path is not None:
            log.save(log_path)
    return act


def _home_tolerance(config: TrialConfig, joint: str, kind: str) -> float:
    """How close to home a joint must stay (rad or m): see HOME_TOLERANCE_RAD and what follows it."""
    if kind != "revolute":
        return HOME_TOLERANCE_M
    servo = (getattr(config.backend, "servos", None) or {}).get(joint)
    return HOME_INTEGRATING_RAD if servo is not None and (servo.position_i or 0) > 0 else HOME_TOLERANCE_RAD


def _hold_until_home(act: Actuators, home: np.ndarray, tol: np.ndarray, period: float,
                     log: TrialLog) -> float:
    """Keep commanding home until every joint has stayed within HOME_TOLERANCE of it for
    HOME_STILL_S (the servos' integrators take out the gravity sag), or HOME_TIMEOUT_S.

    A trial plans from the measured start pose: starting it while a servo still sags
    would move that servo's goal away from where its integrator is pushing, and the
    kick would show up as tracking error that is not the plan's. Returns the time
    taken (s), NaN on timeout.
    """
    zero = np.zeros_like(home)
    t0 = t = act.now()
    since: Optional[float] = None
    while t - t0 < HOME_TIMEOUT_S:
        st = act.read()
        log.append(st.time, len(log.segment_names) - 1, home, zero, st.position, st.velocity, st.effort)
        if np.all(np.abs(st.position - home) <= tol):
            since = st.time if since is None else since
            if st.time - since >= HOME_STILL_S:
                return float(st.time - t0)
        else:
            since = None
        act.command(home, zero)
        t += period
        act.wait_until(t)
    return float("nan")


def _homing_stillness(homing: Optional[TrialLog]) -> Optional[np.ndarray]:
    """The rows of a homing log's last HOME_STILL_S, when it reached home (None otherwise)."""
    reached = homing.metadata.get("home_reached_s") if homing is not None else None
    if homing is None or not len(homing) or reached is None or not np.isfinite(reached):
        return None
    t = np.asarray(homing.time, dtype=float)
    return t >= t[-1] - HOME_STILL_S


def _mean_over(values: np.ndarray, rows: Optional[np.ndarray], fallback: np.ndarray) -> np.ndarray:
    if rows is None or not rows.any():
        return fallback
    with np.errstate(all="ignore"):
        mean = np.nanmean(np.asarray(values, dtype=float)[rows], axis=0)
    return np.where(np.isfinite(mean), mean, fallback)


def _start_of(log: TrialLog, homing: Optional[TrialLog] = None, channel: str = "q") -> dict[str, float]:
    """How a rig repeat started, for the sim to start so too: per joint, the mean of ``channel``
    over the homing's last HOME_STILL_S when it reached home, else the repeat's first row.

    ``q``: where the shafts were (a holding servo hunts across the tick it sits at, and how often
    it reads each side says where in the tick its shaft is; the train's ultrasonic noise averages
    out the same way). ``effort``: what the servos held (a servo that crept home against friction
    holds more or less than gravity alone; its integrator carries that into the first moves)."""
    if not len(log):
        return {}
    source = homing if homing is not None else log
    values = _mean_over(getattr(source, channel), _homing_stillness(homing),
                        np.asarray(getattr(log, channel)[0], dtype=float))
    return {n: float(v) for n, v in zip(log.joint_names, values) if np.isfinite(v)}


def _plan_start_of(log: TrialLog) -> Optional[np.ndarray]:
    """The pose a rig repeat planned from (its first command), for the sim to run the very same
    plan: planned from the sim's own first reading, a start a tick or a millimetre of ultrasonic
    noise apart gives segments of another length, and every later one starts out of step."""
    if not len(log) or not np.all(np.isfinite(log.q_cmd[0])):
        return None
    return np.asarray(log.q_cmd[0], dtype=float)


def _starting_at(config: TrialConfig, start: dict[str, float],
                 effort: Optional[dict[str, float]] = None) -> TrialConfig:
    """A sim config that starts at ``start`` (``backend.start``), its servos holding ``effort``
    (``backend.start_effort``, for a servo model)."""
    update: dict = {"start": dict(start)}
    if effort and config.backend.servo_model != "ideal":
        update["start_effort"] = dict(effort)
    return config.model_copy(update={"backend": config.backend.model_copy(update=update)})


def _safe_stop(config: TrialConfig) -> str:
    """Apply the config's own safe stop to the rig (best effort: the bus may be gone); how the
    rig was left, in the backend's words, or that the stop could not be confirmed."""

    try:
        act = make_backend(config, get_robot(config.robot))
        act.close()
    except Exception as e:  # noqa: BLE001 - nothing more can be done from here
        what = "hold" if config.backend.safe_stop == "hold" else "torque off"
        return f"{what} not confirmed: the rig could not be reached for its safe stop ({e})"
    return getattr(act, "safe_stop_report", None) or config.backend.safe_stop


def run_comparison(config: TrialConfig, out: Path, repeats: int = 5, emulate: bool = False,
                   retries: Optional[int] = None, align: str = "motion",
                   progress: Optional[ProgressFn] = None, report: bool = True,
                   interrupts: Interruptible = NO_SIGNALS, sim_model: Optional[str] = None) -> SessionResult:
    """Run the plan ``repeats`` times on the rig (or its emulator) and on the sim, compare, report.

    ``retries`` (default 3 when emulating, 0 on hardware): how often a rig repeat
    that lost the bus or its sensor is run again. Raises :class:`CompareError` (nothing moved)
    for a config or port that cannot be used.
    """

    if repeats < 1:
        raise CompareError(f"--repeats must be at least 1, got {repeats}")
    if config.backend.kind != "dynamixel":
        raise CompareError(f"{config.source or config.name}: compare runs the plan on the real rig and "
                           f"on the sim; it needs backend.kind: dynamixel (this config is "
                           f"{config.backend.kind})")
    retries = (3 if emulate else 0) if retries is None else int(retries)
    if retries < 0:
        raise CompareError(f"--retries must be 0 or more, got {retries}")
    sim_cfg = sim_counterpart(config)
    model_cfg = sim_counterpart(config, sim_model) if sim_model else None
    try:
        prepare(config)
        prepare(sim_cfg)
        if model_cfg is not None:
            prepare(model_cfg)
    except TrialError as e:
        raise CompareError(str(e)) from None
    if not emulate:
        check_real_ports(config)
    if emulate and config.source is None:
        raise CompareError("--emulate needs a config read from a file (the emulator is started from it)")

    progress = progress or (lambda what, f: None)
    # rough shares of the wall time: the rig runs in real time, the sim about 8x faster
    w_real, w_sim = 0.88 / repeats, 0.12 / repeats
    lost: list[LostAttempt] = []
    real_runs: list[Path] = []
    homings: list[Path] = []
    notes: list[str] = []
    rig = None
    base_cfg = config
    res = None
    touched = stopped = False  # touched: the rig may have moved; stopped: its safe stop was applied
    last_stop = ""  # how the rig was left, in its backend's words
    try:
        if emulate:

            progress("starting the emulated rig", 0.0)
            try:
                rig = EmulatorProcess(Path(config.source))
            except RuntimeError as e:
                raise CompareError(str(e)) from None
            base_cfg = rig.retarget(config)
            # The emulator shares the host's CPU: after a pause it catches its physics up
            # before it answers again. Ride that out per transaction as the lab tools do.
            base_cfg = base_cfg.model_copy(update={"backend": base_cfg.backend.model_copy(
                update={"retries": max(base_cfg.backend.retries, EMULATED_RETRIES)})})
        out_dir = new_run_dir(out, f"compare-{config.name}")
        real_dir, sim_dir, home_dir = out_dir / "real", out_dir / "sim", out_dir / "homing"
        hold_cfg = _with_safe_stop(base_cfg, "hold")
        touched = True
        for i in range(repeats):
            res, homing = _rig_repeat(i, repeats, base_cfg, hold_cfg, real_dir, home_dir, retries, lost,
                                      lambda what, f, i=i: progress(what, w_real * (i + f)), interrupts)
            real_runs.append(res.run_dir)
            homings.append(homing)
            if not res.completed:
                notes.append(f"rig repeat {i + 1} stopped early: {res.reason}; the session ended there")
                break
    except BaseException as e:
        if touched:
            with interrupts.deferred():
                e.safe_stop = _safe_stop(base_cfg)  # type: ignore[attr-defined]
            stopped = True
        raise
    finally:
        if res is not None:
            last_stop = res.safe_stop
        if not stopped and res is not None and not res.completed:
            last_stop = _safe_stop(base_cfg)  # that repeat held the arm; stop as the config says
        if rig is not None:
            rig.close()

    n_sim = len(real_runs)
    found = [(TrialLog.load(p / "trial.npz"), TrialLog.load(h) if h.exists() else None)
             for p, h in zip(real_runs, homings)]
    plan_starts = [_plan_start_of(log) for log, _ in found]
    starts = [_start_of(log, homing) for log, homing in found]
    efforts = [_start_of(log, homing, "effort") for log, homing in found]
    sides = [("sim", sim_cfg, sim_dir)] + ([("model sim", model_cfg, out_dir / "model")] if model_cfg else [])
    runs: dict[str, list[Path]] = {}
    for k, (label, cfg, where) in enumerate(sides):
        runs[label] = []
        share = w_sim / len(sides)
        for i in range(n_sim):
            what = f"{label} repeat {i + 1}/{n_sim}"
            res_s = run_trial(_starting_at(cfg, starts[i], efforts[i]), where, report=False, note=f"compare repeat {i + 1}",
                              plan_start=plan_starts[i],
                              progress=lambda f, i=i, k=k, what=what: progress(
                                  what, 0.88 + 0.12 * k / len(sides) + share * (i + f)),
                              interrupts=interrupts)
            runs[label].append(res_s.run_dir)
    progress("comparing", 1.0)
    real_logs = [log for log, _ in found]
    real_label = "emulated rig" if emulate else "real rig"

    def against_rig(label: str) -> Comparison:
        logs = [TrialLog.load(p / "trial.npz") for p in runs[label]]
        return compare_logs(logs, real_logs, labels=(label, real_label),
                            sources=([str(p.relative_to(out_dir)) for p in runs[label]],
                                     [str(p.relative_to(out_dir)) for p in real_runs]),
                            align=align)  # type: ignore[arg-type]

    ideal_cmp = against_rig("sim")
    cmp = against_rig("model sim") if model_cfg is not None else ideal_cmp
    predicted = prediction(cmp, ideal_cmp) if model_cfg is not None else None
    sim_runs = runs["model sim" if model_cfg is not None else "sim"]
    reached = [TrialLog.load(p).metadata.get("home_reached_s") for p in sorted(home_dir.glob("*.npz"))]
    late = sum(1 for r in reached if r is None or not np.isfinite(r))
    head = ["The sim side is the same config with its backend replaced by the PyBullet defaults (same "
            "name, robot, target, plan, control rate and acceptance limits)"
            + (", running the rig's servo table through the servo model" if model_cfg is not None else "")
            + "; each sim repeat starts where the rig's repeat started (its mean reading over the "
            "homing's last stillness, which places a servo within its tick by how it hunts), so a "
            "homing that left a joint a tick off home is no difference between them."]
    if emulate:
        head.append(f"The rig is the bench's emulator (`hilbench emulate`, one process for all repeats) "
                    f"on this host; the driver retries each bus transaction up to {EMULATED_RETRIES} "
                    f"times against it, so that the host's pauses do not end a repeat.")
    head.append("Every rig repeat starts from home: the needle is withdrawn and the arm brought home at "
                f"the plan's speed and held until every joint is within {np.degrees(HOME_TOLERANCE_RAD):g}° "
                f"({np.degrees(HOME_INTEGRATING_RAD):g}° where its servo integrates) / "
                f"{HOME_TOLERANCE_M * 1e3:g} mm of home (the sensed train {np.degrees(HOME_SENSED_RAD):g}°) "
                f"for {HOME_STILL_S:g} s"
                + (f" ({late} homing(s) timed out after {HOME_TIMEOUT_S:g} s and went on)" if late else "")
                + "; the servos hold between repeats and the config's safe stop "
                f"({config.backend.safe_stop}) is applied after the last one.")
    notes = head + notes
    if model_cfg is not None:
        notes.insert(1, f"The model sim runs the rig's servo table through the servo model "
                        f"({sim_model}); the ideal sim (PyBullet's position motors) is run beside it for "
                        f"the prediction figures.")
    result = SessionResult(out_dir, cmp, sim_runs, real_runs, lost, emulate, notes,
                           ideal=ideal_cmp if model_cfg is not None else None, prediction=predicted,
                           safe_stop=last_stop)
    if report:

        write_compare_report(result.comparison, out_dir, title=f"Sim vs {real_label}: {config.name}",
                             notes=notes, lost=[a.__dict__ for a in lost], ideal=result.ideal,
                             prediction=result.prediction)
    return result


def _rig_repeat(i: int, repeats: int, base_cfg: TrialConfig, hold_cfg: TrialConfig, real_dir: Path,
                home_dir: Path, retries: int, lost: list[LostAttempt], progress: ProgressFn,
                interrupts: Interruptible = NO_SIGNALS):
    """Home, then one trial (the last with the config's safe stop); a lost bus is retried.
    Returns the trial's result and the log of the homing before it."""

    cfg = base_cfg if i == repeats - 1 else hold_cfg
    attempt = 0
    while True:
        what = f"rig repeat {i + 1}/{repeats}" + (f" (attempt {attempt + 1})" if attempt else "")
        progress(f"{what}: homing", 0.0)
        home_log = _unique(home_dir / f"homing-{i + 1}.npz")
        try:
            act = home_rig(cfg, home_log)
            try:
                res = run_trial(cfg, real_dir, report=False, note=f"compare repeat {i + 1}",
                                progress=lambda f: progress(what, f), backend_factory=lambda prep: act,
                                interrupts=interrupts)
            finally:
                act.close()  # already closed by the trial, unless it failed before starting
        except CommunicationError as e:
            if attempt >= retries:
                raise CompareError(f"rig repeat {i + 1}: {e}") from None
            lost.append(LostAttempt(i + 1, str(home_log.relative_to(real_dir.parent)),
                                    f"CommunicationError: {e}"))
            attempt += 1
            continue
        except ActuatorError as e:
            raise CompareError(f"rig repeat {i + 1}: {type(e).__name__}: {e}") from None
        if res.completed or attempt >= retries or not _lost_to_the_host(res.reason):
            return res, home_log
        lost.append(LostAttempt(i + 1, str(res.run_dir.relative_to(real_dir.parent)), res.reason))
        attempt += 1


def _lost_to_the_host(reason: str) -> bool:
    """A repeat that stopped because the bus or the sensor went silent (what a starved
    emulator looks like), as opposed to one the robot itself stopped."""
    return "CommunicationError" in reason or reason.startswith("interlock stale_data")


def _unique(path: Path) -> Path:
    p, i = path, 1
    while p.exists():
        i += 1
        p = path.with_name(f"{path.stem}-{i}{path.suffix}")
    return p
