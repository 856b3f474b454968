"""An emulated-rig trial's figures are the rig's only when its loop kept time.

The bench's own verdict (:mod:`bench.core.looptiming`) says when a paced loop missed more than 1 %
of its deadlines: its tracking is then not the rig's alone. On a shared machine, whose other work
can hold the loop up for tens of milliseconds at a time, a test of such figures runs the trial
again, up to :data:`TRIES` runs in all, and fails saying so if the loop never kept time.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")

#: Runs in all before a test gives up on this machine keeping the loop's time.
TRIES = 3


def until_paced(run: Callable[[], T], timings: Callable[[T], Iterable[dict]], what: str) -> T:
    """``run()`` until every loop timing ``timings`` finds in its result kept time; that result."""
    missed = []
    for attempt in range(1, TRIES + 1):
        out = run()
        late = [t for t in timings(out) if t.get("late")]
        if not late:
            if missed:
                warnings.warn(f"{what}: run {attempt} of {TRIES} kept time; before it the loop missed "
                              f"{'; '.join(missed)}")
            return out
        missed.append(", ".join(f"{t['missed']} of {t['cycles']} deadlines{_withheld(t)}" for t in late))
    raise AssertionError(f"{what}: the loop missed over 1 % of its deadlines in each of {TRIES} runs on "
                         f"this machine ({'; '.join(missed)}): its figures are not the rig's")


def _withheld(timing: dict) -> str:
    waited, stolen = timing.get("cpu_waited_s"), timing.get("cpu_stolen_s")
    return "" if waited is None else f" (waited {waited:.2f} s for a CPU, {stolen or 0:.2f} s stolen)"


def logged_timings(run_dirs: Iterable[Path]) -> list[dict]:
    """The loop timing of each run directory's saved log (what ``--json`` says of a trial)."""
    from bench.core.log import TrialLog
    from bench.core.looptiming import loop_timing

    return [loop_timing(TrialLog.load(d / "trial.npz")).as_dict() for d in run_dirs]
