"""The monitor: the twin's residuals, normalised, through the detector, every cycle of a trial.

Each reading the twin (:mod:`bench.monitor.twin`) predicts, every 10 ms, ends the interval it
stepped under the goals sent since; its residual over σ (the spread the model leaves on clean
trials; with the twin's timing spread in quadrature where the loop ran late) feeds the per-joint
CUSUM (:mod:`bench.monitor.detector`). The log holds it beside that reading, NaN beside the
readings between. An alarm names the joint, the time on the trial's
clock (seconds since its first reading, the clock of a fault's ``from_s``) and the score. With
``action: warn`` it is logged as a ``monitor`` event and the trial goes on; with ``action: stop`` it
is the trip that takes the safe stop, with the reason ``theta5 behaves unlike its model (…)``.

:class:`Watched` puts the monitor beside the interlocks, so the runner sees one trip check: the
interlocks' first, then the monitor's (which must see every cycle, the interlocks' fast path and
their block scan skipping the cycles that cannot trip).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from bench.core.safety import Trip
from bench.monitor.detector import Cusum, CusumParams, DEFAULT_CUSUM
from bench.monitor.twin import ServoTwin
from drivers import JointState

__all__ = ["Alarm", "TwinMonitor", "Watched"]


@dataclass(frozen=True)
class Alarm:
    joint: str
    t_s: float  #: since the trial's first reading
    signal: str  #: what the residual is of ("position" or "current")
    score: float  #: the CUSUM's sum when it crossed the threshold (σ)

    def as_dict(self) -> dict:
        return {"joint": self.joint, "t_s": round(self.t_s, 4), "signal": self.signal,
                "score": round(self.score, 2)}


@dataclass
class TwinMonitor:
    """The twin and its detector over the monitored joints; a trip check for the runner."""

    twin: ServoTwin
    joint_names: Sequence[str]
    sigma: np.ndarray  #: per joint, the residual's spread on clean trials (joint units)
    monitored: np.ndarray  #: per joint, whether it is watched (a joint on another sensor is not)
    model: str = "datasheet"
    action: str = "warn"
    cusum: CusumParams = DEFAULT_CUSUM
    log: Optional[object] = None  #: the trial's log, for the alarms' events
    loop_period_s: Optional[float] = None  #: the period the readings are due at (the twin's timing spread)
    #: per joint the current residual's spread (A at the motor); None: the current not watched
    current_sigma: Optional[np.ndarray] = None
    name: str = "monitor"
    alarms: list[Alarm] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        self._current = self.current_sigma is not None
        #: the detector's columns: each joint's position, then (where watched) each joint's current
        self.signals = ("position", "current") if self._current else ("position",)
        self._detector = Cusum(n * len(self.signals), self.cusum)
        inverse = 1.0 / np.asarray(self.sigma, dtype=float)
        self._scale = np.where(self.monitored, inverse, 0.0)  # the detector's: an unwatched joint's z is 0
        self._shown = np.where(self.monitored, inverse, np.nan)  # the log's: NaN where not watched
        if self._current:
            self._current_variance = np.asarray(self.current_sigma, dtype=float) ** 2
            # one row of residuals, position then current, and its scales for the detector and the log
            self._row = np.zeros(2 * n)
            self._row_scale = np.concatenate((self._scale, np.where(self.monitored, 1.0, 0.0)))
            self._row_shown = np.concatenate((self._shown, np.where(self.monitored, 1.0, np.nan)))
        self._variance = np.asarray(self.sigma, dtype=float) ** 2
        # the log's row where the twin predicted nothing
        self._unpredicted = np.full(n * len(self.signals), np.nan)
        self._t0: Optional[float] = None
        self._last: Optional[tuple[float, np.ndarray]] = None  # (time, goal) of the previous cycle
        self._before: Optional[np.ndarray] = None  # the goal in force until the previous cycle's left
        self._lag = 0.0  # how long after its reading the previous cycle's goal left (s)
        self._pending: list[np.ndarray] = []  # residuals over σ of the cycles not yet in the log
        self._cycles = 0  # the cycles checked
        self._written = 0  # the cycles whose residuals are in the log
        if self.log is not None:  # the journal says what is watched, and how, from the start
            self.log.start_twin(self._current)
            self.log.metadata["monitor"] = self.summary()

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Optional[Trip]:
        """The residual of the interval this reading ends; a trip when an alarm must stop the trial."""
        trip = self._step(t, measured.position, measured.velocity, commanded, measured.effort)
        self.logged()
        return trip

    def _step(self, t: float, position: np.ndarray, velocity: np.ndarray, commanded: np.ndarray,
              effort: np.ndarray) -> Optional[Trip]:
        trip = None
        if self._last is None:
            self._t0 = t
            self.twin.start(position, velocity, self.loop_period_s)
            self._pending.append(self._unpredicted)
        else:
            t_prev, goal = self._last
            interval = t - t_prev
            if self._lag > 0.0:  # the goal before held until this one left: the time-weighted goal
                lag = min(self._lag, interval)
                goal = goal + (self._before - goal) * (lag / interval)
            residual = self.twin.advance(goal, position, velocity, interval)
            if residual is None:  # a reading between the twin's predictions
                self._pending.append(self._unpredicted)
            else:
                trip = self._judge(t, residual, self.twin.timing, effort)
        self._before = self._last[1] if self._last is not None else commanded
        self._last = (t, commanded)  # the runner's own row of the plan, never changed after
        self._lag = 0.0
        self._cycles += 1
        return trip

    def sent(self, t: float) -> None:
        """The runner's word that the goal of the reading just checked left at ``t`` (a paced
        loop's clock): until then the goal before it was in force, which the twin then weighs in."""
        if self._last is not None:
            self._lag = max(0.0, t - self._last[0])

    def _judge(self, t: float, residual: np.ndarray, timing: Optional[np.ndarray],
               effort: np.ndarray) -> Optional[Trip]:
        """A prediction's residuals over σ into the log and the detector; a trip when it must stop."""
        if timing is not None:  # a late loop: σ and the timing spread in quadrature
            residual = residual * np.sqrt(self._variance / (self._variance + timing * timing))
        if self._current:
            twin, row, n = self.twin, self._row, len(residual)
            spread = twin.current_spread  # σ and what the model cannot tell of the current, in quadrature
            row[:n] = residual
            off = row[n:]
            twin.current_residual(twin.amps(effort), out=off)
            off /= np.sqrt(self._current_variance + spread * spread)
            if not off.dot(off) < np.inf:  # a reading without its current (NaN): that joint's sum waits
                off[np.isnan(off)] = 0.0
            self._pending.append(row * self._row_shown)
            hit = self._detector.update(row * self._row_scale)
        else:
            self._pending.append(residual * self._shown)
            hit = self._detector.update(residual * self._scale)
        return self._alarm(t, hit) if hit.size else None

    def logged(self) -> None:
        """Put the residuals of the cycles now in the log beside them (the runner calls this once a
        block's rows are in; a cycle's row is in before its check)."""
        if self.log is None:
            return
        upto = min(self._cycles, len(self.log))
        if upto > self._written:
            count = upto - self._written
            self.log.twin_rows(self._written, np.array(self._pending[:count]))
            del self._pending[:count]
            self._written = upto

    def _alarm(self, t: float, hit: np.ndarray) -> Optional[Trip]:
        score, n = self._detector.score, len(self.joint_names)
        width, latched, hits = len(score), self._detector.latched, set(hit.tolist())
        new, named = [], set()
        for j in hit:  # a joint whose other signal alarmed already (still latched) is that alarm still
            other = (j + n) % width
            if j % n in named or (other != j and latched[other] and other not in hits):
                continue
            named.add(j % n)
            new.append(Alarm(self.joint_names[j % n], t - self._t0, self.signals[j // n], float(score[j])))
        if not new:
            return None
        self.alarms.extend(new)
        first = new[0]
        why = (f"{first.joint} behaves unlike its model ({first.signal} CUSUM {first.score:.1f} σ > "
               f"{self.cusum.threshold:g} σ)")
        if self.log is not None:
            for a in new:
                self.log.event(t, "monitor", f"{a.joint} behaves unlike its model ({a.signal} CUSUM "
                               f"{a.score:.1f} σ at {a.t_s:.3f} s)")
        if self.action == "stop":
            return Trip("monitor", why, t, first.joint, first.score)
        return None

    def scan(self, times: np.ndarray, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
             commanded: np.ndarray, rows: Optional[int] = None) -> Optional[tuple[int, Trip]]:
        """Every row of a block in order (the first ``rows`` of them), as :meth:`check` would: the
        twin takes the rows between its predictions at once (:meth:`ServoTwin.advance_rows`)."""
        rows = len(times) if rows is None else rows
        if rows == 0:
            return None
        first = 0
        if self._last is None:  # the trial's first reading starts the twin
            self._step(float(times[0]), position[0], velocity[0], commanded[0], effort[0])
            first = 1
        t_prev, goal = self._last
        stamps = np.asarray(times[first:rows], dtype=float)
        if not len(stamps):
            return None
        intervals = np.diff(stamps, prepend=t_prev)
        goals = np.concatenate((goal[None, :], commanded[first:rows - 1]))
        written = first
        predictions = self.twin.advance_rows(goals, position[first:rows], velocity[first:rows], intervals)
        for k, residual, timing in predictions:
            row = first + k
            self._pending.extend([self._unpredicted] * (row - written))
            trip = self._judge(float(times[row]), residual, timing, effort[row])
            self._cycles += row - written + 1
            written = row + 1
            if trip is not None:  # the trial stops here: the rows after it are never the monitor's
                self._last = (float(times[row]), commanded[row])
                return row, trip
        self._pending.extend([self._unpredicted] * (rows - written))
        self._cycles += rows - written
        self._last = (float(times[rows - 1]), commanded[rows - 1])
        return None

    def summary(self) -> dict:
        """What ``trial --json`` and the record say of the monitor (its residuals: the log's)."""
        self.logged()
        return {"model": self.model, "action": self.action,
                "joints": [n for n, m in zip(self.joint_names, self.monitored) if m],
                "signals": list(self.signals),
                "cusum": {"drift_sigma": self.cusum.drift, "threshold_sigma": self.cusum.threshold},
                "alarms": [a.as_dict() for a in self.alarms],
                "first_alarm_s": round(self.alarms[0].t_s, 4) if self.alarms else None}

    def close(self) -> None:
        self.twin.close()


class Watched:
    """The interlocks and the monitor as the runner's one trip check (either may be None)."""

    def __init__(self, interlocks, monitor: TwinMonitor) -> None:
        self.interlocks = interlocks
        self.monitor = monitor

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Optional[Trip]:
        trip = None if self.interlocks is None else self.interlocks.check(t, measured, commanded)
        if trip is not None:
            return trip
        return self.monitor.check(t, measured, commanded)

    def scan(self, times, position, velocity, effort, commanded) -> Optional[tuple[int, Trip]]:
        """The interlocks' first trip in the block, unless the monitor stops the trial before it;
        the monitor sees the rows up to the interlocks' trip, none after."""
        hit = None if self.interlocks is None else self.interlocks.scan(times, position, velocity, effort, commanded)
        rows = len(times) if hit is None else hit[0]
        mine = self.monitor.scan(times, position, velocity, effort, commanded, rows)
        return mine if mine is not None else hit

    def logged(self) -> None:
        self.monitor.logged()

    def sent(self, t: float) -> None:
        self.monitor.sent(t)
