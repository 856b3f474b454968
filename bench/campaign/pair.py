"""A boundary in the plane of two axes: rays from the least-fault corner, each a line's boundary.

The two axes are scaled to the unit square, the corner where both are at their start. Ray k of n
leaves the corner at 90° × k / (n − 1) and ends on the square's far side; its first and last rays
are the two axes' own lines (their trials are shared). Each ray's crossing is bracketed as an axis's
is (:class:`bench.campaign.line.LineBoundary`): the boundary curve is the list of those crossings,
each with its interval along its ray.
"""

from __future__ import annotations

import math
from typing import Any, Optional, Sequence

from bench.campaign.line import Line, LineBoundary, LineResult, trial_key
from bench.campaign.spec import Axis
from drivers.errors import CampaignError

__all__ = ["pair_result", "ray_lines", "resolve_pair"]


def resolve_pair(names: Sequence[str], axes: Sequence[Axis]) -> tuple[Axis, Axis]:
    """The two numeric axes ``--pair`` names, each by its label or a part of it found in one label."""
    found = []
    for name in names:
        exact = [a for a in axes if a.label == name]
        part = exact or [a for a in axes if name in a.label]
        labels = ", ".join(a.label for a in axes)
        if not part:
            raise CampaignError(f"--pair {name}: no numeric axis matches; the axes are {labels}")
        if len(part) > 1:
            matches = ", ".join(a.label for a in part)
            raise CampaignError(f"--pair {name}: matches {len(part)} axes ({matches}); write more of its label")
        found.append(part[0])
    if len(found) != 2 or found[0] == found[1]:
        raise CampaignError(f"--pair needs two different axes, got {' and '.join(a.label for a in found)}")
    return found[0], found[1]


def ray_lines(a: Line, b: Line, rays: int) -> list[Line]:
    """The rays of the plane of two axes' lines, from the corner where both are at t = 0."""
    if rays < 2:
        raise CampaignError(f"--rays must be >= 2 (the two axes), got {rays}")
    ((ka, da),), ((kb, db),) = a.step.items(), b.step.items()
    start = {**a.start, kb: b.start[kb]}
    out = []
    for k in range(rays):
        angle = 90.0 * k / (rays - 1)
        if k == 0:
            u = (1.0, 0.0)
        elif k == rays - 1:
            u = (0.0, 1.0)
        else:
            c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
            u = (c / max(c, s), s / max(c, s))
        step = {key: ui * d for key, ui, d in ((ka, u[0], da), (kb, u[1], db)) if ui}
        out.append(Line(f"{angle:g}°", start, step, a.integer | b.integer))
    return out


def pair_result(lines: Sequence[Line], searches: Sequence[LineBoundary],
                results: Sequence[LineResult]) -> dict[str, Any]:
    """``{"axes", "points", "trials", "rays"}``: the boundary curve in the axes' units, the
    distinct trials its rays took, and each ray's crossing with its interval along the ray."""
    ((ka, _),), ((kb, _),) = lines[0].step.items(), lines[-1].step.items()

    def at(line: Line, t: Optional[float]) -> Optional[list[float]]:
        if t is None:
            return None
        v = line.values(t)
        return [float(v[ka]), float(v[kb])]

    keys = {trial_key(line.values(t), r) for line, s in zip(lines, searches) for t, r in s.told}
    rays = []
    for line, res in zip(lines, results):
        rays.append({"angle_deg": float(line.label.rstrip("°")), "point": at(line, res.crossing),
                     "interval": None if res.interval is None else [at(line, t) for t in res.interval],
                     "interval_kind": res.kind, "requirement": res.requirement, "trials": res.trials,
                     "method": res.method, "crossings": [at(line, t) for t in res.crossings]})
    return {"axes": [ka, kb], "points": [r["point"] for r in rays if r["point"] is not None],
            "trials": len(keys), "rays": rays}
