"""Time-optimal, time-synchronised trajectories from ruckig, offline and online.

Why ruckig next to LSPB: it gives the shortest motion under velocity,
acceleration and (optionally) jerk limits, and it can replan from any moving
state within one control cycle, which the bench needs to retarget the needle
mid-motion. All joints finish together (time synchronisation), but unlike
:class:`~trajectories.lspb.LSPB` they need not stay on the joint-space line.

Infinite jerk: ruckig 0.19 accepts ``max_jerk = inf`` (it is its default) and
then plans a second-order, acceleration-limited profile whose acceleration
steps between 0 and ±amax. It is passed through unchanged; no large finite
stand-in is needed.
"""

from __future__ import annotations

import math

import numpy as np
import ruckig
from numpy.typing import ArrayLike

from .base import Limits, PointToPoint, TrajectoryError, as_joint_vector, as_times

__all__ = ["RuckigOnline", "RuckigTrajectory"]

_OK = (ruckig.Result.Working, ruckig.Result.Finished)


def _check_limits(limits: Limits, dof: int) -> None:
    if not isinstance(limits, Limits):
        raise TrajectoryError(f"limits must be a trajectories.Limits, got {type(limits).__name__}")
    if limits.dof != dof:
        raise TrajectoryError(f"limits are for {limits.dof} joints but start has {dof}")


def _velocity(name: str, value: ArrayLike | None, dof: int) -> np.ndarray:
    return np.zeros(dof) if value is None else as_joint_vector(name, value, dof)


def _check_goal_velocity(goal_velocity: np.ndarray, limits: Limits) -> None:
    """Ruckig would refuse too; checking here names the joint in our own words."""
    bad = np.flatnonzero(np.abs(goal_velocity) > limits.velocity)
    if bad.size:
        i = int(bad[0])
        raise TrajectoryError(
            f"goal_velocity[{i}] = {goal_velocity[i]:.6g} exceeds joint {i}'s velocity "
            f"limit {limits.velocity[i]:.6g}"
        )


def _make_input(
    start: np.ndarray,
    start_velocity: np.ndarray,
    goal: np.ndarray,
    goal_velocity: np.ndarray,
    limits: Limits,
) -> ruckig.InputParameter:
    dof = start.size
    inp = ruckig.InputParameter(dof)
    inp.current_position = start.tolist()
    inp.current_velocity = start_velocity.tolist()
    inp.current_acceleration = [0.0] * dof
    inp.target_position = goal.tolist()
    inp.target_velocity = goal_velocity.tolist()
    inp.target_acceleration = [0.0] * dof
    inp.max_velocity = limits.velocity.tolist()
    inp.max_acceleration = limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
    inp.synchronization = ruckig.Synchronization.Time
    return inp


def _plan(inp: ruckig.InputParameter) -> ruckig.Trajectory:
    """Whole trajectory for ``inp``, or a TrajectoryError carrying ruckig's verdict."""
    traj = ruckig.Trajectory(inp.degrees_of_freedom)
    try:
        result = ruckig.Ruckig(inp.degrees_of_freedom).calculate(inp, traj)
    except ruckig.RuckigError as exc:
        raise TrajectoryError(f"ruckig rejected the motion: {str(exc).strip()}") from exc
    if result not in _OK:
        raise TrajectoryError(f"ruckig could not plan the motion: {result.name}")
    return traj


