"""Active level-set sampling: the first zero of a margin that is not monotone along a line.

Bracketing finds *a* zero; where the margin rises again somewhere along the line, the zero where a
requirement *starts* failing may lie before the one bracketed. The points are modelled by a
Gaussian process (a straight-line trend, a squared-exponential kernel whose length scale maximises
the marginal likelihood over a few candidates, a small nugget) and the next point is where the
sign of the margin is least certain (the *straddle* heuristic of Bryan et al., 2005: the largest
1.96 σ − |μ|), searched before the first failing point (beyond it, nothing changes where failing
starts). When no point is uncertain, the bracket of the first failing point is narrowed as a
bracket is; the search ends when that bracket is within the tolerance, or at the budget.

Plain numpy: a line has a few dozen points at most.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from bench.campaign.bracket import Bracket, finite, secant_zero

__all__ = ["LevelSet", "posterior"]

_LENGTHS = (0.03, 0.06, 0.12, 0.25, 0.5, 1.0)  # of the line, tried for the kernel
_NUGGET = 1e-6  # of the signal's variance: a deterministic margin, kept invertible
_CLIP = 3.0  # margins beyond ±3 (of their scale) are clipped: far from zero, only their sign counts
_Z = 1.96
_CANDIDATES = 401


def _kernel(a: np.ndarray, b: np.ndarray, length: float) -> np.ndarray:
    return np.exp(-0.5 * ((a[:, None] - b[None, :]) / length) ** 2)


def posterior(t: np.ndarray, y: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The margin's mean and standard deviation at ``query`` given scores ``y`` at ``t``."""
    t, y, query = (np.asarray(v, dtype=float) for v in (t, y, query))
    y = np.clip(y, -_CLIP, _CLIP)
    basis = np.stack([np.ones_like(t), t], axis=1)
    coef = np.linalg.lstsq(basis, y, rcond=None)[0] if len(t) > 1 else np.array([y.mean(), 0.0])
    r = y - basis @ coef
    best = None
    for length in _LENGTHS:
        k = _kernel(t, t, length) + _NUGGET * np.eye(len(t))
        chol = np.linalg.cholesky(k)
        alpha = np.linalg.solve(chol.T, np.linalg.solve(chol, r))
        var = max(float(r @ alpha) / len(t), 1e-12)  # the signal's variance, at its likelihood's maximum
        nll = 0.5 * len(t) * math.log(var) + float(np.log(np.diag(chol)).sum())
        if best is None or nll < best[0]:
            best = (nll, length, chol, alpha, var)
    _, length, chol, alpha, var = best
    ks = _kernel(query, t, length)
    mean = np.stack([np.ones_like(query), query], axis=1) @ coef + ks @ alpha
    v = np.linalg.solve(chol, ks.T)
    sd = np.sqrt(np.maximum(var * (1.0 + _NUGGET - np.sum(v * v, axis=0)), 0.0))
    return mean, sd


class LevelSet:
    """Takes over a seed's search whose margin is not monotone: the first zero along the line."""

    def __init__(self, search: Bracket, budget: int) -> None:
        self.search, self.budget = search, budget
        self.uncertain = False  # at the end: a point before the first failure still uncertain
        self.done = False

    @property
    def points(self) -> list[tuple[float, float, Optional[str]]]:
        return self.search.points

    def first_failure(self) -> Optional[tuple[tuple[float, float], tuple[float, float]]]:
        """(t, score) of the last holding point before the first failing one, and that one."""
        pts = sorted((t, finite(s)) for t, s, _ in self.points)
        if not pts or pts[0][1] < 0:
            return None
        for a, b in zip(pts, pts[1:]):
            if b[1] < 0:
                return a, b
        return None

    def crossing(self) -> Optional[float]:
        br = self.first_failure()
        return None if br is None else secant_zero(*br)

    def next_value(self) -> Optional[float]:
        """Where the sign is least certain before the first failure; when nowhere is, inside the
        bracket of the first failure; None at the end."""
        br = self.first_failure()
        if self.done or br is None or len(self.points) >= self.budget:
            self.uncertain = br is not None and self._straddle()[1] > 0
            self.done = True
            return None
        t, score = self._straddle()
        if score > 0 and not self.search.seen(self.search.snap(t)):
            return self.search.snap(t)
        t = self.search.narrow(br)
        if t is None or self.search.seen(self.search.snap(t)):
            self.done = True
            return None
        return self.search.snap(t)

    def _straddle(self) -> tuple[float, float]:
        """The candidate before the first failing point whose sign is least certain, and how
        uncertain (1.96 σ − |μ|; above zero, the sign is not known), away from the points."""
        br = self.first_failure()
        if br is None:
            return 0.0, -math.inf
        t = np.array([p[0] for p in self.points])
        y = np.array([finite(p[1]) for p in self.points])
        cand = np.linspace(0.0, br[1][0], _CANDIDATES)
        near = np.min(np.abs(cand[:, None] - t[None, :]), axis=1) <= 0.5 * self.search.tolerance
        cand = cand[~near]
        if not len(cand):
            return 0.0, -math.inf
        mean, sd = posterior(t, y, cand)
        score = _Z * sd - np.abs(mean)
        k = int(np.argmax(score))
        return float(cand[k]), float(score[k])
