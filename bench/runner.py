"""Run trajectories through any Actuators at a fixed control rate and record a TrialLog.

The runner knows nothing of backends, robots or reports: it takes an
``Actuators`` and a list of :class:`Segment` (each a ``Trajectory`` plus a settle
time) the way dm_control's environment takes a physics and a task. Each cycle
reads the joints, checks the interlocks, records, commands, and waits for the
next tick of the backend's clock. Offline trajectories are sampled for the
whole segment in one vectorised call, so a cycle costs little more than the
backend's own work.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal, Optional, Protocol, Sequence

import numpy as np

from drivers import Actuators, ActuatorError, JointState
from trajectories import Trajectory
from trajectories.ruckig_traj import RuckigOnline

from bench.log import TrialLog


class TripCheck(Protocol):
    """What the runner needs of the safety interlocks (see bench/safety.py)."""

    def check(self, t: float, measured: JointState, commanded: np.ndarray): ...


@dataclass
class Segment:
    name: str
    trajectory: Trajectory
    settle: float = 0.0  # s to hold the final command after the trajectory ends


@dataclass
class RunResult:
    log: TrialLog
    completed: bool
    reason: str = ""  # why the run stopped early ("" when completed)
    trip: object | None = None


ProgressFn = Callable[[float], None]  # called with the fraction done (0..1)


class Runner:
    """Executes segments at ``control_period`` through one ``Actuators``."""

    def __init__(self, actuators: Actuators, control_period: float,
                 interlocks: Optional[TripCheck] = None,
                 on_trip: Literal["hold", "stop"] = "hold", hold_after_trip: float = 0.25,
                 progress: Optional[ProgressFn] = None) -> None:
        if control_period <= 0:
            raise ValueError(f"control period must be positive, got {control_period}")
        self.act = actuators
        self.dt = control_period
        self.interlocks = interlocks
        self.on_trip = on_trip
        self.hold_after_trip = hold_after_trip
        self.progress = progress

    def _cycles(self, seg: Segment) -> int:
        return int(math.ceil((seg.trajectory.duration + seg.settle) / self.dt - 1e-9)) + 1

    def run(self, segments: Sequence[Segment], log: TrialLog) -> RunResult:
        """Run every segment in order; stop early on an interlock trip or a backend error.

        Backend errors (lost bus, hardware fault) and Ctrl-C are recorded as
        events and re-raised after the actuators are disabled, so the caller can
        save the log so far.
        """
        act, dt = self.act, self.dt
        n_dof = len(act.joint_names)
        for seg in segments:
            if seg.trajectory.dof != n_dof:
                raise ValueError(f"segment {seg.name!r} has {seg.trajectory.dof} joints, "
                                 f"the actuators have {n_dof}")
        log.segment_names = [s.name for s in segments]
        total = sum(self._cycles(s) for s in segments)
        done = 0
        report_every = max(1, total // 200)
        if not act.enabled:
            act.enable()
        t_next = act.now()
        try:
            for si, seg in enumerate(segments):
                n = self._cycles(seg)
                log.event(act.now(), "segment", f"start {seg.name} ({seg.trajectory.duration:.3f} s"
                          f" + {seg.settle:.3f} s settle)")
                online = isinstance(seg.trajectory, RuckigOnline)
                times = np.arange(n) * dt
                if not online:
                    q_all, qd_all, _ = seg.trajectory.sample(times)
                for k in range(n):
                    if online:
                        q_c, qd_c, _ = seg.trajectory.sample(times[k])
                    else:
                        q_c, qd_c = q_all[k], qd_all[k]
                    st = act.read()
                    log.append(st.time, si, q_c, qd_c, st.position, st.velocity, st.effort)
                    if self.interlocks is not None:
                        trip = self.interlocks.check(st.time, st, q_c)
                        if trip is not None:
                            return self._tripped(trip, st, si, log)
                    act.command(q_c, qd_c)
                    t_next += dt
                    act.wait_until(t_next)
                    done += 1
                    if self.progress is not None and done % report_every == 0:
                        self.progress(done / total)
            st = act.read()
            log.append(st.time, len(segments) - 1, q_c, np.zeros(n_dof), st.position,
                       st.velocity, st.effort)
            log.event(st.time, "done", "all segments completed")
            if self.progress is not None:
                self.progress(1.0)
            return RunResult(log, True)
        except (ActuatorError, KeyboardInterrupt) as e:
            what = "interrupted (Ctrl-C)" if isinstance(e, KeyboardInterrupt) else f"{type(e).__name__}: {e}"
            log.event(_safe_now(act), "abort", what)
            _safe_disable(act)
            raise

    def _tripped(self, trip, st: JointState, si: int, log: TrialLog) -> RunResult:
        act = self.act
        log.event(st.time, "interlock", f"{trip.interlock}: {trip.cause}")
        if self.on_trip == "stop":
            log.event(st.time, "safe-stop", "actuators disabled after the interlock tripped")
            act.disable()
            return RunResult(log, False, f"interlock {trip.interlock}: {trip.cause}", trip)
        hold = st.position.copy()
        zero = np.zeros_like(hold)
        act.command(hold, zero)
        log.event(st.time, "hold", "holding the measured position")
        t_end = act.now() + self.hold_after_trip
        t = act.now()
        while t < t_end:
            t += self.dt
            act.wait_until(t)
            s = act.read()
            log.append(s.time, si, hold, zero, s.position, s.velocity, s.effort)
        return RunResult(log, False, f"interlock {trip.interlock}: {trip.cause}", trip)


def _safe_now(act: Actuators) -> float:
    try:
        return act.now()
    except Exception:
        return float("nan")


def _safe_disable(act: Actuators) -> None:
    try:
        act.disable()
    except Exception:  # the bus may be gone; close() will try again
        pass
