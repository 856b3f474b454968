"""The actuators a trial config asks for: the PyBullet world or the Dynamixel bus, built inactive.

Takes plain values (the config and the robot model), so anything above the engine can
open a backend: a trial, a comparison, the lab tools.
"""

from __future__ import annotations

import numpy as np

from bench.config.calibration import calibration_of
from bench.config.models import ConfigError, TrialConfig, model_number
from bench.kinematics.arc_train import epsilon_from_d2
from drivers import Actuators, JointLimits
from drivers.dynamixel.backend import DynamixelActuators, DynamixelSettings, ServoSettings, UltrasonicSettings
from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings, SceneObject

__all__ = ["backend_limits", "limits_of", "make_backend", "make_dynamixel_backend"]


def limits_of(rows, overrides=None) -> JointLimits:
    """Joint limits from the robot's rows, with a backend's per-joint velocity/effort overrides."""
    overrides = overrides or {}

    def pick(row, name: str) -> float:
        o = overrides.get(row.name)
        value = getattr(o, name, None) if o is not None else None
        return float(value) if value else float(getattr(row, name))

    return JointLimits(np.array([r.lower for r in rows]), np.array([r.upper for r in rows]),
                       np.array([pick(r, "velocity") for r in rows]),
                       np.array([pick(r, "effort") for r in rows]))


def backend_limits(config: TrialConfig, robot) -> JointLimits:
    """The joint limits the backend will have: the robot's, with the backend's overrides."""
    return limits_of(robot.chain.rows, getattr(config.backend, "joints", None))


def make_backend(config: TrialConfig, robot, gui: bool = False) -> Actuators:
    """The configured backend, inactive (reading allowed, commands refused)."""
    cfg = config
    if cfg.backend.kind == "pybullet":

        b = cfg.backend
        chain = robot.chain
        limits = backend_limits(cfg, robot)
        effort, velocity = limits.effort.tolist(), limits.velocity.tolist()
        d = cfg.resolve(cfg.urdf_dir)
        scene = [SceneObject(d / "ct_gantry.urdf", collide=b.gantry_in_physics),
                 SceneObject(d / "ct_bed.urdf"), SceneObject(d / "phantom.urdf")]
        settings = PyBulletSettings(
            robot_urdf=cfg.robot_urdf, joint_names=robot.joint_names, scene=scene,
            physics_hz=b.physics_hz, control_period=cfg.control_period, max_effort=effort,
            max_velocity=velocity, position_gain=b.position_gain, velocity_gain=b.velocity_gain,
            initial_position=chain.home, gui=gui, safe_stop=b.safe_stop,
            solver_iterations=b.solver_iterations)
        return PyBulletActuators(settings)
    if cfg.backend.kind == "dynamixel":
        return make_dynamixel_backend(cfg, robot)
    raise ConfigError(f"backend.kind: unknown backend {cfg.backend.kind!r}")


def make_dynamixel_backend(config: TrialConfig, robot) -> Actuators:
    """The Dynamixel backend from a config (ports, IDs, models, transmissions)."""

    b = config.backend
    cal = calibration_of(config)  # zero offsets and ultrasonic mapping, if the config names one
    rows = robot.chain.rows
    servos = [ServoSettings(joint=n, id=sc.id, model=model_number(sc.model), mode=sc.mode,
                            ratio=sc.ratio, offset=cal.offset(n, sc.offset) if cal else sc.offset,
                            current_limit_a=sc.current_limit_a,
                            gains=(sc.position_p, sc.position_i, sc.position_d))
              for n, sc in b.servos.items()]
    ultra = None
    if b.ultrasonic is not None:

        u = b.ultrasonic
        standoff = u.standoff_mm * 1e-3
        params = robot.params
        opts = u.sensor_options()
        ultra = UltrasonicSettings(port=u.port, joint=u.joint, baud=u.baud,
                                   median_window=u.median_window, stale_after_s=u.stale_after_s,
                                   rate_hz=u.rate_hz, range_m=opts["range_m"],
                                   no_target_m=opts["no_target_m"],
                                   to_joint=lambda d: float(epsilon_from_d2(
                                       cal.d2(d, standoff) if cal else d - standoff, params)))
    settings = DynamixelSettings(
        port=b.port, baud=b.baud, servos=servos, joint_names=robot.joint_names,
        lower=[r.lower for r in rows], upper=[r.upper for r in rows],
        velocity=[r.velocity for r in rows], effort=[r.effort for r in rows],
        return_delay_us=b.return_delay_us, fast_sync_read=b.fast_sync_read, retries=b.retries,
        timeout_s=b.timeout_ms * 1e-3 if b.timeout_ms else None,
        safe_stop=b.safe_stop, reboot_on_hardware_error=b.reboot_on_hardware_error,
        ultrasonic=ultra)
    return DynamixelActuators(settings)
