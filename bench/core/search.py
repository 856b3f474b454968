"""The one fitting loop: CMA-ES on independent problems, every problem's population costed in one
batch. The rig's identification (a problem per joint) and the test stand's (one servo) both search
with it; what differs between them is the cost, the search's coordinates and its settings.

A simulation's error is a staircase in the parameters (the firmware reads an integer encoder) with
long curved valleys (a motor constant against friction, Coulomb against the Stribeck peak), where a
gradient method stalls; an evolution strategy reads the landscape at the population's scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

__all__ = ["Search", "evolve"]

#: ``cost(values, which)``: the cost of each row of ``values`` (parameters of problem ``which[i]``),
#: or (costs, details) with one row of details per candidate, kept for the best of each problem.
Cost = Callable[[np.ndarray, np.ndarray], "np.ndarray | tuple[np.ndarray, np.ndarray]"]


@dataclass(frozen=True)
class Search:
    """Per problem, the best parameters found, their cost and their details (None without), and the
    details of where it started."""

    values: np.ndarray
    cost: np.ndarray
    details: list[Optional[Any]]
    start_details: list[Optional[Any]]
    generations: int


def _costed(cost: Cost, values: np.ndarray, which: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
    out = cost(values, which)
    return (np.asarray(out[0]), out[1]) if isinstance(out, tuple) else (np.asarray(out), None)


def evolve(cost: Cost, start: np.ndarray, x0: np.ndarray, lower: np.ndarray | float,
           upper: np.ndarray | float,
           decode: Callable[[np.ndarray], np.ndarray], *, generations: int, population: int, sigma: float,
           seed: int = 0, tolfun: float = 1e-6, tolx: float = 1e-4,
           progress: Callable[[int, int], None] | None = None) -> Search:
    """CMA-ES for each problem (rows of ``start``), from ``start``'s own cost.

    The search runs in coordinates of the caller's choosing: ``x0`` (a row per problem) is where
    each strategy starts, ``lower``..``upper`` its bounds, and ``decode`` turns rows of coordinates
    into parameter values. Problem ``f``'s strategy is seeded ``seed + f + 1``."""
    import cma  # deferred: only fitting needs it

    F = start.shape[0]
    strategies = [cma.CMAEvolutionStrategy(
        np.asarray(x0[f]).tolist(), sigma,
        {"bounds": [np.asarray(lower).tolist(), np.asarray(upper).tolist()], "popsize": population,
         "seed": seed + f + 1, "verbose": -9, "tolfun": tolfun, "tolx": tolx}) for f in range(F)]
    best = np.array(start, dtype=float, copy=True)
    best_cost, detail = _costed(cost, start, np.arange(F))
    best_cost = np.array(best_cost, dtype=float)
    details: list[Optional[Any]] = [None if detail is None else detail[f] for f in range(F)]
    start_details = list(details)
    done = 0
    for g in range(generations):
        active = [f for f in range(F) if not strategies[f].stop()]
        if not active:
            break
        asked = {f: strategies[f].ask() for f in active}
        values = decode(np.concatenate([np.array(asked[f]) for f in active]))
        costs, detail = _costed(cost, values, np.repeat(active, population))
        for i, f in enumerate(active):
            rows = slice(i * population, (i + 1) * population)
            c = costs[rows]
            strategies[f].tell(asked[f], c.tolist())
            k = int(np.argmin(c))
            if c[k] < best_cost[f]:
                best_cost[f] = c[k]
                best[f] = values[rows][k]
                details[f] = None if detail is None else detail[rows][k]
        done = g + 1
        if progress:
            progress(done, generations)
    return Search(best, best_cost, details, start_details, done)