class RuckigTrajectory(PointToPoint):
    """Offline time-optimal trajectory, computed once at construction.

    ``start_velocity`` and ``goal_velocity`` default to rest; accelerations at
    both ends are zero.
    """

    def __init__(
        self,
        start: ArrayLike,
        goal: ArrayLike,
        limits: Limits,
        start_velocity: ArrayLike | None = None,
        goal_velocity: ArrayLike | None = None,
    ) -> None:
        self._start = as_joint_vector("start", start)
        dof = self._start.size
        self._goal = as_joint_vector("goal", goal, dof)
        _check_limits(limits, dof)
        self._limits = limits
        self._start_velocity = _velocity("start_velocity", start_velocity, dof)
        self._goal_velocity = _velocity("goal_velocity", goal_velocity, dof)
        _check_goal_velocity(self._goal_velocity, limits)
        self._traj = _plan(
            _make_input(
                self._start, self._start_velocity, self._goal, self._goal_velocity, limits
            )
        )
        self._duration = float(self._traj.duration)

    @property
    def duration(self) -> float:
        return self._duration

    @property
    def limits(self) -> Limits:
        return self._limits

    def sample(self, t: float | ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """State at time(s) ``t``; outside [0, duration) the end states are returned exactly."""
        times, scalar = as_times(t)
        n, dof = times.size, self.dof
        q = np.empty((n, dof))
        qd = np.empty((n, dof))
        qdd = np.zeros((n, dof))
        before = times < 0.0
        after = times >= self._duration
        q[before], qd[before] = self._start, self._start_velocity
        q[after], qd[after] = self._goal, self._goal_velocity
        at_time = self._traj.at_time
        for k in np.flatnonzero(~(before | after)).tolist():
            q[k], qd[k], qdd[k] = at_time(float(times[k]))
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd


class RuckigOnline(PointToPoint):
    """Online generator for a control loop running at a fixed period ``dt``.

    Each :meth:`sample` advances ruckig's ``update`` cycle by cycle up to
    ``t`` (rounded to the cycle grid), exactly as a real-time loop would, so
    what the bench commands is what the robot's own controller would compute.
    Time is relative to construction (or the last :meth:`reset`).
    """

    def __init__(self, start: ArrayLike, goal: ArrayLike, limits: Limits, dt: float) -> None:
        self._start = as_joint_vector("start", start)
        dof = self._start.size
        self._initial_goal = as_joint_vector("goal", goal, dof)
        _check_limits(limits, dof)
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise TrajectoryError(f"dt must be finite and > 0, got {dt!r}")
        self._limits = limits
        self._dt = dt
        self.reset()

    def reset(self) -> None:
        """Back to the start state at time 0, heading for the goal given at construction."""
        dof = self.dof
        self._otg = ruckig.Ruckig(dof, self._dt)
        self._out = ruckig.OutputParameter(dof)
        self._goal = self._initial_goal
        self._inp = _make_input(self._start, np.zeros(dof), self._goal, np.zeros(dof), self._limits)
        self._cycle = 0
        self._state = (self._start.copy(), np.zeros(dof), np.zeros(dof))
        self._replan()

    def set_goal(self, goal: ArrayLike, goal_velocity: ArrayLike | None = None) -> None:
        """Retarget from the current state; ruckig replans on the next update."""
        goal = as_joint_vector("goal", goal, self.dof)
        goal_velocity = _velocity("goal_velocity", goal_velocity, self.dof)
        _check_goal_velocity(goal_velocity, self._limits)
        previous = (self._inp.target_position, self._inp.target_velocity)
        self._inp.target_position = goal.tolist()
        self._inp.target_velocity = goal_velocity.tolist()
        try:
            self._replan()
        except TrajectoryError:
            self._inp.target_position, self._inp.target_velocity = previous
            raise
        self._goal = goal

    def _replan(self) -> None:
        """Plan eagerly so that ``duration`` is known and a bad goal fails at once."""
        traj = _plan(self._inp)
        self._plan_start = self._cycle * self._dt
        self._plan_duration = float(traj.duration)
        self._finished = self._plan_duration == 0.0

    # -- Trajectory protocol ----------------------------------------------
    @property
    def duration(self) -> float:
        """Absolute time at which the current plan ends."""
        return self._plan_start + self._plan_duration

    @property
    def goal(self) -> np.ndarray:
        """The current target (changed by :meth:`set_goal`)."""
        return self._goal

    @property
    def limits(self) -> Limits:
        return self._limits

    @property
    def dt(self) -> float:
        return self._dt

    @property
    def time(self) -> float:
        """Time of the last computed cycle."""
        return self._cycle * self._dt

    @property
    def finished(self) -> bool:
        """True once ruckig reports that the current plan has been completed."""
        return self._finished

    def sample(self, t: float | ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """State at the cycle nearest ``t``; ``t`` must not go back in time."""
        times, scalar = as_times(t)
        if not np.all(np.isfinite(times)):
            raise TrajectoryError(
                "t must be finite: the online generator steps there cycle by cycle"
            )
        cycles = np.maximum(np.rint(times / self._dt), 0.0)
        previous = np.concatenate(([float(self._cycle)], cycles[:-1]))
        back = np.flatnonzero(cycles < previous)
        if back.size:
            k = int(back[0])
            raise TrajectoryError(
                f"sample times must not decrease: t = {times[k]:.6g} s comes after "
                f"t = {previous[k] * self._dt:.6g} s (call reset() to start over)"
            )
        n, dof = times.size, self.dof
        q, qd, qdd = np.empty((n, dof)), np.empty((n, dof)), np.empty((n, dof))
        for k, cycle in enumerate(cycles.tolist()):
            self._advance_to(int(cycle))
            q[k], qd[k], qdd[k] = self._state
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    def _advance_to(self, cycle: int) -> None:
        if cycle <= self._cycle:
            return
        inp, out = self._inp, self._out
        while self._cycle < cycle:
            if self._finished:  # ruckig would only repeat the final state
                self._cycle = cycle
                break
            try:
                result = self._otg.update(inp, out)
            except ruckig.RuckigError as exc:
                raise TrajectoryError(f"ruckig rejected the motion: {str(exc).strip()}") from exc
            if result not in _OK:
                raise TrajectoryError(
                    f"ruckig failed at t = {self.time:.6g} s: {result.name}"
                )
            if out.new_calculation:
                self._plan_start = self._cycle * self._dt
                self._plan_duration = float(out.trajectory.duration)
            out.pass_to_input(inp)
            self._cycle += 1
            self._finished = result == ruckig.Result.Finished
        self._state = (
            np.array(inp.current_position),
            np.array(inp.current_velocity),
            np.array(inp.current_acceleration),
        )
