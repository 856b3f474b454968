"""The global stage of the rig's fit: a CMA-ES strategy per joint (their problems are independent),
every joint's population simulated in one batch, through the bench's one fitting loop
(:func:`bench.core.search.evolve`), in units of each parameter's scale.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from bench.core.search import evolve

__all__ = ["cma_search"]

#: Candidates per joint and generation (CMA-ES's default for 6 parameters is 9).
POPULATION = 10


def cma_search(cost: Callable[[np.ndarray, np.ndarray], np.ndarray], start: np.ndarray, scale: np.ndarray,
               lower: np.ndarray, upper: np.ndarray, *, generations: int, sigma: float = 0.3, seed: int = 0,
               progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per joint (rows of ``start``), the best parameters found and their cost.

    ``cost(values, which)``: the costs of parameter rows ``values`` for joints ``which``. The
    search runs in units of ``scale`` within ``lower``..``upper``."""
    lo, hi = lower / scale, upper / scale
    found = evolve(cost, start, np.clip(start / scale, lo, hi), lo, hi,
                   lambda x: np.clip(x * scale, lower, upper), generations=generations,
                   population=POPULATION, sigma=sigma, seed=seed, tolfun=1e-6, tolx=1e-4, progress=progress)
    return found.values, found.cost
