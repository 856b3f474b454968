"""The actuators a trial config asks for: the PyBullet world or the Dynamixel bus, built inactive.

Takes plain values (the config and the robot model), so anything above the engine can
open a backend: a trial, a comparison, the lab tools.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from bench.config.calibration import CalibrationFile, calibration_of
from bench.config.models import ConfigError, ServoConfig, TrialConfig, load_servo_model_file, model_number
from bench.config.servo_model import apply_physics, physics_for
from bench.kinematics.arc_train import epsilon_from_d2, train_pose
from bench.kinematics.transmission import servo_transmissions
from bench.rig.serving import hooks_for
from drivers import Actuators, BackendSetupError, JointLimits
from drivers.dynamixel.backend import DynamixelActuators
from drivers.dynamixel.goals import outside_limits
from drivers.dynamixel.settings import DynamixelSettings, ServoSettings, UltrasonicSettings
from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings, SceneObject
from drivers.pybullet.servo_sim import ServoSimActuators, ServoSimSettings, TrainSensor
from drivers.servo import ServoParams

__all__ = ["backend_limits", "limits_of", "make_backend", "make_dynamixel_backend", "make_servo_sim",
           "refuse_start_outside_limits", "servo_params", "servo_table", "with_physics"]


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


def servo_table(config: TrialConfig, robot) -> dict[str, ServoConfig]:
    """The servos behind the joints: the config's table, or for a simulator without one, an
    XM430-W350 per joint through the robot's transmissions with its zero at home."""
    table = getattr(config.backend, "servos", None)
    if table:
        return {n: table[n] for n in robot.joint_names}
    ratios = servo_transmissions(robot)
    return {row.name: ServoConfig(id=i + 1, model="XM430-W350", ratio=float(r), offset=float(row.home),
                                  mode="position" if r == 1.0 else "extended_position")
            for i, (row, r) in enumerate(zip(robot.chain.rows, ratios))}


def with_physics(params: ServoParams, per_joint: Sequence[dict]) -> ServoParams:
    """``params`` with each joint's physics (the keys of :data:`bench.config.servo_model.FIELD_KEYS`, ``kt_scale``, ``ke_scale``)
    set; what a joint leaves unset keeps its value."""
    return apply_physics(params, per_joint)


def servo_params(table: dict[str, ServoConfig], names) -> ServoParams:
    """The servo model's datasheet parameters for a servo table: models, gains, current limits."""
    return ServoParams.datasheet([model_number(table[n].model) for n in names],
                                 gains=[(table[n].position_p, table[n].position_i, table[n].position_d)
                                        for n in names],
                                 current_limit_a=[table[n].current_limit_a for n in names])


def _train_sensor(config: TrialConfig, robot) -> TrainSensor | None:
    """The train's ultrasonic sensor as the simulator models it (standoff, rate, median)."""
    u = config.backend.ultrasonic
    if u is None:
        return None
    standoff, params = u.standoff_mm * 1e-3, robot.params
    return TrainSensor(joint=list(robot.joint_names).index(u.joint),
                       to_distance=lambda q: standoff + float(train_pose(q, params).d2),
                       to_joint=lambda d: float(epsilon_from_d2(d - standoff, params)),
                       rate_hz=u.rate_hz, median_window=u.median_window, noise_std_m=u.noise_mm * 1e-3,
                       seed=config.seed)


def _named_joints(config: TrialConfig, robot, key: str) -> list[tuple[int, float]]:
    """(joint index, value) for each joint ``backend.<key>`` names; an unknown joint is refused."""
    names = list(robot.joint_names)
    out = []
    for name, value in getattr(config.backend, key, {}).items():
        if name not in names:
            raise ConfigError(f"backend.{key}: unknown joint {name!r}; {config.robot} has {names}")
        out.append((names.index(name), value))
    return out


def start_pose(config: TrialConfig, robot) -> np.ndarray:
    """Where a simulator starts: home, with the joints ``backend.start`` names moved (clipped to
    the limits); an unknown joint is refused."""
    q = robot.chain.home.copy()
    for j, value in _named_joints(config, robot, "start"):
        q[j] = value
    return np.clip(q, robot.chain.lower, robot.chain.upper)


def start_effort(config: TrialConfig, robot) -> np.ndarray:
    """Per joint, the effort ``backend.start_effort`` says its servo holds at the start (NaN: not
    named, it holds its pose against gravity); an unknown joint is refused."""
    out = np.full(len(robot.joint_names), np.nan)
    for j, value in _named_joints(config, robot, "start_effort"):
        out[j] = value
    return out


