"""A trial before anything moves: the target solved, the plan built and checked, its interlocks.

Everything that can be wrong with a trial (the config, the URDF, the target, a plan
that is too long or would trip an interlock) is found by :func:`prepare` before a
backend is built, so a bad trial never moves anything.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from bench.config.calibration import applied_calibration, calibration_path
from bench.config.models import MAX_PLAN_S, ConfigError, TrialConfig, model_number
from bench.core.result import PreparedTrial, TrialError
from bench.core.runner import Segment
from bench.core.safety import (
    GantryClearanceInterlock,
    Interlocks,
    JointLimitInterlock,
    StaleDataInterlock,
    TrackingErrorInterlock,
    VelocityLimitInterlock,
)
from bench.kinematics.needle import NeedleTarget, UnreachableError
from bench.kinematics.registry import get_robot
from bench.monitor.build import monitor_setup
from bench.rig.backends import backend_limits, servo_table
from bench.trial.preflight import needle_direction_problem, off_bed_problem, planned_path_trip
from drivers import Actuators, JointLimits
from drivers.dynamixel.control_table import model_spec
from trajectories import (
    LSPB,
    Excitation,
    ExcitationSpec,
    Limits,
    RuckigOnline,
    RuckigTrajectory,
    TrajectoryError,
)

__all__ = ["aimed_plan", "excitation_of", "interlocks_for", "plan", "planned_limits", "prepare", "target_of",
           "tracking_bounds"]


def target_of(config: TrialConfig) -> NeedleTarget:
    t = config.target
    return NeedleTarget(np.array([t.x_mm, t.y_mm, t.z_mm]) * 1e-3, t.depth_mm * 1e-3,
                        np.radians(t.angle_deg), np.radians(t.tilt_deg))


def prepare(config: TrialConfig, plan_start: Optional[np.ndarray] = None) -> PreparedTrial:
    """Check the URDF, solve the target, load what the backend will apply (the calibration, read
    once; the faults, parsed once; the limits) and build the interlocks and the plan from home
    (or ``plan_start``), checked through them; raise TrialError naming the problem."""

    robot = get_robot(config.robot)
    if not config.robot_urdf.is_file():
        raise TrialError(f"robot URDF not found: {config.robot_urdf} (urdf_dir: {config.urdf_dir})")
    for name in ("ct_gantry", "ct_bed", "phantom"):
        p = config.resolve(config.urdf_dir) / f"{name}.urdf"
        if not p.is_file():
            raise TrialError(f"scene URDF not found: {p} (urdf_dir: {config.urdf_dir})")
    target = target_of(config)
    t = config.target
    off_bed = off_bed_problem(robot, t.x_mm, t.y_mm, t.z_mm)
    if off_bed and config.safety.refuse_planned_trips:  # off: the interlocks themselves under test
        raise TrialError(off_bed)
    try:
        q_insert = robot.ik(target)
    except UnreachableError as e:
        raise TrialError(f"target: {e}") from None
    q_entry = q_insert.copy()
    q_entry[robot.joint_names.index(robot.insertion_joint)] = 0.0
    problem = needle_direction_problem(robot, q_insert, config.target.angle_deg)
    if problem:
        raise TrialError(problem)
    try:
        calibration = applied_calibration(config)
        faults = config.fault_specs()
    except (ConfigError, ValueError) as e:
        raise TrialError(str(e)) from None
    prep = PreparedTrial(config, robot, target, q_entry, q_insert, calibration=calibration,
                         calibration_path=calibration_path(config) if calibration is not None else None,
                         faults=faults, limits=backend_limits(config, robot))
    prep.interlocks = interlocks_for(prep, prep.limits)
    try:
        prep.monitor = monitor_setup(config, robot)
    except (ConfigError, ValueError) as e:
        raise TrialError(str(e)) from None
    prep.start = np.array(robot.chain.home if plan_start is None else plan_start, dtype=float)
    prep.aim_at_reading = plan_start is None
    prep.segments = _checked_plan(prep, prep.start)
    return prep


def _checked_plan(prep: PreparedTrial, start: np.ndarray) -> list[Segment]:
    """The plan from ``start``, refused if it would run longer than MAX_PLAN_S (a typo, not a
    trial) or if its path, followed perfectly, would trip the trial's interlocks."""

    try:
        segments = plan(prep, start, prep.limits.velocity)
    except (TrajectoryError, ValueError) as e:
        raise TrialError(f"plan: {e}") from None
    total = sum(s.trajectory.duration + s.settle for s in segments)
    if not total <= MAX_PLAN_S:
        raise TrialError(f"plan: the trial would last {total:.0f} s from home, more than the "
                         f"{MAX_PLAN_S:.0f} s allowed; raise plan.velocity_scale or "
                         f"plan.acceleration_scale, or shorten plan.settle_s")
    if prep.config.safety.refuse_planned_trips:
        trip = planned_path_trip(segments, prep.interlocks, prep.config.control_period)
        if trip is not None:
            raise TrialError(trip.message())
    for seg in segments:  # the replay stepped the online generators: start them over for the run
        reset = getattr(seg.trajectory, "reset", None)
        if reset is not None:
            reset()
    return segments


def aimed_plan(prep: PreparedTrial, q_start: np.ndarray) -> list[Segment]:
    """The prepared plan, its moves from and back to the start re-aimed at ``q_start`` (the
    backend's first reading) when the robot is not exactly where the plan starts; the rest of the
    plan is the one prepared and checked. A plan prepared from a given start is kept as it is."""
    q_start = np.asarray(q_start, dtype=float)
    if not prep.aim_at_reading or (prep.start is not None and np.array_equal(q_start, prep.start)):
        return list(prep.segments)
    traj = _trajectories(prep, prep.limits.velocity)
    out = []
    for seg in prep.segments:
        if seg.name == "approach":
            seg = Segment(seg.name, traj(q_start, prep.q_entry), seg.settle)
        elif seg.name == "home":  # an excitation run returns to where it started
            seg = Segment(seg.name, traj(prep.q_entry, q_start), seg.settle)
        out.append(seg)
    return out


