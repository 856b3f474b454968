"""Whether the control loop kept time: achieved period, bus time and missed deadlines, from the log.

A hardware-in-the-loop run is only as good as its loop kept time. In a paced trial (the rig's
bus, real or emulated, on the wall clock) each cycle's deadline is the next cycle's start: a cycle
whose read, interlock check and command ended after it *missed its deadline*, as ros2_control's
controller manager reports an overrun. A simulator's clock runs as fast as the CPU allows: the
loop is *not paced*, has no deadline to miss, and only its speed against real time is told. A log
written before the loop was timed says *not recorded*.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal, Optional

import numpy as np

from bench.core.log import TrialLog

__all__ = ["MISSED_SHARE_LIMIT", "LoopTiming", "loop_timing"]

#: A run that missed more than this share of its deadlines says so in its verdict line.
MISSED_SHARE_LIMIT = 0.01

State = Literal["paced", "not paced", "not recorded"]


def _ms(seconds: Optional[float]) -> str:
    return "?" if seconds is None else f"{seconds * 1e3:.2f} ms"


@dataclass(frozen=True)
class LoopTiming:
    """The loop's timing in a trial, in s (SI): what the report, the console and ``--json`` say."""

    state: State
    period_s: Optional[float] = None  #: the configured control period
    cycles: int = 0  #: cycles timed (a paced trial's)
    period_median_s: Optional[float] = None  #: achieved period, between cycle starts
    period_p99_s: Optional[float] = None
    period_max_s: Optional[float] = None
    bus_median_s: Optional[float] = None  #: a cycle's bus transactions (write and read)
    bus_p99_s: Optional[float] = None
    missed: int = 0  #: cycles whose work ended after their deadline
    missed_share: float = 0.0
    worst_late_s: Optional[float] = None  #: how late the worst miss ended
    worst_at_s: Optional[float] = None  #: when it ran, s into the trial
    worst_segment: Optional[str] = None
    first_missed_at_s: Optional[float] = None
    wall_s: Optional[float] = None  #: the loop's wall-clock time
    sim_s: Optional[float] = None  #: the trial time it covered (simulated, or on the rig's clock)
    #: paced: the priority the loop ran at (``nice -10``, or the one kept and why), as recorded
    priority: Optional[str] = None
    #: paced: how long the loop was runnable but waited for a CPU (other work on the machine ran)
    cpu_waited_s: Optional[float] = None
    #: paced: how long a hypervisor took this machine's CPUs meanwhile (per CPU)
    cpu_stolen_s: Optional[float] = None
    #: paced: the clock the deadlines were on: ``wall``, or ``virtual`` (an emulated rig on the virtual
    #: clock: a deadline is missed only by the modelled wire time, never by the machine)
    clock: Optional[str] = None

    @property
    def late(self) -> bool:
        """More than :data:`MISSED_SHARE_LIMIT` of the deadlines missed: the verdict says so."""
        return self.state == "paced" and self.missed > MISSED_SHARE_LIMIT * self.cycles

    def verdict_note(self) -> str:
        """What the verdict line adds ("" when the loop kept time or was not paced)."""
        if not self.late:
            return ""
        return (f"the loop missed {self.missed} of {self.cycles} deadlines "
                f"({100 * self.missed_share:.1f} %, over {100 * MISSED_SHARE_LIMIT:g} %){self._withheld()}")

    def _withheld(self) -> str:
        """What the machine withheld from the loop, where it was enough to say (a tenth of a second)."""
        said = []
        if self.cpu_waited_s is not None and self.cpu_waited_s >= 0.1:
            said.append(f"it waited {self.cpu_waited_s:.2f} s for a CPU other work held")
        if self.cpu_stolen_s is not None and self.cpu_stolen_s >= 0.1:
            said.append(f"the hypervisor took {self.cpu_stolen_s:.2f} s of each CPU")
        return f"; {' and '.join(said)}" if said else ""

    def summary_line(self) -> str:
        """One line for the console."""
        if self.state == "not recorded":
            return "loop timing: not recorded (a log from before the loop was timed)"
        if self.state == "not paced":
            return f"loop timing: not paced: {self._speed()}"
        if not self.cycles:
            return "loop timing: no cycle was timed"
        line = (f"loop timing{self._at()}{self._on_clock()}: period {_ms(self.period_median_s)} median, {_ms(self.period_p99_s)} p99, "
                f"{_ms(self.period_max_s)} max (set {_ms(self.period_s)}); bus {_ms(self.bus_median_s)} "
                f"median, {_ms(self.bus_p99_s)} p99; ")
        return line + self._missed_words()

    def _at(self) -> str:
        return f" (at {self.priority})" if self.priority and self.clock != "virtual" else ""

    def _on_clock(self) -> str:
        """On the virtual clock: how fast its trial time ran against the wall clock."""
        if self.clock != "virtual":
            return ""
        speed = f", {self.sim_s / self.wall_s:.1f}× real time" if self.wall_s and self.sim_s else ""
        return f" (virtual clock{speed})"

    def _missed_words(self) -> str:
        if not self.missed:
            return f"no missed deadline in {self.cycles} cycles"
        return (f"{self.missed} of {self.cycles} deadlines missed ({100 * self.missed_share:.1f} %), the "
                f"worst {_ms(self.worst_late_s)} late at {self.worst_at_s:.2f} s ({self.worst_segment})"
                f"{self._withheld()}")

    def _speed(self) -> str:
        words = "a simulated clock has no wall-clock deadline"
        if self.wall_s and self.sim_s:
            words += (f"; {self.sim_s:.2f} s simulated in {self.wall_s:.2f} s, "
                      f"{self.sim_s / self.wall_s:.1f}× real time")
        return words

    def markdown(self) -> str:
        """The report's section body."""
        if self.state == "not recorded":
            return "Not recorded: this log was written before the bench timed its loop.\n"
        if self.state == "not paced":
            return (f"Not paced: {self._speed()}, so no cycle can miss one. The control period is "
                    f"{_ms(self.period_s)} of simulated time.\n")
        if not self.cycles:
            return "No cycle was timed (the trial stopped before its first command).\n"
        rows = ["| | median | p99 | max |", "|---|---:|---:|---:|",
                f"| achieved period (set {_ms(self.period_s)}) | {_ms(self.period_median_s)} | "
                f"{_ms(self.period_p99_s)} | {_ms(self.period_max_s)} |",
                f"| bus transactions per cycle | {_ms(self.bus_median_s)} | {_ms(self.bus_p99_s)} | |"]
        said = (f"A cycle's deadline is the next cycle's start: its read, interlock check and command "
                f"must end before it. {self._missed_words()[0].upper()}{self._missed_words()[1:]}")
        if self.missed:
            said += f"; the first at {self.first_missed_at_s:.2f} s"
        said += "."
        if self.clock == "virtual":
            said += (f" The deadlines were on the virtual clock: only the modelled wire time can miss "
                     f"one, never the machine; {self._speed().split('; ', 1)[-1]}.")
        elif self.priority:
            said += f" The loop ran at {self.priority}."
        if self.late:
            said += (f" **More than {100 * MISSED_SHARE_LIMIT:g} % missed: the loop did not keep time, "
                     f"and the trial's tracking is not the rig's alone.**")
        return "\n".join(rows) + "\n\n" + said + "\n"

    def as_dict(self) -> dict:
        """For ``--json`` and result.json (s to 0.1 µs; ``late`` and the verdict note spelled out)."""
        tidy = {k: round(v, 7) if isinstance(v, float) else v for k, v in asdict(self).items()}
        return tidy | {"late": self.late, "verdict": self.verdict_note()}


