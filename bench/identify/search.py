"""The global stage of the fit: CMA-ES per joint, every joint's population simulated in one batch.

The simulation error is a staircase in the parameters (the firmware reads an integer encoder)
with long curved valleys (motor constant against friction, Coulomb against the Stribeck peak),
where a gradient method stalls; an evolution strategy reads the landscape at the population's
scale instead. Each joint has its own strategy (their problems are independent); a generation
asks every strategy for its population and simulates all of them together.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["cma_search"]

#: Candidates per joint and generation (CMA-ES's default for 6 parameters is 9).
POPULATION = 10


def cma_search(cost: Callable[[np.ndarray, np.ndarray], np.ndarray], start: np.ndarray, scale: np.ndarray,
               lower: np.ndarray, upper: np.ndarray, *, generations: int, sigma: float = 0.3, seed: int = 0,
               progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per joint (rows of ``start``), the best parameters found and their cost.

    ``cost(values, which)``: the costs of parameter rows ``values`` for joints ``which``. The
    search runs in units of ``scale`` within ``lower``..``upper``."""
    import cma  # deferred: only fitting needs it

    F = start.shape[0]
    lo, hi = lower / scale, upper / scale
    strategies = [cma.CMAEvolutionStrategy(
        np.clip(start[f] / scale, lo, hi).tolist(), sigma,
        {"bounds": [lo.tolist(), hi.tolist()], "popsize": POPULATION, "seed": seed + f + 1,
         "verbose": -9, "tolfun": 1e-6, "tolx": 1e-4}) for f in range(F)]
    best = start.copy()
    best_cost = cost(start, np.arange(F))
    for g in range(generations):
        active = [f for f in range(F) if not strategies[f].stop()]
        if not active:
            break
        asked = {f: strategies[f].ask() for f in active}
        values = np.concatenate([np.array(asked[f]) * scale for f in active])
        which = np.repeat(active, POPULATION)
        costs = cost(np.clip(values, lower, upper), which)
        for i, f in enumerate(active):
            c = costs[i * POPULATION:(i + 1) * POPULATION]
            strategies[f].tell(asked[f], c.tolist())
            k = int(np.argmin(c))
            if c[k] < best_cost[f]:
                best_cost[f] = c[k]
                best[f] = np.clip(np.array(asked[f][k]) * scale, lower, upper)
        if progress:
            progress(g + 1, generations)
    return best, best_cost
