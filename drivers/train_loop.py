"""The train's arc angle as the rig measures and steers it: the ultrasonic sensor's reading in whole
millimetres through a median filter, and the host loop that nudges the train servo's goal by the
integral of the sensor's error (the pinion slips on the arc's rack; the sensor does not).

:class:`TrainLoop` is the loop both the Dynamixel backend and the servo simulator run;
:class:`SensedDistance` is the reading the driver would hand over, modelled for the simulator
(no noise: that is the rig's, not the model's).
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["MAX_MM", "MIN_MM", "SensedDistance", "TrainLoop", "sensor_millimetres"]

#: The range an HRXL-MaxSonar reports (mm); no echo reads as the maximum.
MIN_MM = 300
MAX_MM = 5000


def sensor_millimetres(distance_m: float) -> int:
    """The whole millimetres the sensor reports for a true distance, clamped as it clamps."""
    if not np.isfinite(distance_m):
        return MAX_MM
    return max(MIN_MM, min(MAX_MM, int(round(distance_m * 1000.0))))


@dataclass
class TrainLoop:
    """Host loop on the train: goal += ∫ gain · (commanded − sensed) dt, clamped (joint units)."""

    joint: int
    loop_gain: float = 0.5  # 1/s: how fast the host loop removes train error
    max_correction: float = 0.05  # joint units
    correction: float = 0.0
    _last_time: float | None = None

    def reset(self) -> None:
        self.correction = 0.0
        self._last_time = None

    def goal(self, q: np.ndarray, sensed: float, now: float, valid: bool = True) -> np.ndarray:
        """The goals with the train's nudged by the loop; ``sensed`` is the train's reading at ``now``."""
        out = q.copy()
        out[self.joint] += self.correct(float(q[self.joint]), sensed, now, valid)
        return out

    def correct(self, commanded: float, sensed: float, now: float, valid: bool = True) -> float:
        """The loop's correction to the train's goal after one more reading (scalars, no arrays:
        the simulator's block path calls it every cycle)."""
        dt = min(max(now - (self._last_time if self._last_time is not None else now), 0.0), 0.1)
        self._last_time = now
        if valid:  # NaN stays NaN, as np.clip leaves it
            c = self.correction + self.loop_gain * (commanded - sensed) * dt
            self.correction = float(min(max(c, -self.max_correction), self.max_correction))
        return self.correction


@dataclass
class SensedDistance:
    """The driver's filtered reading of a distance sampled at ``rate_hz`` in whole millimetres
    (median of the last ``median_window``), for a simulator that knows the true distance."""

    distance: Callable[[], float]  # the true distance now (m)
    rate_hz: float
    median_window: int = 5
    #: Gaussian reading noise (m, 1σ) before the sensor rounds to whole millimetres: a still
    #: train's readings dither across the millimetre steps, and the host loop that steers by
    #: them averages them, as on the rig.
    noise_std_m: float = 0.0
    seed: int = 0
    _window: deque = field(default_factory=deque)
    _next_sample: float = 0.0
    _rng: np.random.Generator | None = None
    #: Readings taken so far: the median changes only when this does.
    samples: int = 0

    def update(self, now: float) -> None:
        """Take the readings due by ``now`` (s)."""
        period = 1.0 / self.rate_hz
        while self._next_sample <= now + 1e-12:
            d = self.distance()
            if self.noise_std_m > 0:
                if self._rng is None:
                    self._rng = np.random.default_rng(self.seed)
                d += float(self._rng.normal(0.0, self.noise_std_m))
            self._window.append(sensor_millimetres(d) * 1e-3)
            while len(self._window) > self.median_window:
                self._window.popleft()
            self._next_sample += period
            self.samples += 1

    @property
    def due(self) -> float:
        """A time (s) just before the next reading is due: :meth:`update` earlier takes none."""
        return self._next_sample - 2e-12

    def read(self) -> float:
        """The median distance (m); NaN before the first reading."""
        return statistics.median(self._window) if self._window else float("nan")
