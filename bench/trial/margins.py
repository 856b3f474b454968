"""How far a trial was from tripping each interlock, cycle by cycle, as configured (SI units).

The export and the live view show these beside the log: a margin that shrinks is
seen before its interlock trips. Negative means the interlock would trip. The
gantry margin is the clearance bound the interlock itself checks
(:class:`bench.scene.contact.GantryClearance`) less the configured margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.core.result import PreparedTrial
from bench.scene.contact import GantryClearance
from bench.trial.plan import planned_limits, tracking_bounds

__all__ = ["Margins", "MarginMeter", "margins_of"]


@dataclass(frozen=True)
class Margins:
    """Rows of cycles: how far each was from each interlock's trip (SI; negative trips)."""

    joint_limits: np.ndarray  # (n, joints): to the nearer limit, with the interlock's tolerance
    tracking: np.ndarray  # (n, joints): the tracking-error bound less |measured − commanded|
    gantry: np.ndarray | None  # (n,): gantry clearance less the margin; None when that interlock is off


class MarginMeter:
    """The interlocks' margins of a prepared trial, built once and applied to rows of a log."""

    def __init__(self, prep: PreparedTrial) -> None:
        s = prep.config.safety
        lim = planned_limits(prep)
        self.lower = lim.lower - s.joint_limit_tolerance
        self.upper = lim.upper + s.joint_limit_tolerance
        self.bound = tracking_bounds(prep)
        self.gantry_margin = s.gantry_margin_mm * 1e-3 if s.enabled and s.gantry_margin_mm > 0 else None
        self._clearance = (GantryClearance(prep.robot, self.gantry_margin)
                           if self.gantry_margin is not None else None)

    def __call__(self, q: np.ndarray, q_cmd: np.ndarray) -> Margins:
        q, q_cmd = np.atleast_2d(q), np.atleast_2d(q_cmd)
        to_limit = np.minimum(q - self.lower, self.upper - q)
        tracking = self.bound - np.abs(q - q_cmd)
        gantry = None
        if self._clearance is not None:
            gantry = np.array([self._clearance.check(row).distance for row in q]) - self.gantry_margin
        return Margins(to_limit, tracking, gantry)


def margins_of(log, prep: PreparedTrial) -> Margins:
    """The margins the trial's interlocks had at each cycle of ``log``."""
    return MarginMeter(prep)(log.q, log.q_cmd)
