"""A boundary along one line of a spec's axis space, under the trial's own randomness.

A :class:`Line` runs from the least fault (every axis at its start) along one axis, or along a ray
in the plane of two. :class:`LineBoundary` finds where its margin crosses zero:

1. The first seed brackets the crossing (:class:`bench.campaign.bracket.Bracket`); where its margin
   turns out not to be monotone, active level-set sampling takes over
   (:class:`bench.campaign.levelset.LevelSet`), within the same budget.
2. A second seed is tried at the bracket's end nearest the crossing. The same margin there means
   the trial is deterministic (a bias): the interval is the bracket.
3. Otherwise (noise, a deadband, anything drawn from the trial's seed) each further seed, up to the
   number asked for, brackets its own crossing from there (the first seed's slope as a hint, a few
   trials each). The boundary is the median of the seeds' crossings, where half of the trials fail;
   the interval is their range, where the trials go from all passing to all failing.

Every point of a seed's search runs with that seed (the spec's repeat index), so a seed's margin
is a curve of the fault's magnitude alone (common random numbers), which a bracket can close.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from bench.campaign.bracket import Bracket, finite
from bench.campaign.levelset import LevelSet

__all__ = ["Evaluate", "Line", "LineBoundary", "LineResult", "RANDOM_SEEDS", "SEED_TRIALS", "search_lines",
           "trial_key"]

#: Seeds a random trial is bracketed with when the spec runs each draw once.
RANDOM_SEEDS = 5
#: Trials each further seed may take to bracket its own crossing.
SEED_TRIALS = 4


@dataclass(frozen=True)
class Line:
    """Axis values along t ∈ [0, 1]: ``start`` plus t × ``step`` on the moving axes."""

    label: str
    start: dict[str, Any]
    step: dict[str, float]
    integer: frozenset[str] = frozenset()

    def values(self, t: float) -> dict[str, Any]:
        out = dict(self.start)
        for k, d in self.step.items():
            v = self.start[k] + t * d
            out[k] = int(round(v)) if k in self.integer else float(v)
        return out

    def snap(self, t: float) -> float:
        """t moved to the nearest point the line can take (a whole number on an integer axis)."""
        if len(self.step) != 1 or not self.integer:
            return t
        ((k, d),) = self.step.items()
        return (round(self.start[k] + t * d) - self.start[k]) / d


@dataclass
class LineResult:
    """A line's boundary in t: the crossing, its interval and how the interval was made."""

    crossing: Optional[float]
    interval: Optional[tuple[float, float]]
    kind: str  # "bracket" (deterministic, or one seed) or "seeds" (the range of the seeds' crossings)
    crossings: list[Optional[float]]  # each seed's, None where it held across the line
    requirement: Optional[str]
    trials: int
    method: str


