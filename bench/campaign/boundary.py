"""Tolerance boundaries: along each axis, and in the plane of a pair of axes, the value where a
requirement starts failing, with its interval under the trial's own randomness.

Each numeric axis of a spec (uniform, loguniform, integers, or a grid of numbers; a fault's
parameter or an override's value) is a line from its start (a range's low end, a grid's first
value: for a fault magnitude, the least fault; for a target, the range's low end) to the other end
of its range, the other axes at their start; ``pair`` adds the rays of two axes' plane
(:mod:`bench.campaign.pair`). Each line's margin is falsification's score (the lowest robustness
over its requirement's scale, :func:`bench.campaign.falsify.score_of`), and its boundary is found
by :class:`bench.campaign.line.LineBoundary`: a bracket (active level-set sampling where the margin
is not monotone), then, for a random trial, each seed's own crossing.

The trials are a campaign's: planned by the spec's planner (a seed's trials all have the seed of
its repeat index), stored in the same ``campaign.db``, run on its pools, every distinct trial once,
every line's next trials in one batch. The search is deterministic, so it resumes by replaying
itself against the trials already stored. ``grid`` runs the dense grid beside it, for the report.
"""

from __future__ import annotations

import datetime as dt
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from bench.campaign.checked import DB_NAME
from bench.campaign.falsify import open_search, row_score
from bench.campaign.line import RANDOM_SEEDS, Line, LineBoundary, LineResult, search_lines
from bench.campaign.pair import pair_result, ray_lines, resolve_pair
from bench.campaign.run import CampaignError, default_out, open_store, run_campaign
from bench.campaign.spec import Axis, Planner, load_campaign_spec
from bench.campaign.store import CampaignStore

__all__ = ["Boundaries", "axis_line", "find_boundaries", "numeric_axes"]

NUMERIC = ("uniform", "loguniform", "integers", "grid")


@dataclass
class Boundaries:
    """What a boundary search found: per axis, per pair, and the grids run beside them."""

    campaign_dir: Path
    boundaries: list[dict]  # {axis, requirement, value, interval, interval_kind, crossings, trials, method}
    pairs: list[dict] = field(default_factory=list)  # {axes, points, trials, rays}
    grids: list[dict] = field(default_factory=list)  # {axis, values, passed, n}
    pair_grids: list[dict] = field(default_factory=list)  # {axes, values, passed, n}: [i][j] at a_i, b_j


def numeric_axes(planner: Planner) -> list[Axis]:
    return [a for a in planner.axes if a.kind in NUMERIC
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in a.args)]


def axis_line(axis: Axis, start: dict[str, Any]) -> Line:
    """The axis from the end of its range at its start to the other end, the others at ``start``."""
    vals = [float(v) for v in axis.args]
    lo, hi = (vals[0], vals[1]) if axis.kind != "grid" else (min(vals), max(vals))
    if axis.kind == "grid" and vals[0] == hi:
        lo, hi = hi, lo  # a grid that starts at its largest value runs down
    whole = axis.kind == "integers" or (axis.kind == "grid" and all(isinstance(v, int) for v in axis.args))
    origin = int(lo) if whole else lo
    return Line(axis.label, {**start, axis.label: origin}, {axis.label: hi - lo},
                frozenset({axis.label}) if whole else frozenset())


