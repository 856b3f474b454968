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
from bench.compare.homing import (
    EMULATED_NOTE,
    HOME_INTEGRATING_RAD,
    HOME_SENSED_RAD,
    HOME_STILL_S,
    HOME_TIMEOUT_S,
    HOME_TOLERANCE_M,
    HOME_TOLERANCE_RAD,
    home_rig,
    plan_start_of,
    start_of,
    starting_at,
)
from bench.compare.prediction import Prediction, prediction, sensed_joint
from bench.compare.report import write_compare_report
from bench.config.models import ConfigError, PyBulletBackendConfig, TrialConfig
from bench.core.interrupts import NO_SIGNALS
from bench.core.log import TrialLog
from bench.core.record import new_run_dir
from bench.core.result import PreparedTrial, TrialError
from bench.core.runner import Interruptible
from bench.rig.backends import make_backend
from bench.rig.emulated import EmulatorProcess, open_emulated_rig
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from drivers import ActuatorError, CommunicationError
from drivers.capabilities import SafeStopReport, find_capability
from drivers.errors import CompareError
from drivers.link import port_usable

__all__ = ["CompareError", "LostAttempt", "SessionResult", "check_real_ports", "home_rig",
           "run_comparison", "sim_counterpart"]

# Kept under their former names for the callers that read a homing's start.
_start_of, _plan_start_of, _starting_at = start_of, plan_start_of, starting_at

#: Bus retries per transaction against the emulator (the most a config allows), so that a
#: busy host's pauses of up to about 0.2 s do not end a repeat.
EMULATED_RETRIES = 20

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
    #: The emulated rig's counters when it stopped (packets, status packets dropped...); {} on hardware.
    rig_stats: dict = field(default_factory=dict)
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
    else:  # the ideal motors are not servos: the twin watches the rig's side only
        data["monitor"] = None
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
        if port_usable(port):
            continue
        if not os.path.exists(port):
            raise CompareError(f"{field_name}: {what} port {port} not found (is the adapter plugged "
                               f"in?); nothing moved. Rehearse without hardware with --emulate")
        if not os.access(port, os.R_OK | os.W_OK):
            raise CompareError(f"{field_name}: no read/write permission on {what} port {port}; "
                               f"nothing moved")


def _with_safe_stop(config: TrialConfig, safe_stop: str) -> TrialConfig:
    return config.model_copy(update={"backend": config.backend.model_copy(update={"safe_stop": safe_stop})})


def _safe_stop(prep: PreparedTrial) -> str:
    """Apply the config's own safe stop to the rig (best effort: the bus may be gone); how the
    rig was left, in the backend's words, or that the stop could not be confirmed."""
    config = prep.config
    try:
        act = make_backend(config, prep.robot, calibration=prep.calibration)
        act.close()
    except Exception as e:  # noqa: BLE001 - nothing more can be done from here
        what = "hold" if config.backend.safe_stop == "hold" else "torque off"
        return f"{what} not confirmed: the rig could not be reached for its safe stop ({e})"
    layer = find_capability(act, SafeStopReport)
    return (layer.safe_stop_report if layer is not None else None) or config.backend.safe_stop


@dataclass
class _Rig:
    """What the rig side of a session did: its repeats, their homings, the attempts lost."""

    out_dir: Path  #: where the session's folder goes, then that folder
    runs: list[Path] = field(default_factory=list)
    homings: list[Path] = field(default_factory=list)
    lost: list[LostAttempt] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stats: dict = field(default_factory=dict)  #: the emulator's counters, when it stopped
    safe_stop: str = ""  #: how the rig was left at the end, in its backend's words