@dataclass
class LineBoundary:
    """The search of one line; ``asks()`` the (t, seed) points it wants, ``tell()`` their scores."""

    line: Line
    tolerance: float
    max_trials: int
    seeds: Optional[int] = None  # None: RANDOM_SEEDS once the trial turns out random; 1: one seed, no check
    first: Bracket = field(init=False)
    levelset: Optional[LevelSet] = field(default=None, init=False)
    random: Optional[bool] = field(default=None, init=False)
    others: list[Bracket] = field(default_factory=list, init=False)
    told: dict[tuple[float, int], tuple[float, Optional[str]]] = field(default_factory=dict, init=False)
    _pending: list[tuple[float, int]] = field(default_factory=list, init=False)
    _check: Optional[tuple[float, float]] = field(default=None, init=False)  # (t, first seed's score)

    def __post_init__(self) -> None:
        self.first = Bracket(self.tolerance, self.max_trials, snap=self.line.snap)

    def asks(self) -> list[tuple[float, int]]:
        """The points wanted now (the same until they are told); empty when the search has ended."""
        if not self._pending:
            self._pending = self._next()
        return list(self._pending)

    def tell(self, t: float, seed: int, score: float, worst: Optional[str]) -> None:
        self._pending = [p for p in self._pending if p != (t, seed)]
        self.told[(t, seed)] = (score, worst)
        if seed == 0:
            self.first.tell(t, score, worst)
            if self.levelset is None and len(self.first.points) >= 3 and not self.first.monotone():
                self.levelset = LevelSet(self.first, self.max_trials)
        elif self.random is None:
            self.random = abs(finite(score) - self._check[1]) > 1e-9
            if self.random:
                self._start_seeds(t, score, worst)
        else:
            self.others[seed - 1].tell(t, score, worst)

    def _next(self) -> list[tuple[float, int]]:
        search = self.levelset or self.first
        if not search.done:
            t = search.next_value()
            if t is not None:
                return [(t, 0)]
        if self.seeds == 1:
            return []
        if self.random is None:
            self._check = self._check_point()
            return [] if self._check is None else [(self._check[0], 1)]
        asks = []
        for r, s in enumerate(self.others, start=1):
            t = s.next_value()
            if t is not None:
                asks.append((t, r))
        return asks

    def _bracket(self) -> Optional[tuple[tuple[float, float], tuple[float, float]]]:
        return self.levelset.first_failure() if self.levelset else self.first.bracket()

    def _check_point(self) -> Optional[tuple[float, float]]:
        """The first seed's point nearest its crossing (or, with none, its lowest score)."""
        br = self._bracket()
        pts = list(br) if br else [(t, finite(s)) for t, s, _ in self.first.points]
        if not pts:
            return None
        return min(pts, key=lambda p: abs(p[1])) if br else min(pts, key=lambda p: p[1])

    def _start_seeds(self, t: float, score: float, worst: Optional[str]) -> None:
        """Each further seed's search, from the check's point, with the first seed's slope."""
        br = self._bracket()
        pts = list(br) if br else sorted((p, finite(s)) for p, s, _ in self.first.points)
        (x0, f0), (x1, f1) = pts[0], pts[-1]  # the bracket, or the line's ends
        slope = (f1 - f0) / (x1 - x0) if x1 != x0 and f1 != f0 else None
        n = self.seeds or RANDOM_SEEDS
        self.others = [Bracket(self.tolerance, SEED_TRIALS, start=(t,), slope=slope, snap=self.line.snap)
                       for _ in range(1, n)]
        if self.others:
            self.others[0].tell(t, score, worst)

    def result(self) -> LineResult:
        trials = len(self.told)
        search = self.levelset or self.first
        br = self._bracket()
        method = ("active level-set sampling (the margin is not monotone)" if self.levelset
                  else "regula falsi, guarded by bisection")
        if self.levelset is not None and self.levelset.uncertain:
            method += "; a crossing before it is not ruled out within the budget"
        requirement = _failing_worst(self.first.points)
        if not self.random:
            crossing = search.crossing()
            if crossing is None:
                return LineResult(None, None, "bracket", [None], requirement, trials,
                                  _no_crossing(self.first))
            (x0, _), (x1, _) = br
            how = "one seed" if self.seeds == 1 else "deterministic: a second seed gave the same margin"
            return LineResult(crossing, (min(x0, x1), max(x0, x1)), "bracket", [crossing], requirement,
                              trials, f"{method}; {how}")
        seeds = [self.first, *self.others]
        crossings = [_seed_crossing(search)] + [_seed_crossing(s) for s in self.others]
        found = [c for c in crossings if c is not None]
        if not found:
            return LineResult(None, None, "seeds", crossings, requirement, trials,
                              f"no crossing in the range for any of {len(seeds)} seeds")
        ranked = sorted(found) + [float("inf")] * (len(crossings) - len(found))
        median = statistics.median_low(ranked)
        for s in self.others:
            requirement = requirement or _failing_worst(s.points)
        # seeds that held across the line leave the interval open to its end
        interval = (min(found), max(found) if len(found) == len(crossings) else 1.0)
        return LineResult(None if median == float("inf") else median, interval, "seeds", crossings,
                          requirement, trials, f"{method}; {len(seeds)} seeds, the median of their crossings")


def _seed_crossing(search: Bracket | LevelSet) -> Optional[float]:
    """A seed's crossing: within its bracket; 0 where it fails at the least fault; else, when its
    few trials did not bracket it, the zero of the secant through its two points nearest zero if
    that falls on the line (None: it holds across the line, as far as its trials tell)."""
    crossing = search.crossing()
    if crossing is not None:
        return crossing
    pts = sorted(((t, finite(s)) for t, s, _ in search.points), key=lambda p: abs(p[1]))
    if any(t == 0.0 and f < 0 for t, f in pts):
        return 0.0
    pts = pts[:2]
    if len(pts) < 2 or pts[0][1] == pts[1][1]:
        return None
    (x0, f0), (x1, f1) = pts
    t = x0 - f0 * (x1 - x0) / (f1 - f0)
    return t if 0.0 <= t <= 1.0 else None


def _failing_worst(points: list[tuple[float, float, Optional[str]]]) -> Optional[str]:
    """The requirement that fails first along the line: the worst at its first failing point."""
    failing = sorted((t, w) for t, s, w in points if finite(s) < 0)
    return failing[0][1] if failing else None


def _no_crossing(search: Bracket) -> str:
    scores = [finite(s) for _, s, _ in search.points]
    if scores and all(s < 0 for s in scores):
        return "no crossing in the range: it fails at both ends"
    return "no crossing in the range"


#: Runs trials at (axis values, seed) and gives back each one's (score, worst requirement).
Evaluate = Callable[[list[tuple[dict, int]]], list[tuple[float, Optional[str]]]]


def search_lines(searches: list[LineBoundary], evaluate: Evaluate,
                 progress: Callable[[int], None] = lambda ran: None) -> int:
    """Run the searches side by side, one batch of trials per step, each distinct trial once
    (the lines share their start, a pair's edge rays are its axes' lines); return the trials run."""
    cache: dict[str, tuple[float, Optional[str]]] = {}
    ran = 0
    while True:
        asks = [(s, t, r) for s in searches for (t, r) in s.asks()]
        if not asks:
            return ran
        keys = [trial_key(s.line.values(t), r) for s, t, r in asks]
        new: dict[str, tuple[dict, int]] = {}
        for (s, t, r), key in zip(asks, keys):
            if key not in cache and key not in new:
                new[key] = (s.line.values(t), r)
        if new:
            for key, res in zip(new, evaluate(list(new.values()))):
                cache[key] = res
            ran += len(new)
        for (s, t, r), key in zip(asks, keys):
            s.tell(t, r, *cache[key])
        progress(ran)


def trial_key(values: dict[str, Any], seed: int) -> str:
    """One trial's identity: its axis values and its seed."""
    return repr((sorted(values.items()), seed))
