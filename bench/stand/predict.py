"""How well a servo model predicts test-stand logs, scored as BAM scores its models: each log
rolled out open loop over its whole length and the mean |q_sim − q_measured| over every 5 ms
sample (MAE, rad)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from bench.stand.logs import StandLog, read_stand_logs
from bench.stand.model import StandModel, load_stand_model, slots_for
from bench.stand.simulate import rollout
from drivers.servo import ServoParams

__all__ = ["LogScore", "Prediction", "predict", "predict_logs", "score"]


@dataclass(frozen=True)
class LogScore:
    """One log's rollout and its errors (rad)."""

    log: StandLog
    simulated: np.ndarray
    mae: float
    max_error: float

    def as_dict(self) -> dict:
        return {"log": str(self.log.path), "mae_rad": self.mae, "max_error_rad": self.max_error,
                "samples": len(self.log)}


@dataclass(frozen=True)
class Prediction:
    """A model's rollouts of several logs and their mean MAE."""

    model: StandModel
    spec: str
    scores: list[LogScore]

    @property
    def mean_mae(self) -> float:
        return float(np.mean([s.mae for s in self.scores]))

    def as_dict(self) -> dict:
        return {"model": self.spec, "logs": [s.as_dict() for s in self.scores], "mean_mae_rad": self.mean_mae}


def score(log: StandLog, simulated: np.ndarray) -> LogScore:
    """BAM's MAE of one rollout (its first ``len(log)`` samples) and the largest error."""
    err = np.abs(simulated[: len(log)] - log.position)
    return LogScore(log, simulated[: len(log)], float(err.mean()), float(err.max()))


def predict_logs(model: StandModel, logs: Sequence[StandLog], spec: str = "") -> Prediction:
    """Every log rolled out under ``model`` at once (one slot per log)."""
    q = rollout(logs, slots_for(model, len(logs)))
    return Prediction(model, spec or model.name, [score(g, q[:, i]) for i, g in enumerate(logs)])


def predict(spec: str | Path, paths: Sequence[str | Path]) -> Prediction:
    """Read every log (all checked before any is simulated) and the model, then roll them out
    (``ideal``: the goal itself, a servo that tracks perfectly)."""
    logs = read_stand_logs(paths)
    if str(spec) == "ideal":  # a servo that is always where it is told: the floor any model must beat
        ideal = StandModel("ideal servo (q = goal)", ServoParams.datasheet([logs[0].model_number]))
        return Prediction(ideal, "ideal", [score(g, g.goal) for g in logs])
    motors = {g.model_number for g in logs}
    model = load_stand_model(spec, next(iter(motors)) if len(motors) == 1 else logs[0].model_number)
    return predict_logs(model, logs, str(spec))
