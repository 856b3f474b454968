"""The detector: a two-sided CUSUM per joint on the twin's normalised residual.

Page's cumulative sum (Page 1954; Basseville and Nikiforov, *Detection of Abrupt Changes*, 1993,
§2.2) on z = residual / σ, per joint and per sign:

    g⁺ₖ = max(0, g⁺ₖ₋₁ + zₖ − κ),   g⁻ₖ = max(0, g⁻ₖ₋₁ − zₖ − κ),   alarm when g⁺ or g⁻ > h.

κ (the drift allowance, in σ) is what the residual may hold for ever without an alarm: the clean
residual of a model within its stated spread stays under it, a sag of a few σ climbs at z − κ a
cycle. h (the threshold) sets the false-alarm rate: the statistic of a clean run rises above zero
only in short excursions, and h is a multiple of the highest of them (the figures and how they
were chosen: the README's monitor section). A joint that has alarmed stays latched, silent, until
its sums are back to zero (the fault gone, or taken up by the servo): a persisting fault is one
alarm, not one every few cycles; one that comes back is a new one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Cusum", "CusumParams", "DEFAULT_CUSUM"]

_NONE = np.zeros(0, dtype=np.intp)


@dataclass(frozen=True)
class CusumParams:
    """κ, the drift allowance, and h, the alarm threshold, both in σ of the residual."""

    drift: float
    threshold: float


#: Chosen on clean trials (README, the monitor section): κ = 2 σ, h = 12 σ.
DEFAULT_CUSUM = CusumParams(drift=2.0, threshold=12.0)


class Cusum:
    """Two-sided CUSUM over ``n`` joints; :meth:`update` returns the joints that alarm."""

    def __init__(self, n: int, params: CusumParams = DEFAULT_CUSUM) -> None:
        self.params = params
        self._sums = np.zeros((2, n))  # g⁺ and g⁻, one array: a cycle is a handful of operations
        self.up, self.down = self._sums[0], self._sums[1]
        self.latched = np.zeros(n, dtype=bool)
        self._any_latched = False

    @property
    def score(self) -> np.ndarray:
        """Each joint's larger sum (σ): how far it has gone towards an alarm."""
        return self._sums.max(axis=0)

    def update(self, z: np.ndarray) -> np.ndarray:
        """One cycle's normalised residuals (finite: 0 for a joint not watched); the indices that
        alarm now. (Run every cycle beside the trial: a few array operations when nothing is near an
        alarm.)"""
        sums, h = self._sums, self.params.threshold
        self.up += z
        self.down -= z
        sums -= self.params.drift
        np.maximum(sums, 0.0, out=sums)
        if self._any_latched:  # a latch holds until the joint's sums are back to zero
            self.latched &= sums.max(axis=0) > 0.0
            self._any_latched = bool(self.latched.any())
        if sums.max() <= h:
            return _NONE
        over = sums.max(axis=0) > h
        hit = np.flatnonzero(over & ~self.latched)
        self.latched |= over
        self._any_latched = True
        return hit

    def sums(self, z: np.ndarray) -> np.ndarray:
        """:meth:`update` over rows of residuals (NaN, not watched, counts as zero; a row all NaN, a
        reading the twin did not predict, is no cycle of the detector): each joint's larger sum after
        each row, for the plots and pages that show the detector's course."""
        out = np.empty(z.shape)
        predicted = ~np.isnan(z).all(axis=1)
        for k, row in enumerate(np.nan_to_num(z, nan=0.0)):
            if predicted[k]:
                self.update(row)
            out[k] = self._sums.max(axis=0)
        return out