def run_comparison(config: TrialConfig, out: Path, repeats: int = 5, emulate: bool = False,
                   retries: Optional[int] = None, align: str = "motion",
                   progress: Optional[ProgressFn] = None, report: bool = True,
                   interrupts: Interruptible = NO_SIGNALS, sim_model: Optional[str] = None,
                   clock: Optional[str] = None) -> SessionResult:
    """Run the plan ``repeats`` times on the rig (or its emulator) and on the sim, compare, report.

    ``retries`` (default 3 when emulating, 0 on hardware): how often a rig repeat
    that lost the bus or its sensor is run again. Raises :class:`CompareError` (nothing moved)
    for a config or port that cannot be used.
    """
    retries = _checked_request(config, repeats, emulate, retries)
    rig_prep, sides = _prepared_sides(config, sim_model)
    if not emulate:
        check_real_ports(config)
    progress = progress or (lambda what, f: None)
    rig = _Rig(Path(out))
    _run_rig(rig, rig_prep, repeats, emulate, retries, progress, interrupts, clock)
    found = [(TrialLog.load(p / "trial.npz"), TrialLog.load(h) if h.exists() else None)
             for p, h in zip(rig.runs, rig.homings)]
    runs = {label: _run_sim(cfg, where, found, label, k, len(sides), progress, interrupts)
            for k, (label, cfg, where) in enumerate((lb, c, rig.out_dir / d) for lb, c, d in sides)}
    progress("comparing", 1.0)
    result = _analysed(rig, runs, [log for log, _ in found], emulate, align, sim_model)
    result.rig_stats = rig.stats
    result.safe_stop = rig.safe_stop
    result.notes = _notes(config, rig, emulate, sim_model) + rig.notes
    if report:
        real_label = "emulated rig" if emulate else "real rig"
        write_compare_report(result.comparison, rig.out_dir, title=f"Sim vs {real_label}: {config.name}",
                             notes=result.notes, lost=[a.__dict__ for a in rig.lost], ideal=result.ideal,
                             prediction=result.prediction)
    return result


def _checked_request(config: TrialConfig, repeats: int, emulate: bool, retries: Optional[int]) -> int:
    """The retries to allow; CompareError for a request that cannot run (nothing moved)."""
    if repeats < 1:
        raise CompareError(f"--repeats must be at least 1, got {repeats}")
    if config.backend.kind != "dynamixel":
        raise CompareError(f"{config.source or config.name}: compare runs the plan on the real rig and "
                           f"on the sim; it needs backend.kind: dynamixel (this config is "
                           f"{config.backend.kind})")
    retries = (3 if emulate else 0) if retries is None else int(retries)
    if retries < 0:
        raise CompareError(f"--retries must be 0 or more, got {retries}")
    if emulate and config.source is None:
        raise CompareError("--emulate needs a config read from a file (the emulator is started from it)")
    return retries


def _prepared_sides(config: TrialConfig, sim_model: Optional[str]):
    """The rig's trial, prepared once for every repeat, and the sim sides (label, config, folder),
    each checked before anything moves."""
    sides = [("sim", sim_counterpart(config), "sim")]
    if sim_model:
        sides.append(("model sim", sim_counterpart(config, sim_model), "model"))
    try:
        rig = prepare(config)
        for _, cfg, _ in sides:
            prepare(cfg)  # a sim side that cannot run is refused before the rig moves
    except TrialError as e:
        raise CompareError(str(e)) from None
    return rig, sides