def find_boundaries(spec_path: Path | str, out: Path | str | None = None, tolerance: float = 0.01,
                    max_trials: int = 12, workers: Optional[int] = None, scheduler: Optional[str] = None,
                    notify: Optional[Callable[[str], None]] = None, grid: int = 0,
                    pair: Optional[Sequence[str]] = None, rays: int = 7,
                    repeats: Optional[int] = None) -> Boundaries:
    """Each numeric axis's boundary (values in the axis's units) and, with ``pair``, the boundary
    curve in the plane of those two axes; ``repeats``: the seeds a random trial is bracketed with
    (default: the spec's, or :data:`bench.campaign.line.RANDOM_SEEDS` when it runs each draw once).
    With ``grid`` > 1, each axis's pass rate on ``grid`` evenly spaced values, and a pair's on a
    ``grid`` × ``grid`` grid, each value run by as many seeds."""
    if not 0 < tolerance < 1:
        raise CampaignError(f"--tolerance must be between 0 and 1 (a share of the range), got {tolerance}")
    if max_trials < 2:
        raise CampaignError(f"--max-trials must be >= 2 (the two ends), got {max_trials}")
    if repeats is not None and repeats < 1:
        raise CampaignError(f"--repeats must be >= 1, got {repeats}")
    spec = load_campaign_spec(spec_path)
    planner = Planner(spec)
    axes = numeric_axes(planner)
    if not axes:
        raise CampaignError(f"{spec_path}: the spec has no numeric axis to search (uniform, loguniform, "
                            "integers or a grid of numbers)")
    start = {a.label: a.args[0] for a in planner.axes}
    lines = [axis_line(a, start) for a in axes]
    plane: list[Line] = []
    if pair:
        a, b = resolve_pair(pair, axes)
        plane = ray_lines(lines[axes.index(a)], lines[axes.index(b)], rays)
        pair = [a.label, b.label]
    seeds = repeats or (spec.repeats if spec.repeats > 1 else None)
    out = Path(out) if out is not None else default_out(f"{spec.name}-boundary")
    open_search(spec, spec_path, planner, out, {"mode": "boundary", "tolerance": tolerance,
                                                    "max_trials": max_trials, "seeding": "common",
                                                    "repeats": repeats, "pair": list(pair) if pair else None,
                                                    "rays": rays if pair else None})
    say = notify or (lambda msg: None)
    ids = itertools.count()

    def evaluate(batch: list[tuple[dict, int]]) -> list[tuple[float, Optional[str]]]:
        planned = [planner.trial(next(ids), 0, 0, r, values) for values, r in batch]
        return [(row_score(row), row.get("worst") or ("error" if row.get("status") == "error" else None))
                for row in _run(out, planned, workers, scheduler)]

    searches = [LineBoundary(line, tolerance, max_trials, seeds) for line in lines + plane]
    search_lines(searches, evaluate, lambda ran: say(f"{ran} trial(s): " + _brackets(lines, searches)))
    results = [s.result() for s in searches]
    found = Boundaries(out, [_axis_entry(line, r) for line, r in zip(lines, results)])
    if plane:
        found.pairs.append(pair_result(plane, searches[len(lines):], results[len(lines):]))
    if grid > 1:  # as many runs of each value as a line's seeds
        runs = seeds or (RANDOM_SEEDS if any(s.random for s in searches) else 1)
        found.grids = _axis_grids(lines, grid, runs, lambda batch: _grid_rows(out, planner, ids, batch,
                                                                               workers, scheduler))
        if plane:
            found.pair_grids = [_pair_grid(plane, grid, runs, lambda batch: _grid_rows(
                out, planner, ids, batch, workers, scheduler))]
    with open_store(out) as store:
        store.set_meta(boundaries=found.boundaries, pairs=found.pairs, grids=found.grids,
                       pair_grids=found.pair_grids,
                       ended=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"))
    return found


def _axis_entry(line: Line, res: LineResult) -> dict[str, Any]:
    """A line's boundary in its axis's units."""
    ((label, _),) = line.step.items()

    def x(t: Optional[float]) -> Optional[float]:
        return None if t is None else line.values(t)[label] if label in line.integer else float(
            line.start[label] + t * line.step[label])

    interval = None if res.interval is None else sorted(x(t) for t in res.interval)
    return {"axis": label, "requirement": res.requirement, "value": x(res.crossing), "interval": interval,
            "interval_kind": res.kind, "crossings": [x(t) for t in res.crossings], "trials": res.trials,
            "method": res.method}


def _brackets(lines: Sequence[Line], searches: Sequence[LineBoundary]) -> str:
    parts = []
    for line, s in zip(lines, searches):
        br = s.first.bracket()
        if br is not None:
            ((label, d),) = line.step.items()
            lo, hi = sorted(line.start[label] + t * d for t in (br[0][0], br[1][0]))
            parts.append(f"{label} [{lo:.4g}, {hi:.4g}]")
    return ", ".join(parts)


def _grid_rows(out: Path, planner: Planner, ids, batch: list[dict], workers, scheduler) -> list[dict]:
    """A grid's trials, each with a seed of its own (the pass rate is over independent trials)."""
    planned = []
    for values in batch:
        k = next(ids)
        planned.append(planner.trial(k, 0, k, 0, values))
    return _run(out, planned, workers, scheduler)


def _axis_grids(lines: Sequence[Line], n: int, runs: int,
                run: Callable[[list[dict]], list[dict]]) -> list[dict]:
    batch = [line.values(i / (n - 1)) for line in lines for i in range(n) for _ in range(runs)]
    rows = iter(run(batch))
    grids = []
    for line in lines:
        ((label, _),) = line.step.items()
        values = sorted({line.values(i / (n - 1))[label] for i in range(n)})
        passed = dict.fromkeys(values, 0)
        count = dict.fromkeys(values, 0)
        for i in range(n):
            x = line.values(i / (n - 1))[label]
            for _ in range(runs):
                passed[x] += row_score(next(rows)) >= 0
                count[x] += 1
        grids.append({"axis": label, "values": values, "passed": [passed[x] for x in values],
                      "n": [count[x] for x in values]})
    return grids


def _pair_grid(rays: Sequence[Line], n: int, runs: int, run: Callable[[list[dict]], list[dict]]) -> dict:
    """The pass rate on an n × n grid of the pair's plane, ``[i][j]`` at (a_i, b_j)."""
    ((ka, da),), ((kb, db),) = rays[0].step.items(), rays[-1].step.items()
    a = [rays[0].values(i / (n - 1))[ka] for i in range(n)]
    b = [rays[-1].values(j / (n - 1))[kb] for j in range(n)]
    batch = [{**rays[0].start, ka: x, kb: y} for x in a for y in b for _ in range(runs)]
    ok = [row_score(r) >= 0 for r in run(batch)]
    passed = [[sum(ok[(i * n + j) * runs:(i * n + j + 1) * runs]) for j in range(n)] for i in range(n)]
    return {"axes": [ka, kb], "values": [a, b], "passed": passed, "n": [[runs] * n for _ in range(n)]}


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
