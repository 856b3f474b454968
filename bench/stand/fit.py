"""The fit of one servo's physics to test-stand logs: every log rolled out open loop (as BAM
scores a model) under each candidate, all candidates and logs stepped in one batch, CMA-ES on
the mean MAE.

Fitted: the motor constant (Kt = Ke in SI, as BAM fits it: Ke fitted apart let the fit trade it
against the friction and predicted unseen trajectory kinds worse, 0.059 rad against 0.049 in the
cross-validation), the winding resistance, the armature, Coulomb and
viscous friction, the load-dependent friction (BAM's m3 law: friction per N·m the gearbox
carries) and the stand's gravity offset. The firmware (P gain of each log, the XL330's P/256),
the current limit and the PWM limit stay the datasheet's; the measured supply drives the motor.
The error of an open-loop rollout is a staircase with long valleys (Kt against R, the friction
terms against each other), where a gradient method stalls: an evolution strategy reads it at
the population's scale: the bench's one fitting loop (:func:`bench.core.search.evolve`), in
coordinates running 0..1 across each value's range.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from bench.core.search import evolve
from bench.stand.logs import StandLog
from bench.stand.simulate import Slots, rollout
from drivers.servo import ServoParams

__all__ = ["PARAMS", "StandFit", "batch_cost", "batch_maes", "fit_stand", "init_worker", "stand_maes",
           "stand_params"]

#: The fitted values, in this order, with their search ranges.
PARAMS = ("kt_nma", "resistance_ohm", "armature_kgm2", "coulomb_nm", "viscous_nms", "load_friction",
          "gravity_offset_rad")
LOWER = np.array([0.1, 1.0, 1e-4, 0.0, 0.0, 0.0, -0.1])
UPPER = np.array([1.0, 10.0, 0.01, 0.1, 0.05, 0.5, 0.1])
#: Candidates per generation.
POPULATION = 16


def start_values(datasheet: ServoParams) -> np.ndarray:
    """Where the search starts: the datasheet's motor, a light armature and light friction."""
    return np.array([float(datasheet.kt[0]), float(datasheet.resistance[0]), 0.002, 0.01, 0.005, 0.1, 0.0])


def stand_params(datasheet: ServoParams, values: np.ndarray,
                 repeat: int = 1) -> tuple[ServoParams, np.ndarray]:
    """The servo parameters of each candidate (rows of ``values``), each repeated ``repeat`` times,
    and the gravity offset of each."""
    values = np.atleast_2d(values)
    col = lambda i: np.repeat(values[:, i], repeat)  # noqa: E731
    n = len(values) * repeat
    base = ServoParams(**{f: np.repeat(getattr(datasheet, f), n) for f in ServoParams.__dataclass_fields__})
    p = base.with_(kt=col(0), ke=col(0), resistance=col(1), armature=col(2), coulomb=col(3), viscous=col(4),
                   load_motor=col(5), load_external=col(5))
    return p, col(6)


def stand_maes(logs: Sequence[StandLog], datasheet: ServoParams, values: np.ndarray) -> np.ndarray:
    """(candidates, logs) MAE (rad) of each candidate's open-loop rollout of each log."""
    values = np.atleast_2d(values)
    L = len(logs)
    params, offset = stand_params(datasheet, values, L)
    slots = Slots(log=np.tile(np.arange(L), len(values)), params=params, gravity_offset=offset,
                  measured_supply=np.ones(len(values) * L, dtype=bool))
    q = rollout(logs, slots)
    out = np.empty((len(values), L))
    for i, g in enumerate(logs):
        out[:, i] = np.abs(q[: len(g), i::L] - g.position[:, None]).mean(axis=0)
    return out


_WORKER: dict = {}


def init_worker(logs: Sequence[StandLog], datasheet: ServoParams) -> None:
    _WORKER["logs"], _WORKER["datasheet"] = logs, datasheet


def _worker_maes(values: np.ndarray) -> np.ndarray:
    return stand_maes(_WORKER["logs"], _WORKER["datasheet"], values)


def batch_maes(logs: Sequence[StandLog], datasheet: ServoParams, values: np.ndarray,
               pool: Optional[Executor] = None, workers: int = 1) -> np.ndarray:
    """:func:`stand_maes`, the candidates shared among the pool's ``workers`` processes (set up with
    :func:`init_worker` on the same logs)."""
    if pool is None or workers < 2 or len(values) < 2:
        return stand_maes(logs, datasheet, values)
    parts = np.array_split(values, min(workers, len(values)))
    return np.concatenate(list(pool.map(_worker_maes, parts)))


def batch_cost(logs: Sequence[StandLog], datasheet: ServoParams, values: np.ndarray,
               pool: Optional[Executor] = None, workers: int = 1) -> np.ndarray:
    """The fit's cost of each candidate: its mean MAE over the logs."""
    return batch_maes(logs, datasheet, values, pool, workers).mean(axis=1)


@dataclass(frozen=True)
class StandFit:
    """The fitted values (in :data:`PARAMS`), each log's MAE under them and under the start."""

    values: np.ndarray
    mae_after: np.ndarray
    mae_before: np.ndarray
    generations: int

    def as_values(self) -> dict[str, float]:
        return dict(zip(PARAMS, map(float, self.values)))


def fit_stand(logs: Sequence[StandLog], datasheet: ServoParams, *, generations: int = 40, seed: int = 0,
              pool: Optional[Executor] = None, workers: int = 1,
              progress: Callable[[int, int], None] | None = None) -> StandFit:
    """CMA-ES on the mean MAE over ``logs`` from :func:`start_values`; ``pool`` (set up with
    :func:`init_worker`) shares each generation's candidates among ``workers`` processes."""
    def cost(values: np.ndarray, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # noqa: ARG001
        """Each candidate's mean MAE over the logs, and its MAE of each (one servo: ``which`` is all 0)."""
        maes = batch_maes(logs, datasheet, values, pool, workers)
        return maes.mean(axis=1), maes

    scale = UPPER - LOWER
    x0 = start_values(datasheet)
    found = evolve(cost, x0[None, :], ((x0 - LOWER) / scale)[None, :], 0.0, 1.0,
                   lambda x: LOWER + np.clip(x, 0.0, 1.0) * scale, generations=generations,
                   population=POPULATION, sigma=0.2, seed=seed, tolfun=1e-7, tolx=1e-5, progress=progress)
    return StandFit(values=found.values[0], mae_after=found.details[0], mae_before=found.start_details[0],
                    generations=found.generations)
