"""Rates over a campaign's trials: the Wilson interval every rate is shown with, and, for campaigns
with the twin beside their trials (``monitor:`` in the base config or the overrides):
how often, how soon and on which joint it flagged each fault magnitude, beside the pass rate.

A trial's record of the monitor (its first alarm, the joints named) and the time its fault began
(:func:`fault_onset`) come from its result in ``campaign.db``; an alarm before the fault began
counts as a false alarm, not a detection. At a
magnitude that injects nothing (a contact of 0 N·m, a friction factor of 1) every alarm is false:
that row of the table is the campaign's false-alarm rate.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from typing import Any, Optional, Sequence

__all__ = ["detection_rates", "detection_table", "fault_onset", "monitored", "wilson"]


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a rate of k in n (95 % by default): sound at 0 and n, where the
    normal approximation is not."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def fault_onset(faults: Sequence[dict]) -> float:
    """When a trial's fault began (s on its clock): the latest ``from_s`` of its faults that have one
    (a contact, a drift, a stuck joint: the fault under study), 0 when none has (a deadband, noise,
    a weak joint: there from the start, as background or as the fault itself)."""
    starts = [float(f["from_s"]) for f in faults if isinstance(f, dict) and f.get("from_s") is not None]
    return max(starts) if starts else 0.0


def _watch(row: dict) -> Optional[dict]:
    """The monitor's record of a trial, checked (a campaign.db may have been edited); None if absent."""
    m = (row.get("metrics") or {}).get("monitor") if isinstance(row.get("metrics"), dict) else None
    if not isinstance(m, dict):
        return None
    first, onset = m.get("first_alarm_s"), m.get("onset_s", 0.0)
    joints, end = m.get("joints_named", []), m.get("insertion_end_s")
    finite = lambda v: isinstance(v, (int, float)) and math.isfinite(v)  # noqa: E731
    ok = (first is None or finite(first)) and finite(onset) and (end is None or finite(end)) and \
        isinstance(joints, list) and all(isinstance(j, str) for j in joints)
    return {"first": first, "onset": float(onset), "joints": joints, "end": end} if ok else None


def monitored(rows: Sequence[dict]) -> bool:
    return any(_watch(r) is not None for r in rows)


def detection_rates(sel: Sequence[dict]) -> dict[str, Any]:
    watched = [(r, _watch(r)) for r in sel]
    watched = [(r, w) for r, w in watched if w is not None]
    n = len(watched)
    hits = [w for _, w in watched if w["first"] is not None and w["first"] >= w["onset"] - 1e-9]
    false = sum(1 for _, w in watched if w["first"] is not None and w["first"] < w["onset"] - 1e-9)
    delays = [w["first"] - w["onset"] for w in hits]
    named = Counter(j for w in hits for j in w["joints"][:1])
    # in time: before the insertion ended (the placement is measured then); unknown in older records
    in_time = sum(1 for w in hits if w["end"] is not None and w["first"] <= w["end"])
    timed = sum(1 for _, w in watched if w["end"] is not None)
    return {"n": n, "detected": len(hits), "interval": wilson(len(hits), n), "false": false,
            "in_time": in_time, "timed": timed,
            "delay": statistics.median(delays) if delays else math.nan,
            "named": ", ".join(f"{j} ({k})" for j, k in named.most_common(3)) or "—",
            "passed": sum(bool(r["passed"]) for r, _ in watched)}


def detection_table(groups: Sequence[tuple[str, float, list[dict]]], label: str) -> list[str]:
    """One markdown row per magnitude: pass rate, detection rate with its 95 % interval, the
    median time from the fault's start to the alarm, the joints named first, the alarms before the
    fault, and the trials flagged before their insertion ended (when the placement is measured)."""
    lines = [f"| {label} | trials | pass rate | detected | detection rate (95 % interval) | "
             f"median time to alarm (s) | joint named first | alarms before the fault | "
             f"flagged before the insertion ended |",
             "|---|---:|---:|---:|---:|---:|---|---:|---:|"]
    for text, _, sel in groups:
        d = detection_rates(sel)
        if not d["n"]:
            continue
        lo, hi = d["interval"]
        delay = "—" if math.isnan(d["delay"]) else f"{d['delay']:.3f}"
        lines.append(f"| {text} | {d['n']} | {100 * d['passed'] / d['n']:.0f} % | {d['detected']} | "
                     f"{100 * d['detected'] / d['n']:.0f} % ({100 * lo:.0f}–{100 * hi:.0f} %) | "
                     f"{delay} | {d['named']} | {d['false']} | "
                     f"{d['in_time'] if d['timed'] else '—'} |")
    return lines