def _run_rig(rig: _Rig, prep: PreparedTrial, repeats: int, emulate: bool, retries: int,
             progress: ProgressFn, interrupts: Interruptible, clock: Optional[str] = None) -> None:
    """Every rig repeat, each after its homing, the emulator (``emulate``) started once for all;
    the config's safe stop after the last, or whenever the session ends early."""
    w_real = 0.88 / repeats  # rough share of the wall time: the rig runs in real time, the sim ~8x faster
    emulator = None
    res = None
    touched = stopped = False  # touched: the rig may have moved; stopped: its safe stop was applied
    try:
        if emulate:
            progress("starting the emulated rig", 0.0)
            emulator, prep = _emulated(prep, clock)
        rig.out_dir = new_run_dir(rig.out_dir, f"compare-{prep.config.name}")
        touched = True
        for i in range(repeats):
            res, homing = _rig_repeat(i, repeats, prep, rig.out_dir / "real", rig.out_dir / "homing",
                                      retries, rig.lost,
                                      lambda what, f, i=i: progress(what, w_real * (i + f)), interrupts)
            rig.runs.append(res.run_dir)
            rig.homings.append(homing)
            if not res.completed:
                rig.notes.append(f"rig repeat {i + 1} stopped early: {res.reason}; the session ended there")
                break
    except BaseException as e:
        if touched:
            with interrupts.deferred():
                e.safe_stop = rig.safe_stop = _safe_stop(prep)  # type: ignore[attr-defined]
            stopped = True
        raise
    finally:
        if res is not None and not stopped:
            rig.safe_stop = res.safe_stop
        if not stopped and res is not None and not res.completed:
            rig.safe_stop = _safe_stop(prep)  # that repeat held the arm; stop as the config says
        if emulator is not None:
            emulator.close()
            rig.stats = dict(emulator.stats)


def _emulated(prep: PreparedTrial, clock: Optional[str] = None) -> tuple[EmulatorProcess, PreparedTrial]:
    """The emulated rig (``hilbench emulate`` in a child process, or this process's on the virtual
    clock) and the trial pointed at it."""
    try:
        emulator = open_emulated_rig(Path(prep.config.source), prep.config, clock)
    except RuntimeError as e:
        raise CompareError(str(e)) from None
    cfg = emulator.retarget(prep.config)
    # The emulator shares the host's CPU: after a pause it catches its physics up before it
    # answers again. Ride that out per transaction as the lab tools do.
    cfg = cfg.model_copy(update={"backend": cfg.backend.model_copy(
        update={"retries": max(cfg.backend.retries, EMULATED_RETRIES)})})
    return emulator, prep.with_config(cfg)


def sim_start(config: TrialConfig, log: TrialLog, homing: Optional[TrialLog]
              ) -> tuple[dict[str, float], Optional[np.ndarray]]:
    """Where a sim repeat of rig repeat ``log`` starts (per joint) and the pose its plan starts
    from (the rig's, so both run the very same plan). A joint the rig read through its sensor
    starts, on a sim without that sensor, where the plan does: the rig planned from the sensor's
    first reading, a millimetre or two of noise off the homing's mean, and a sim reading the joint
    exactly would snap across the difference (on the arc, past the velocity interlock)."""
    start, plan_start = start_of(log, homing), plan_start_of(log)
    sensed = sensed_joint(log)
    if sensed is not None and plan_start is not None and getattr(config.backend, "ultrasonic", None) is None:
        start[sensed] = float(plan_start[log.joint_names.index(sensed)])
    return start, plan_start


def _run_sim(config: TrialConfig, where: Path, found: list, label: str, k: int, n_sides: int,
             progress: ProgressFn, interrupts: Interruptible) -> list[Path]:
    """One sim side: each repeat starts where the rig's repeat did and runs its very plan."""
    n, share = len(found), 0.12 / max(len(found), 1) / n_sides
    runs = []
    for i, (log, homing) in enumerate(found):
        what = f"{label} repeat {i + 1}/{n}"
        start, plan_start = sim_start(config, log, homing)
        cfg = starting_at(config, start, start_of(log, homing, "effort"))
        try:
            prep = prepare(cfg, plan_start=plan_start)
        except TrialError as e:
            raise CompareError(f"{what}: {e}") from None
        res = run_trial(prep, where, TrialHooks(
            note=f"compare repeat {i + 1}", report=False, interrupts=interrupts,
            progress=lambda f, i=i, what=what: progress(what, 0.88 + 0.12 * k / n_sides + share * (i + f))))
        runs.append(res.run_dir)
    return runs


