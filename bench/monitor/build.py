"""A trial's monitor from its config: the servo table, the model's physics, the joints watched.

Checked before anything moves (:func:`monitor_setup`, called by the trial's preparation): a model
file for another robot, or a backend whose joints are not servos, is refused in one line. The
monitor itself (:func:`build_monitor`) is built afresh for each run: it keeps state.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from bench.config.models import ConfigError, TrialConfig, load_servo_model_file
from bench.rig.backends import servo_params, servo_table, with_physics
from bench.monitor.monitor import TwinMonitor
from bench.monitor.twin import ServoTwin, TwinSetup
from drivers.dynamixel.control_table import x_series_table

__all__ = ["DEFAULT_SIGMA_TICKS", "MonitorSetup", "build_monitor", "default_sigma", "encoder_tick",
           "monitor_setup"]

#: The residual's spread (σ) of a datasheet model, in encoder ticks through each joint's
#: transmission, revolute and prismatic: the quantisation's own (0.3 tick) and the model's error
#: on clean trials of the servo-model sim and the emulated rig (0.2-0.7 tick; docs/monitor.md). A
#: model file from ``identify`` carries the σ its detector needs on its logs (``twin_sigma``,
#: :mod:`bench.monitor.spread`); the larger of the two is the joint's σ.
DEFAULT_SIGMA_TICKS = {"revolute": 1.0, "prismatic": 2.0}
#: The current residual's spread (σ, A, at the motor) of a datasheet model: see docs/monitor.md. A
#: model file from ``identify`` carries its own (``twin_sigma_current``); the larger is the joint's.
DEFAULT_SIGMA_CURRENT_A = 0.02


@dataclass(frozen=True)
class MonitorSetup:
    """What a run's monitor is built from, checked."""

    twin: TwinSetup
    sigma: np.ndarray
    monitored: np.ndarray
    model: str
    action: str
    loop_period_s: Optional[float] = None  #: the trial's control period, when the readings are due
    current_sigma: Optional[np.ndarray] = None  #: per joint the current residual's σ (A); None: not watched


def encoder_tick(ratio) -> np.ndarray:
    """Per joint one encoder tick through its transmission (rad or m)."""
    return np.abs(np.asarray(ratio, dtype=float)) * x_series_table()["Present Position"].scale


def default_sigma(ratio, kinds) -> np.ndarray:
    """Per joint the datasheet model's σ (:data:`DEFAULT_SIGMA_TICKS` through its transmission), the
    floor of an identified one."""
    return encoder_tick(ratio) * np.array([DEFAULT_SIGMA_TICKS[k] for k in kinds])


def monitor_setup(config: TrialConfig, robot) -> Optional[MonitorSetup]:
    """The config's monitor, checked; None when it has none."""
    m = config.monitor
    if m is None:
        return None
    b = config.backend
    if b.kind == "pybullet" and b.servo_model == "ideal":
        raise ConfigError("monitor: the ideal motors are PyBullet's position motors, not servos, and no "
                          "servo model predicts them; monitor a servo-model sim (backend.servo_model: "
                          "datasheet or a model file) or a rig")
    names = list(robot.joint_names)
    table = servo_table(config, robot)
    params = servo_params(table, names)
    reported_kt = params.kt.copy()  # the driver's: Present Current to effort by the datasheet's Kt
    spread: dict[str, float] = {}
    spread_current: dict[str, float] = {}
    if m.model != "datasheet":
        model = load_servo_model_file(config.resolve(Path(m.model)))
        if model.robot != config.robot:
            raise ConfigError(f"monitor.model: {m.model} is for {model.robot}, not {config.robot}")
        params = with_physics(params, [model.physics_of(n) for n in names])
        spread = model.twin_sigma
        spread_current = model.twin_sigma_current
    ratio = np.array([table[n].ratio for n in names], dtype=float)
    # the spread the model leaves where identify measured it, never below the encoder's steps
    floor = default_sigma(ratio, [r.kind for r in robot.chain.rows])
    sigma = np.array([max(spread.get(n, 0.0), floor[j]) for j, n in enumerate(names)])
    current_sigma = np.array([max(spread_current.get(n, 0.0), DEFAULT_SIGMA_CURRENT_A) for n in names])
    sensed = getattr(b, "ultrasonic", None)
    monitored = np.array([not (sensed is not None and n == sensed.joint) for n in names])
    twin = TwinSetup(str(config.robot_urdf), names, params, ratio,
                     np.array([table[n].offset for n in names], dtype=float),
                     robot.chain.lower, robot.chain.upper, reported_kt)
    return MonitorSetup(twin, sigma, monitored, m.model, m.action, config.control_period, current_sigma)


def build_monitor(setup: MonitorSetup, log=None) -> TwinMonitor:
    """A fresh monitor for one run (its alarms logged in ``log``)."""
    return TwinMonitor(ServoTwin(setup.twin), setup.twin.joint_names, setup.sigma, setup.monitored,
                       setup.model, setup.action, log=log, loop_period_s=setup.loop_period_s,
                       current_sigma=setup.current_sigma)
