"""Homing the rig before each compare repeat, and how the repeat started, for its sim to start so.

Before each repeat the needle is withdrawn and the arm brought home at the plan's speed and
held there until every joint has arrived (:func:`home_rig`); the homing's last stillness says
where the shafts were and what the servos held (:func:`start_of`), and the repeat's first
command what it planned from (:func:`plan_start_of`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from bench.config.models import TrialConfig
from bench.core.log import TrialLog
from bench.core.result import PreparedTrial
from bench.core.runner import Runner, Segment
from bench.rig.backends import make_backend
from bench.rig.serving import rig_kind
from drivers import Actuators
from trajectories import LSPB

__all__ = ["EMULATED_NOTE", "HOME_INTEGRATING_RAD", "HOME_SENSED_RAD", "HOME_STILL_S", "HOME_TIMEOUT_S", "HOME_TOLERANCE_M",
           "HOME_TOLERANCE_RAD", "home_rig", "plan_start_of", "start_of", "starting_at"]

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

#: What a compare report says of an emulated rig ({retries}: the driver's retries against it).
EMULATED_NOTE = ("The rig is the bench's emulator (`hilbench emulate`, one process for all repeats) "
                 "on this host, not the real rig; the driver retries each bus transaction up to "
                 "{retries} times against it, so that the host's pauses do not end a repeat.")


def home_rig(prep: PreparedTrial, log_path: Optional[Path] = None) -> Actuators:
    """Withdraw the needle, bring the arm home at the plan's speed and hold it there until
    it has arrived (:func:`_hold_until_home`).

    Returns the config's backend still enabled and holding home, for the trial
    that follows to run in the same session (no hand-over between two drivers,
    in which the arm would relax). The caller closes it; on an error it is
    closed here. The homing log is saved to ``log_path``.
    """

    config = prep.config
    robot = prep.robot
    home = robot.chain.home
    ins = robot.joint_names.index(robot.insertion_joint)
    p = config.plan
    act = make_backend(prep.config, prep.robot, calibration=prep.calibration)
    log = TrialLog(list(robot.joint_names), metadata={"purpose": "homing before a repeat",
                                                        "robot": config.robot, "rig": rig_kind(config)})
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


def start_of(log: TrialLog, homing: Optional[TrialLog] = None, channel: str = "q") -> dict[str, float]:
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


def plan_start_of(log: TrialLog) -> Optional[np.ndarray]:
    """The pose a rig repeat planned from (its first command), for the sim to run the very same
    plan: planned from the sim's own first reading, a start a tick or a millimetre of ultrasonic
    noise apart gives segments of another length, and every later one starts out of step."""
    if not len(log) or not np.all(np.isfinite(log.q_cmd[0])):
        return None
    return np.asarray(log.q_cmd[0], dtype=float)


def starting_at(config: TrialConfig, start: dict[str, float],
                 effort: Optional[dict[str, float]] = None) -> TrialConfig:
    """A sim config that starts at ``start`` (``backend.start``), its servos holding ``effort``
    (``backend.start_effort``, for a servo model)."""
    update: dict = {"start": dict(start)}
    if effort and config.backend.servo_model != "ideal":
        update["start_effort"] = dict(effort)
    return config.model_copy(update={"backend": config.backend.model_copy(update=update)})
