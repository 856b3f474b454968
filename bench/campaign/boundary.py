"""Tolerance boundaries: along each fault axis, the magnitude where a requirement starts failing.

Each numeric axis of a spec (uniform, loguniform, integers, or a grid of numbers) is searched on its
own, the other axes held at their first value (a grid's first, a range's low end: for a fault
magnitude, the least fault). The trial's score is falsification's (the lowest robustness over its
requirement's scale, :func:`bench.campaign.falsify.score_of`), a continuous margin, so the search
brackets its zero:

- both ends of the axis first; when they have the same sign there is no boundary in the range;
- then, in turn: a trial where the straight line through the bracket's scores crosses zero
  (regula falsi), a trial 0.9 × the tolerance past it toward the bracket's other end (a close
  estimate closes the bracket at once), and a bisection (the bracket halves whatever the margin's
  shape); until the bracket is narrower than ``tolerance`` of the axis's range;
- every score seen is checked to fall monotonically along the axis; where it does not, the
  boundary is the first crossing found by a scan of the trials so far and the method says so.

The interval is the final bracket. Trials of all axes run together, one batch per step, as a
campaign's: planned by the spec's planner, stored in the same ``campaign.db``, run on its pools.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from bench.campaign.checked import DB_NAME
from bench.campaign.falsify import open_search, row_score
from bench.campaign.run import CampaignError, default_out, open_store, run_campaign
from bench.campaign.spec import Axis, Planner, load_campaign_spec
from bench.campaign.store import CampaignStore

__all__ = ["AxisSearch", "find_boundaries"]

NUMERIC = ("uniform", "loguniform", "integers", "grid")


def _span(a: Axis) -> tuple[float, float]:
    vals = [float(v) for v in a.args]
    return (vals[0], vals[1]) if a.kind != "grid" else (min(vals), max(vals))


def _start(a: Axis) -> Any:
    return a.args[0]


@dataclass
class AxisSearch:
    """One axis's bracket of the score's zero, in the axis's units."""

    axis: Axis
    tolerance: float
    points: list[tuple[float, float, Optional[str]]] = field(default_factory=list)  # (value, score, worst)
    lo: Optional[tuple[float, float]] = None
    hi: Optional[tuple[float, float]] = None
    done: bool = False
    _step: int = 0  # secant, a step just past it, bisection, in turn

    @property
    def span(self) -> tuple[float, float]:
        return _span(self.axis)

    def next_value(self) -> Optional[float]:
        a, b = self.span
        seen = {v for v, _, _ in self.points}
        if a not in seen:
            return a
        if b not in seen:
            return b
        if self.done or self.lo is None or self.hi is None:
            return None
        (x0, f0), (x1, f1) = self.lo, self.hi
        width = self.tolerance * (b - a)
        if abs(x1 - x0) <= width:
            self.done = True
            return None
        last = self.points[-1][0]
        step = self._step % 3
        self._step += 1
        if step == 1 and last in (x0, x1):
            # just past the last estimate, toward the bracket's other end: when the estimate was
            # close, the bracket closes to within the tolerance at once
            other = x1 if last == x0 else x0
            x = last + (0.9 * width if other > last else -0.9 * width)
        elif step == 2:
            x = 0.5 * (x0 + x1)  # a bisection: the bracket halves whatever the margin's shape
        else:
            x = x0 - f0 * (x1 - x0) / (f1 - f0) if f1 != f0 else 0.5 * (x0 + x1)
            edge = 0.05 * abs(x1 - x0)
            if not (min(x0, x1) + edge <= x <= max(x0, x1) - edge):
                x = 0.5 * (x0 + x1)
        if self.axis.kind == "integers":
            x = float(round(x))
            if x in seen:
                self.done = True
                return None
        return x

    def tell(self, x: float, score: float, worst: Optional[str]) -> None:
        self.points.append((x, score, worst))
        a, b = self.span
        seen = {v: s for v, s, _ in self.points}
        if a in seen and b in seen and self.lo is None:
            fa, fb = _finite(seen[a]), _finite(seen[b])
            if (fa >= 0) == (fb >= 0):
                self.done = True  # no crossing within the range
                return
            self.lo, self.hi = (a, fa), (b, fb)
            return
        if self.lo is None or x in (a, b):
            return
        f = _finite(score)
        if (f >= 0) == (self.lo[1] >= 0):
            self.lo = (x, f)
        else:
            self.hi = (x, f)

    def monotone(self) -> bool:
        pts = sorted((v, _finite(s)) for v, s, _ in self.points)
        diffs = [b[1] - a[1] for a, b in zip(pts, pts[1:])]
        return all(d <= 1e-9 for d in diffs) or all(d >= -1e-9 for d in diffs)

    def result(self, requirement_of: Callable[[float], Optional[str]]) -> dict:
        label = self.axis.label
        if self.lo is None:
            return {"axis": label, "requirement": None, "value": None, "interval": None,
                    "trials": len(self.points), "method": "no crossing in the range"}
        method = "regula falsi, guarded by bisection"
        x0, x1 = self.lo[0], self.hi[0]
        if not self.monotone():  # the first sign change along the axis among the trials run
            pts = sorted((v, _finite(s)) for v, s, _ in self.points)
            start = pts[0][1] >= 0
            for (va, sa), (vb, sb) in zip(pts, pts[1:]):
                if (sb >= 0) != start:
                    x0, x1 = va, vb
                    break
            method = "first crossing of a scan (the margin is not monotone)"
        lo, hi = sorted((x0, x1))
        value = hi if self.axis.kind == "integers" else _crossing(self.lo, self.hi, lo, hi)
        return {"axis": label, "requirement": requirement_of(x1 if (self.hi[1] < 0) else x0),
                "value": value, "interval": [lo, hi], "trials": len(self.points), "method": method}