def _p(values: np.ndarray, q: float) -> Optional[float]:
    return float(np.percentile(values, q)) if values.size else None


def loop_timing(log: TrialLog, period_s: Optional[float] = None) -> LoopTiming:
    """The loop's timing as the log recorded it (see the module's note on the three states)."""
    meta = log.metadata
    period_s = period_s if period_s is not None else meta.get("control_period")
    if not log.timed:
        if meta.get("loop_wall_s") is None:
            return LoopTiming("not recorded", period_s)
        sim_s = float(log.time[-1] - log.time[0]) if len(log) > 1 else 0.0
        return LoopTiming("not paced", period_s, wall_s=float(meta["loop_wall_s"]), sim_s=sim_s)
    start, late, bus = log.loop_start, log.loop_late, log.bus_s
    timed = np.isfinite(late)
    clock = meta.get("loop_clock") if isinstance(meta.get("loop_clock"), str) else None
    wall = meta.get("loop_wall_s")
    spans = dict(wall_s=float(wall) if isinstance(wall, (int, float)) else None,
                 sim_s=float(log.time[-1] - log.time[0]) if len(log) > 1 else None, clock=clock)
    cycles = int(timed.sum())
    withheld = {k: meta.get(f"loop_{k}") if isinstance(meta.get(f"loop_{k}"), (int, float)) else None
                for k in ("cpu_waited_s", "cpu_stolen_s")}
    if not cycles:
        return LoopTiming("paced", period_s, priority=_priority(meta), **withheld, **spans)
    both = np.isfinite(start[1:]) & np.isfinite(start[:-1])
    periods = np.diff(start)[both]
    buses = bus[np.isfinite(bus)]
    missed = timed & (late > 0)
    n_missed = int(missed.sum())
    t0 = float(log.time[0])
    worst = worst_at = worst_seg = first = None
    if n_missed:
        i = int(np.nanargmax(np.where(missed, late, np.nan)))
        worst, worst_at = float(late[i]), float(log.time[i]) - t0
        seg, names = int(log.segment[i]), log.segment_names
        worst_seg = names[seg] if 0 <= seg < len(names) else f"segment {seg}"
        first = float(log.time[int(np.argmax(missed))]) - t0
    return LoopTiming("paced", period_s, cycles,
                      float(np.median(periods)) if periods.size else None, _p(periods, 99),
                      float(periods.max()) if periods.size else None,
                      float(np.median(buses)) if buses.size else None, _p(buses, 99),
                      n_missed, n_missed / cycles, worst, worst_at, worst_seg, first,
                      priority=_priority(meta), **withheld, **spans)


def _priority(meta: dict) -> Optional[str]:
    got = meta.get("loop_priority")
    return got if isinstance(got, str) else None
