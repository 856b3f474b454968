"""Run trajectories through any Actuators at a fixed control rate and record a TrialLog.

The runner knows nothing of backends, robots or reports: it takes an
``Actuators`` and a list of :class:`Segment` (each a ``Trajectory`` plus a settle
time) the way dm_control's environment takes a physics and a task. Each cycle
reads the joints, checks the interlocks, records, commands, and waits for the
next tick of the backend's clock. Trajectories are sampled vectorised, a chunk
of cycles at a time (memory stays bounded whatever a segment lasts).

A backend that can run a block of cycles in one call and rewind to any of
them (the simulator: :class:`drivers.capabilities.BlockExecution`) gets the blocks whole: the
interlocks then scan each block after it ran (:meth:`Interlocks.scan`) and, on
a trip, the backend is rewound to the tripping cycle, so the trial trips and
holds exactly where checking every cycle would have — at the cost of a bare
simulation loop.

A backend on the wall clock (:class:`drivers.capabilities.BusTiming`: the rig's bus) gives each
cycle a deadline, the next cycle's start: the runner then records, per cycle, when it started,
how late its work (read, interlocks, command) ended against that deadline and how long its bus
transactions took (:data:`bench.core.log.TIMING_SERIES`), three stores a cycle. A simulator's
clock runs as fast as the CPU allows: it is not paced, has no deadline, and only the run's
wall-clock time is kept (``loop_wall_s``), for its speed against real time. A backend that reads
a joint through another sensor (:class:`drivers.capabilities.SensedEncoder`: the train on its
ultrasonic sensor) has that joint's servo encoder recorded beside each reading
(:data:`bench.core.log.ENCODER_SERIES`), what identification fits the joint on.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from typing import Callable, Iterator, Literal, Optional, Protocol, Sequence, runtime_checkable

import numpy as np

from bench.core.interrupts import NO_SIGNALS
from bench.core.log import TrialLog
from drivers import Actuators, JointState
from drivers.capabilities import BlockExecution, BusTiming, SensedEncoder, find_capability
from drivers.timing import FrozenHeap
from trajectories import Trajectory

#: Cycles sampled from a trajectory at once: bounds a segment's memory, amortises sampling.
SAMPLE_CHUNK = 2048
#: Cycles a block-executing backend runs between two looks at the interlocks and progress.
BLOCK = 256


class Interruptible(Protocol):
    """Raises when the run must stop (a stop signal arrived), polled every cycle or block."""

    def check(self) -> None: ...


class TripCheck(Protocol):
    """What the runner needs of the safety interlocks (see bench/core/safety.py)."""

    def check(self, t: float, measured: JointState, commanded: np.ndarray): ...


@runtime_checkable
class BlockScan(TripCheck, Protocol):
    """Interlocks that can scan a whole block of cycles after it ran (see Interlocks.scan)."""

    def scan(self, time: np.ndarray, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
             commanded: np.ndarray): ...


def runs_blocks(act: Actuators, interlocks: Optional[TripCheck]) -> bool:
    """True when the runner may hand ``act`` whole blocks of cycles.

    Only when the outermost layer itself executes blocks: a wrapper (which must see every
    cycle) offers no capability, so the block path never goes around one.
    """
    return (find_capability(act, BlockExecution) is act
            and (interlocks is None or isinstance(interlocks, BlockScan)))


def sample_chunks(trajectory: Trajectory, cycles: int, dt: float,
                  chunk: int = SAMPLE_CHUNK) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(positions, velocities) for cycles 0..cycles-1 at period dt, ``chunk`` rows at a time."""
    for k0 in range(0, cycles, chunk):
        q, qd, _ = trajectory.sample(np.arange(k0, min(cycles, k0 + chunk)) * dt)
        yield np.atleast_2d(q), np.atleast_2d(qd)


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
PhaseFn = Callable[[str], None]  # called with each segment's name as it starts


