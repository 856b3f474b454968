"""One seed's crossing along a line: the bracket of the margin's zero in t ∈ [0, 1].

A search asks for one point at a time and is told the margin there (falsification's score: above
zero every requirement holds). It starts at the points it is given: the line's two ends for a first
search; for a further seed, the point nearest the first seed's crossing, with that crossing's slope
as a hint. Then:

- while no pair of its points has opposite signs, a secant step toward the zero (the hint's slope
  until it has two points of its own), a little past the zero so that a good estimate brackets it,
  clamped into [0, 1]; it ends without a crossing once an end of the line has the same sign;
- once bracketed: regula falsi, the score of an end kept twice in a row halved (Illinois), so a
  curved margin does not pin the estimate to one end; a step 0.9 × the tolerance past an estimate
  whose secant puts the zero that close (the bracket closes at once); a bisection after two steps
  that did not halve the bracket (it halves whatever the margin's shape); until the bracket is
  narrower than the tolerance.

The bracket is the first sign change along the line among the points so far, so a margin that is
not monotone is still bracketed somewhere; :meth:`Bracket.monotone` says whether it is.
"""

from __future__ import annotations

import math
from typing import Callable, Optional, Sequence

__all__ = ["Bracket", "finite"]

#: A trial that failed without a margin (stopped before its placement) counts as failing by far.
FAILED_WITHOUT_MARGIN = -1e6


def finite(score: float) -> float:
    """The score as a number to interpolate: −∞ (no margin) becomes a large negative one."""
    return score if math.isfinite(score) else FAILED_WITHOUT_MARGIN


class Bracket:
    """The zero of one seed's margin along t ∈ [0, 1], to ``tolerance`` of the line."""

    def __init__(self, tolerance: float, budget: int, start: Sequence[float] = (0.0, 1.0),
                 slope: Optional[float] = None, snap: Callable[[float], float] = lambda t: t) -> None:
        self.tolerance, self.budget, self.slope, self.snap = tolerance, budget, slope, snap
        self.points: list[tuple[float, float, Optional[str]]] = []  # (t, score, worst), as told
        self._start = [snap(t) for t in start]
        self._estimate: Optional[float] = None  # the last regula falsi estimate
        self._widths: list[float] = []  # the bracket's width at each narrowing step
        self._kept: tuple[Optional[float], int] = (None, 0)  # the end kept by the last estimates, how often
        self.done = False

    # -- what the points say --------------------------------------------------

    def seen(self, t: float) -> bool:
        return any(abs(t - p) <= 1e-12 for p, _, _ in self.points)

    def bracket(self) -> Optional[tuple[tuple[float, float], tuple[float, float]]]:
        """The first sign change along the line: ((t, score) holding, (t, score) failing) in the
        order of t, or None."""
        pts = sorted((t, finite(s)) for t, s, _ in self.points)
        for a, b in zip(pts, pts[1:]):
            if (a[1] >= 0) != (b[1] >= 0):
                return a, b
        return None

    def monotone(self) -> bool:
        pts = sorted((t, finite(s)) for t, s, _ in self.points)
        diffs = [b[1] - a[1] for a, b in zip(pts, pts[1:])]
        return all(d <= 1e-9 for d in diffs) or all(d >= -1e-9 for d in diffs)

    def crossing(self) -> Optional[float]:
        """Where the straight line through the bracket's two scores crosses zero (within it)."""
        br = self.bracket()
        return None if br is None else secant_zero(*br)

    # -- the next point -------------------------------------------------------

    def next_value(self) -> Optional[float]:
        """The next t to try, or None when the search has ended (call once per point told)."""
        if self.done or len(self.points) >= self.budget:
            self.done = True
            return None
        for t in self._start:
            if not self.seen(t):
                return t
        br = self.bracket()
        t = self._widen() if br is None else self.narrow(br)
        if t is None or self.seen(self.snap(t)):
            self.done = True
            return None
        return self.snap(t)

    def tell(self, t: float, score: float, worst: Optional[str]) -> None:
        self.points.append((t, score, worst))

    def _widen(self) -> Optional[float]:
        """A secant step toward the zero from the point nearest it, past it by half the tolerance."""
        pts = sorted(((t, finite(s)) for t, s, _ in self.points), key=lambda p: abs(p[1]))
        if not pts:
            return None
        (t0, f0) = pts[0]
        slope = self.slope
        if len(pts) > 1 and pts[1][0] != t0:
            own = (pts[1][1] - f0) / (pts[1][0] - t0)
            if own != 0 and (slope is None or (own > 0) == (slope > 0)):
                slope = own
        if not slope:
            return None
        t = t0 - f0 / slope
        t += 0.5 * self.tolerance * _direction(t0, t)
        t = min(1.0, max(0.0, t))
        return None if abs(t - t0) <= 1e-12 else t

    def narrow(self, br: tuple[tuple[float, float], tuple[float, float]]) -> Optional[float]:
        """The next t inside the bracket ``br`` ((t, score) at each end), or None when it is
        narrower than the tolerance."""
        (x0, f0), (x1, f1) = br
        width = abs(x1 - x0)
        if width <= self.tolerance:
            return None
        self._widths.append(width)
        last = self.points[-1][0] if self.points else None
        if self._estimate is not None and last == self._estimate and last in (x0, x1) and f1 != f0:
            # the last estimate is an end: when the bracket's secant puts the zero within 0.9 × the
            # tolerance of it, a step that far toward the other end closes the bracket at once
            self._estimate = None
            f_last, other = (f0, x1) if last == x0 else (f1, x0)
            if abs(f_last) * width / abs(f1 - f0) < 0.9 * self.tolerance:
                return last + 0.9 * self.tolerance * _direction(last, other)
        if len(self._widths) >= 3 and self._widths[-1] > 0.5 * self._widths[-3]:
            self._estimate = None  # two steps that did not halve it: a bisection, whatever the shape
            self._widths.clear()
            return 0.5 * (x0 + x1)
        # regula falsi, the score of an end kept twice in a row halved (Illinois): the estimate
        # moves off an end that a curved margin would otherwise pin it to
        kept = x0 if last == x1 else x1 if last == x0 else None
        self._kept = (kept, self._kept[1] + 1 if kept == self._kept[0] else 0)
        scale = 0.5 ** self._kept[1]
        g0, g1 = (f0 * scale, f1) if kept == x0 else (f0, f1 * scale) if kept == x1 else (f0, f1)
        t = secant_zero((x0, g0), (x1, g1))
        if min(abs(t - x0), abs(t - x1)) <= 1e-9 * max(1.0, width):
            t = 0.5 * (x0 + x1)  # regula falsi on an end: nothing learnt there
        self._estimate = self.snap(t)
        return t


def secant_zero(p0: tuple[float, float], p1: tuple[float, float]) -> float:
    """The zero of the straight line through two (t, score) points, kept between them."""
    (x0, f0), (x1, f1) = p0, p1
    t = x0 - f0 * (x1 - x0) / (f1 - f0) if f1 != f0 else 0.5 * (x0 + x1)
    return min(max(x0, x1), max(min(x0, x1), t))


def _direction(start: float, toward: float) -> float:
    """+1 or -1: which way along the axis ``toward`` lies from ``start`` (+1 where they meet)."""
    return 1.0 if toward >= start else -1.0