def planned_limits(prep: PreparedTrial) -> JointLimits:
    """The joint limits the backend will have: the robot's, with the backend's overrides."""
    return prep.limits if prep.limits is not None else backend_limits(prep.config, prep.robot)


def plan(prep: PreparedTrial, q_start: np.ndarray, limits_velocity: np.ndarray) -> list[Segment]:
    """home -> entry pose -> insertion along the needle axis -> retract."""

    p = prep.config.plan
    vmax = limits_velocity * p.velocity_scale
    amax = vmax * p.acceleration_scale
    traj = _trajectories(prep, limits_velocity)

    if prep.config.excitation is not None:
        return [Segment("approach", traj(q_start, prep.q_entry), p.settle_s),
                Segment("excite", excitation_of(prep, Limits(vmax, amax)), p.settle_s),
                Segment("home", traj(prep.q_entry, q_start), 0.0)]
    segs = [Segment("approach", traj(q_start, prep.q_entry), p.settle_s),
            Segment("insert", traj(prep.q_entry, prep.q_insert), p.settle_s)]
    if p.retract:
        segs.append(Segment("retract", traj(prep.q_insert, prep.q_entry), 0.0))
    return segs


def _trajectories(prep: PreparedTrial, limits_velocity: np.ndarray):
    """The plan's trajectory between two poses, at the plan's share of the joint limits."""
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

    return traj


def excitation_of(prep: PreparedTrial, limits: Limits) -> Excitation:
    """The excitation around the entry pose, within the plan's speeds and the joint limits (a
    margin of half the tracking-error bound keeps the limit interlock quiet)."""
    ex = prep.config.excitation
    rows = prep.robot.chain.rows
    names = list(prep.robot.joint_names)
    lim = planned_limits(prep)
    kinds = [r.kind for r in rows]
    amp = np.array([np.radians(ex.amplitude_deg) if k == "revolute" else ex.amplitude_mm * 1e-3 for k in kinds])
    margin = tracking_bounds(prep) * 0.5 + prep.config.safety.joint_limit_tolerance
    room = np.minimum(prep.q_entry - lim.lower, lim.upper - prep.q_entry) - margin
    if ex.joints == "all":
        joints = [j for j in range(len(names)) if room[j] > 0]
    else:
        joints = [names.index(n) for n in ex.joints]
        stuck = [names[j] for j in joints if not room[j] > 0]
        if stuck:
            raise TrajectoryError(f"excitation.joints: {', '.join(stuck)} cannot move around the entry pose "
                                  f"(at a limit, less the interlocks' margin); leave them out")
    spec = ExcitationSpec(chirp_s=ex.chirp_s, f0_hz=ex.f0_hz, f1_hz=ex.f1_hz, multisine_s=ex.multisine_s,
                          multisine_period_s=ex.multisine_period_s, harmonics=ex.harmonics,
                          updown_s=ex.updown_s, pause_s=ex.pause_s, sweep_speeds=ex.sweep_speeds,
                          sweep_slowest=ex.sweep_slowest, sweep_fastest=ex.sweep_fastest, sweep_s=ex.sweep_s,
                          reversal_s=ex.reversal_s, hold_s=ex.hold_s)
    return Excitation(prep.q_entry, joints, amp, lim.lower, lim.upper, limits, spec, margin,
                      top_speed=np.minimum(lim.velocity, servo_top_speeds(prep)))


def servo_top_speeds(prep: PreparedTrial) -> np.ndarray:
    """Each joint's speed (rad/s or m/s) with its servo's shaft at the servo's no-load speed: the
    fastest a sweep can ask of it, whatever the joint's own limit says."""
    table = servo_table(prep.config, prep.robot)
    return np.array([model_spec(model_number(table[n].model)).motor.no_load_speed * abs(table[n].ratio)
                     for n in prep.robot.joint_names])


def interlocks_for(prep: PreparedTrial, act: Actuators | JointLimits):
    """The configured interlocks for this robot and backend (None when disabled).

    ``act``: the backend, or the limits it will have (to replay a plan before it exists)."""

    s = prep.config.safety
    if not s.enabled:
        return None
    names = list(prep.robot.joint_names)
    kinds = [r.kind for r in prep.robot.chain.rows]
    lim = act if isinstance(act, JointLimits) else act.limits
    tol = s.joint_limit_tolerance
    checks = [JointLimitInterlock(lim.lower - tol, lim.upper + tol, names, kinds=kinds),
              VelocityLimitInterlock(lim.velocity, names, s.velocity_factor, kinds=kinds),
              TrackingErrorInterlock(list(tracking_bounds(prep)), names, kinds=kinds)]
    if s.stale_data:
        checks.append(StaleDataInterlock())
    if s.gantry_margin_mm > 0:
        checks.append(GantryClearanceInterlock(prep.robot, s.gantry_margin_mm * 1e-3,
                                               lookahead_s=s.gantry_lookahead_s))
    return Interlocks(checks)


def tracking_bounds(prep: PreparedTrial) -> np.ndarray:
    """Each joint's tracking-error bound as configured (rad or m): the interlock's, the margins
    the live view and the export show, and the excitation's room."""
    s = prep.config.safety
    return np.array([np.radians(s.tracking_error_deg) if r.kind == "revolute" else s.tracking_error_mm * 1e-3
                     for r in prep.robot.chain.rows])