def _analysed(rig: _Rig, runs: dict[str, list[Path]], real_logs: list[TrialLog], emulate: bool,
              align: str, sim_model: Optional[str]) -> SessionResult:
    """Each sim side against the rig; with a servo model, how well it predicts the rig."""
    real_label = "emulated rig" if emulate else "real rig"

    def against_rig(label: str) -> Comparison:
        logs = [TrialLog.load(p / "trial.npz") for p in runs[label]]
        return compare_logs(logs, real_logs, labels=(label, real_label),
                            sources=([str(p.relative_to(rig.out_dir)) for p in runs[label]],
                                     [str(p.relative_to(rig.out_dir)) for p in rig.runs]),
                            align=align)  # type: ignore[arg-type]

    ideal = against_rig("sim")
    if not sim_model:
        return SessionResult(rig.out_dir, ideal, runs["sim"], rig.runs, rig.lost, emulate)
    model = against_rig("model sim")
    return SessionResult(rig.out_dir, model, runs["model sim"], rig.runs, rig.lost, emulate,
                         ideal=ideal, prediction=prediction(model, ideal))


def _notes(config: TrialConfig, rig: _Rig, emulate: bool, sim_model: Optional[str]) -> list[str]:
    """What the report says about how the session ran."""
    reached = [TrialLog.load(p).metadata.get("home_reached_s")
               for p in sorted((rig.out_dir / "homing").glob("*.npz"))]
    late = sum(1 for r in reached if r is None or not np.isfinite(r))
    notes = ["The sim side is the same config with its backend replaced by the PyBullet defaults (same "
             "name, robot, target, plan, control rate and acceptance limits)"
             + (", running the rig's servo table through the servo model" if sim_model else "")
             + "; each sim repeat starts where the rig's repeat started (its mean reading over the "
             "homing's last stillness, which places a servo within its tick by how it hunts), so a "
             "homing that left a joint a tick off home is no difference between them."]
    if sim_model:
        notes.append(f"The model sim runs the rig's servo table through the servo model "
                     f"({sim_model}); the ideal sim (PyBullet's position motors) is run beside it for "
                     f"the prediction figures.")
    if emulate:
        notes.append(EMULATED_NOTE.format(retries=EMULATED_RETRIES))
    notes.append("Every rig repeat starts from home: the needle is withdrawn and the arm brought home at "
                 f"the plan's speed and held until every joint is within {np.degrees(HOME_TOLERANCE_RAD):g}° "
                 f"({np.degrees(HOME_INTEGRATING_RAD):g}° where its servo integrates) / "
                 f"{HOME_TOLERANCE_M * 1e3:g} mm of home (the sensed train {np.degrees(HOME_SENSED_RAD):g}°) "
                 f"for {HOME_STILL_S:g} s"
                 + (f" ({late} homing(s) timed out after {HOME_TIMEOUT_S:g} s and went on)" if late else "")
                 + "; the servos hold between repeats and the config's safe stop "
                 f"({config.backend.safe_stop}) is applied after the last one.")
    return notes


def _rig_repeat(i: int, repeats: int, rig: PreparedTrial, real_dir: Path, home_dir: Path, retries: int,
                lost: list[LostAttempt], progress: ProgressFn, interrupts: Interruptible = NO_SIGNALS):
    """Home, then one trial (the last with the config's safe stop, the others holding); a lost
    bus is retried. Returns the trial's result and the log of the homing before it."""

    prep = rig if i == repeats - 1 else rig.with_config(_with_safe_stop(rig.config, "hold"))
    attempt = 0
    while True:
        what = f"rig repeat {i + 1}/{repeats}" + (f" (attempt {attempt + 1})" if attempt else "")
        progress(f"{what}: homing", 0.0)
        home_log = _unique(home_dir / f"homing-{i + 1}.npz")
        try:
            act = home_rig(prep, home_log)
            try:
                res = run_trial(prep, real_dir, TrialHooks(
                    note=f"compare repeat {i + 1}", report=False, progress=lambda f: progress(what, f),
                    interrupts=interrupts, backend=lambda _: act))
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