def _crossing(p0: tuple[float, float], p1: tuple[float, float], lo: float, hi: float) -> float:
    (x0, f0), (x1, f1) = p0, p1
    x = x0 - f0 * (x1 - x0) / (f1 - f0) if f1 != f0 else 0.5 * (x0 + x1)
    return min(hi, max(lo, x))


def _finite(s: float) -> float:
    return s if math.isfinite(s) else -1e6


def find_boundaries(spec_path: Path | str, out: Path | str | None = None, tolerance: float = 0.01,
                    max_trials: int = 12, workers: Optional[int] = None, scheduler: Optional[str] = None,
                    notify: Optional[Callable[[str], None]] = None,
                    grid: int = 0) -> tuple[Path, list[dict], list[dict]]:
    """Each numeric axis's boundary; the search directory, ``[{axis, requirement, value, interval,
    trials, method}]`` (values in the axis's units) and, with ``grid`` > 1, each axis's pass rate on
    ``grid`` evenly spaced values (``spec.repeats`` trials each) beside it: ``[{axis, values, passed,
    n}]``."""
    if not 0 < tolerance < 1:
        raise CampaignError(f"--tolerance must be between 0 and 1 (a share of the range), got {tolerance}")
    if max_trials < 2:
        raise CampaignError(f"--max-trials must be >= 2 (the two ends), got {max_trials}")
    spec = load_campaign_spec(spec_path)
    planner = Planner(spec)
    axes = [a for a in planner.axes if a.kind in NUMERIC and all(isinstance(v, (int, float)) for v in a.args)]
    if not axes:
        raise CampaignError(f"{spec_path}: the spec has no numeric axis to search (uniform, loguniform, "
                            "integers or a grid of numbers)")
    out = Path(out) if out is not None else default_out(f"{spec.name}-boundary")
    open_search(spec, spec_path, planner, out, {"mode": "boundary", "tolerance": tolerance,
                                                    "max_trials": max_trials})
    searches = [AxisSearch(a, tolerance) for a in axes]
    say = notify or (lambda msg: None)
    k = 0
    run = lambda planned: _run(out, planned, workers, scheduler)  # noqa: E731
    worst_at: dict[tuple[str, float], Optional[str]] = {}
    while True:
        asks = []
        for s in searches:
            x = s.next_value() if len(s.points) < max_trials else None
            if x is not None:
                asks.append((s, x))
        if not asks:
            break
        planned = []
        for s, x in asks:
            values = {a.label: _start(a) for a in planner.axes}
            values[s.axis.label] = int(x) if s.axis.kind == "integers" else float(x)
            planned.append(planner.trial(k, 0, k, 0, values))
            k += 1
        rows = run(planned)
        for (s, x), row in zip(asks, rows):
            s.tell(x, row_score(row), row.get("worst"))
            worst_at[(s.axis.label, x)] = row.get("worst")
        say(f"{k} trial(s): " + ", ".join(f"{s.axis.label} [{s.lo[0]:.4g}, {s.hi[0]:.4g}]"
                                          for s in searches if s.lo is not None))
    results = [s.result(lambda x, s=s: worst_at.get((s.axis.label, x))) for s in searches]
    grids = []
    if grid > 1:
        planned, where = [], []
        for s in searches:
            a, b = s.span
            for i in range(grid):
                x = a + (b - a) * i / (grid - 1)
                values = {ax.label: _start(ax) for ax in planner.axes}
                values[s.axis.label] = int(round(x)) if s.axis.kind == "integers" else float(x)
                for _ in range(spec.repeats):
                    planned.append(planner.trial(k, 0, k, 0, values))
                    where.append((s.axis.label, values[s.axis.label]))
                    k += 1
        rows = run(planned)
        for s in searches:
            xs = sorted({x for label, x in where if label == s.axis.label})
            sel = [[r for (label, x2), r in zip(where, rows) if label == s.axis.label and x2 == x] for x in xs]
            grids.append({"axis": s.axis.label, "values": xs,
                          "passed": [sum(row_score(r) >= 0 for r in g) for g in sel], "n": [len(g) for g in sel]})
    with open_store(out) as store:
        store.set_meta(boundaries=results, grids=grids,
                       ended=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"))
    return out, results, grids


def _run(out: Path, planned: list, workers: Optional[int], scheduler: Optional[str]) -> list[dict]:
    """Add the planned trials not yet in the store, run what is missing, return their rows."""
    with CampaignStore(out / DB_NAME) as store:
        have = {r["id"]: r for r in store.trials()}
        for t in planned:
            if t.id in have and have[t.id]["params"] != json.loads(json.dumps(t.params)):
                raise CampaignError(f"{out}: trial {t.id} was planned at {have[t.id]['params']}, not "
                                    f"{t.params}: the spec changed; start another --out")
        new = [t for t in planned if t.id not in have]
        if new:
            store.add_trials(new, {})
    summary = run_campaign(out, workers=workers, scheduler=scheduler, report=False)
    if summary.interrupted:
        raise KeyboardInterrupt
    with open_store(out) as store:
        return [store.trial(t.id) for t in planned]