class Runner:
    """Executes segments at ``control_period`` through one ``Actuators``."""

    def __init__(self, actuators: Actuators, control_period: float,
                 interlocks: Optional[TripCheck] = None,
                 on_trip: Literal["hold", "stop"] = "hold", hold_after_trip: float = 0.25,
                 progress: Optional[ProgressFn] = None, interrupts: Interruptible = NO_SIGNALS,
                 phase: Optional[PhaseFn] = None) -> None:
        if control_period <= 0:
            raise ValueError(f"control period must be positive, got {control_period}")
        self.act = actuators
        self.dt = control_period
        self.interlocks = interlocks
        self.on_trip = on_trip
        self.hold_after_trip = hold_after_trip
        self.progress = progress
        self.phase = phase
        self.interrupts = interrupts
        self._encoder: Optional[Callable[[], float]] = None  # set per run: the sensed joint's encoder
        # told when a block's rows are in the log, by checks that record beside them (the monitor)
        self._logged: Optional[Callable[[], None]] = getattr(interlocks, "logged", None)
        #: told when each paced cycle's goal has left (the twin's goals start then, not at the reading)
        self._sent: Optional[Callable[[float], None]] = getattr(interlocks, "sent", None)

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
        self._total = sum(self._cycles(s) for s in segments)
        self._done = 0
        self._report_every = max(1, self._total // 200)
        if not act.enabled:
            act.enable()
        run_chunk = self._run_blocks if runs_blocks(act, self.interlocks) else self._run_cycles
        bus = find_capability(act, BusTiming)
        if bus is not None and not log.timed and not len(log):
            log.start_timing()
        self._bus_time = bus.bus_time if bus is not None and log.timed else None
        if bus is not None:  # what the deadlines are on: the wall clock, or an emulated rig's virtual one
            log.metadata["loop_clock"] = "virtual" if getattr(getattr(bus, "clock", None), "virtual",
                                                              False) else "wall"
        if self._bus_time is not None:
            self._bus_time()  # the set-up's transactions are not the first cycle's
        enc = find_capability(act, SensedEncoder)
        if enc is not None and enc.encoder_joint is not None and log.encoder_joint is None and not len(log):
            log.start_encoder(enc.encoder_joint)
        self._encoder = enc.encoder_position if enc is not None and log.encoder_joint is not None else None
        # a paced loop: what exists now is never walked by the cycle collector mid-run
        with FrozenHeap() if self._bus_time is not None else contextlib.nullcontext():
            began = time.perf_counter()
            t_next = act.now()
            q_c = None
            try:
                for si, seg in enumerate(segments):
                    n = self._cycles(seg)
                    if self.phase is not None:
                        self.phase(seg.name)
                    log.event(act.now(), "segment", f"start {seg.name} ({seg.trajectory.duration:.3f} s"
                              f" + {seg.settle:.3f} s settle)")
                    for q_all, qd_all in sample_chunks(seg.trajectory, n, dt):
                        t_next, stopped = run_chunk(si, q_all, qd_all, t_next, log)
                        if stopped is not None:
                            return stopped
                        q_c = q_all[-1]
                st = act.read()
                log.append(st.time, len(segments) - 1, st.position if q_c is None else q_c,
                           np.zeros(n_dof), st.position, st.velocity, st.effort)
                if self._encoder is not None:
                    log.encode(self._encoder())
                log.event(st.time, "done", "all segments completed")
                if self.progress is not None:
                    self.progress(1.0)
                return RunResult(log, True)
            except BaseException as e:  # a lost bus, a stop signal, a bad command: stop safely first
                log.event(safe_now(act), "abort", abort_reason(e))
                _safe_disable(act)
                raise
            finally:
                log.metadata["loop_wall_s"] = time.perf_counter() - began

    def _run_cycles(self, si: int, q_all: np.ndarray, qd_all: np.ndarray, t_next: float,
                    log: TrialLog) -> tuple[float, Optional[RunResult]]:
        """One chunk, cycle by cycle: read, record, check, command, wait."""
        act, dt, interlocks = self.act, self.dt, self.interlocks
        report_every, check = self._report_every, self.interrupts.check
        bus_time = self._bus_time  # None when not paced: no clock read beyond the backend's own
        encoder = self._encoder  # None unless a joint is read through another sensor
        sent = self._sent if bus_time is not None else None
        for k in range(len(q_all)):
            q_c, qd_c = q_all[k], qd_all[k]
            started = act.now() if bus_time is not None else 0.0
            st = act.read()
            log.append(st.time, si, q_c, qd_c, st.position, st.velocity, st.effort)
            if encoder is not None:
                log.encode(encoder())
            if interlocks is not None:
                trip = interlocks.check(st.time, st, q_c)
                if trip is not None:
                    return t_next, self._tripped(trip, st, si, log)
            act.command(q_c, qd_c)
            t_next += dt
            if bus_time is not None:  # the deadline is the next cycle's start
                now = act.now()
                if sent is not None:
                    sent(now)
                log.time_cycle(started, now - t_next, bus_time())
            act.wait_until(t_next)
            check()
            log.maybe_flush()
            self._done += 1
            if self.progress is not None and self._done % report_every == 0:
                self.progress(self._done / self._total)
        return t_next, None

    def _run_blocks(self, si: int, q_all: np.ndarray, qd_all: np.ndarray, t_next: float,
                    log: TrialLog) -> tuple[float, Optional[RunResult]]:
        """One chunk in blocks the backend runs whole; the interlocks scan each block after it."""
        act, interlocks = self.act, self.interlocks
        for b0 in range(0, len(q_all), BLOCK):
            q, qd = q_all[b0:b0 + BLOCK], qd_all[b0:b0 + BLOCK]
            # the same sums the cycle-by-cycle loop makes, in the same order
            ends = np.add.accumulate(np.concatenate(([t_next], np.full(len(q), self.dt))))[1:]
            states = act.execute_block(q, qd, ends)
            hit = None if interlocks is None else interlocks.scan(
                states.time, states.position, states.velocity, states.effort, q)
            if hit is None:
                log.append_block(states.time, si, q, qd, states.position, states.velocity,
                                 states.effort)
                if self._logged is not None:
                    self._logged()
                t_next = float(ends[-1])
                self.interrupts.check()
                log.maybe_flush()
                self._done += len(q)
                if self.progress is not None:
                    self.progress(self._done / self._total)
                continue
            j, trip = hit
            log.append_block(states.time[:j + 1], si, q[:j + 1], qd[:j + 1],
                             states.position[:j + 1], states.velocity[:j + 1], states.effort[:j + 1])
            st = act.rewind(j)
            return t_next, self._tripped(trip, st, si, log)
        return t_next, None

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
            if self._encoder is not None:
                log.encode(self._encoder())
        return RunResult(log, False, f"interlock {trip.interlock}: {trip.cause}", trip)


def abort_reason(e: BaseException) -> str:
    """One line for the log and the operator: why the run stopped."""
    if isinstance(e, KeyboardInterrupt):
        return str(e) if str(e).startswith("interrupted") else "interrupted (Ctrl-C)"
    return f"{type(e).__name__}: {e}"


def safe_now(act: Actuators) -> float:
    """The backend's clock, or NaN where it cannot say (a lost bus, a closed simulator): the log
    places an event at NaN after the one before it."""
    try:
        return act.now()
    except Exception:
        return float("nan")


def _safe_disable(act: Actuators) -> None:
    try:
        act.disable()
    except Exception:  # the bus may be gone; close() will try again
        pass