def make_servo_sim(config: TrialConfig, robot) -> Actuators:
    """The simulator driving the joints through the servo model (``backend.servo_model``)."""
    b = config.backend
    names = robot.joint_names
    table = servo_table(config, robot)
    limits = backend_limits(config, robot)
    params = servo_params(table, names)
    datasheet_kt = params.kt.copy()
    per_joint: list[dict] = [{} for _ in names]
    if b.servo_model != "datasheet":  # a servo model file: the rig's physics over the datasheet
        model = load_servo_model_file(config.resolve(Path(b.servo_model)))
        if model.robot != config.robot:
            raise ConfigError(f"backend.servo_model: {b.servo_model} is for {model.robot}, not {config.robot}")
        per_joint = [model.physics_of(n) for n in names]
    if b.servo_model != "datasheet" or b.servo_physics:  # the config's own physics over the model's
        params = with_physics(params, [{**p, **physics_for(b.servo_physics, n)}
                                       for p, n in zip(per_joint, names)])
    settings = ServoSimSettings(
        robot_urdf=config.robot_urdf, joint_names=names, servos=params,
        ratio=[table[n].ratio for n in names], offset=[table[n].offset for n in names],
        max_velocity=limits.velocity, max_effort=limits.effort, physics_hz=b.physics_hz,
        control_period=config.control_period, initial_position=start_pose(config, robot),
        transport_delay_s=b.transport_delay_ms * 1e-3, safe_stop=b.safe_stop, start_holding=True,
        initial_effort=start_effort(config, robot), train_sensor=_train_sensor(config, robot),
        current_based=[table[n].mode == "current_based_position" for n in names], reported_kt=datasheet_kt)
    return ServoSimActuators(settings)


def make_backend(config: TrialConfig, robot, gui: bool = False,
                 calibration: Optional[CalibrationFile] = None) -> Actuators:
    """The configured backend, inactive (reading allowed, commands refused).

    ``calibration``: what a trial read once and records; without it a Dynamixel backend reads
    the config's own. A Dynamixel backend on a bus this process emulates carries that bus's
    fault hooks (:mod:`bench.rig.serving`)."""
    cfg = config
    if cfg.backend.kind == "pybullet" and cfg.backend.servo_model != "ideal":
        if gui:
            raise ConfigError("--gui shows PyBullet's ideal motors only; drop --gui or set "
                              "backend.servo_model: ideal")
        return make_servo_sim(cfg, robot)
    if cfg.backend.kind == "pybullet":

        b = cfg.backend
        limits = backend_limits(cfg, robot)
        effort, velocity = limits.effort.tolist(), limits.velocity.tolist()
        d = cfg.resolve(cfg.urdf_dir)
        scene = [SceneObject(d / "ct_gantry.urdf", collide=b.gantry_in_physics),
                 SceneObject(d / "ct_bed.urdf"), SceneObject(d / "phantom.urdf")]
        settings = PyBulletSettings(
            robot_urdf=cfg.robot_urdf, joint_names=robot.joint_names, scene=scene,
            physics_hz=b.physics_hz, control_period=cfg.control_period, max_effort=effort,
            max_velocity=velocity, position_gain=b.position_gain, velocity_gain=b.velocity_gain,
            initial_position=start_pose(cfg, robot), gui=gui, safe_stop=b.safe_stop,
            solver_iterations=b.solver_iterations)
        return PyBulletActuators(settings)
    if cfg.backend.kind == "dynamixel":
        return refuse_start_outside_limits(make_dynamixel_backend(cfg, robot, calibration),
                                           cfg.safety.joint_limit_tolerance)
    raise ConfigError(f"backend.kind: unknown backend {cfg.backend.kind!r}")


def refuse_start_outside_limits(act: Actuators, tolerance: float) -> Actuators:
    """``act``, unless a joint reads beyond its limits (a wrong offset or calibration): then it is
    closed, never enabled, and refused. The lab tools skip this, to read and fix such a rig."""
    lim = act.limits
    problem = outside_limits(act.joint_names, act.read().position, lim.lower, lim.upper, tolerance)
    if problem:
        act.close()
        raise BackendSetupError(f"{problem}; torque not enabled (check its offset and calibration)")
    return act


def make_dynamixel_backend(config: TrialConfig, robot,
                           calibration: Optional[CalibrationFile] = None) -> Actuators:
    """The Dynamixel backend from a config (ports, IDs, models, transmissions)."""

    b = config.backend
    # zero offsets and ultrasonic mapping: as given, else the config's own, if it names one
    cal = calibration if calibration is not None else calibration_of(config)
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
        ultrasonic=ultra, limit_tolerance=config.safety.joint_limit_tolerance)
    backend = DynamixelActuators(settings)
    hooks = hooks_for(b.port)
    if hooks is not None:  # an emulated bus: bus-level faults reach the wire through its hooks
        backend.fault_hooks = hooks
    return backend
