"""An emulated-rig trial's figures are the rig's only when its loop kept time.

The bench's own verdict (:mod:`bench.core.looptiming`) says when a paced loop missed more than 1 %
of its deadlines: its tracking is then not the rig's alone. On a shared machine, whose other work
can hold the loop up for tens of milliseconds at a time, a test whose figure fails on such a run
runs the trial again, up to :data:`TRIES` runs in all. A figure that fails on a run whose loop kept
time fails the test at once; one that holds counts, late loop or not.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")

#: Runs in all before a test gives up on this machine keeping the loop's time.
TRIES = 3


def until_paced(run: Callable[[], T], timings: Callable[[T], Iterable[dict]], check: Callable[[T], None],
                what: str) -> T:
    """``run()`` until ``check`` (asserts the figures) passes on its result; a failure is run again
    only where ``timings`` finds a loop of that run that missed over 1 % of its deadlines."""
    late_runs = []
    for attempt in range(1, TRIES + 1):
        out = run()
        try:
            check(out)
        except AssertionError as failure:
            late = [t for t in timings(out) if t.get("late")]
            if not late:
                raise  # the loop kept time: the figure is the rig's, and it failed
            late_runs.append(", ".join(f"{t['missed']} of {t['cycles']} deadlines{_withheld(t)}"
                                       for t in late))
            last = failure
            continue
        if late_runs:
            warnings.warn(f"{what}: run {attempt} of {TRIES} held its figures; before it the loop missed "
                          f"{'; '.join(late_runs)}")
        return out
    raise AssertionError(f"{what}: the figures failed in each of {TRIES} runs, each with a loop that "
                         f"missed over 1 % of its deadlines on this machine ({'; '.join(late_runs)}); "
                         f"the last: {last}")


def _withheld(timing: dict) -> str:
    waited, stolen = timing.get("cpu_waited_s"), timing.get("cpu_stolen_s")
    return "" if waited is None else f" (waited {waited:.2f} s for a CPU, {stolen or 0:.2f} s stolen)"


def logged_timings(run_dirs: Iterable[Path]) -> list[dict]:
    """The loop timing of each run directory's saved log (what ``--json`` says of a trial)."""
    from bench.core.log import TrialLog
    from bench.core.looptiming import loop_timing

    return [loop_timing(TrialLog.load(d / "trial.npz")).as_dict() for d in run_dirs]
