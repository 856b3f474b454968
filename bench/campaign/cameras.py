"""What a campaign's cameras measured: the basis each trial's placement was judged on, and the gap
between the encoders' tip and the cameras' over the trials, by fault magnitude.

A trial on a rig (no simulator truth) with cameras is judged on the cameras' tip; a simulator's
trial on its truth, the cameras' figures beside (:mod:`bench.campaign.execute`). The gap measures
what the encoders cannot see (an encoder bias, play in a slide's rack): its rise with a fault's
magnitude is the fault measured, not only flagged. A trial's camera figures come from
``campaign.db`` and are checked before use (it may have been edited): what is not of the shape the
bench writes counts as no measurement.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Optional, Sequence

import numpy as np

__all__ = ["basis_line", "cameras_markdown", "seen"]

#: How each basis a campaign judged placement on is said in its report.
BASES = {"sim": "the simulator's true joint positions (as an external camera would; a biased or noisy "
                "sensor does not hide the error)",
         "camera": "the cameras' tip (two calibrated cameras, as seed 000 measured its Table 3; the trials "
                   "ran on a rig, with no simulator truth)",
         "measured": "the readings (the encoders' tip)"}


def basis_line(truths: Sequence[str]) -> str:
    """The report's line saying what placement was judged on ("" when no trial says)."""
    if not truths:
        return ""
    return "- placement measured on " + "; ".join(BASES.get(t, t) for t in truths)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def seen(row: dict) -> Optional[dict]:
    """A trial's camera figures, checked; None when it had no cameras (or they are not the bench's)."""
    metrics = row.get("metrics")
    c = metrics.get("camera") if isinstance(metrics, dict) else None
    if not isinstance(c, dict) or not isinstance(c.get("problem"), str):
        return None
    tip, gap, flag = c.get("tip_deviation_mm"), c.get("encoder_gap_mm"), c.get("flag")
    measured = (isinstance(tip, list) and len(tip) == 3 and all(_finite(v) for v in tip)
                and (gap is None or _finite(gap)) and (flag is None or isinstance(flag, bool)))
    if c["problem"] == "" and not measured:
        return None
    return {"problem": c["problem"], "tip": tip if measured else None, "gap": gap if measured else None,
            "flag": flag if measured else None,
            "uncertainty": c.get("uncertainty_mm") if _finite(c.get("uncertainty_mm")) else None}


def _fmt(v: Optional[float], nd: int = 2) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.{nd}f}"


def _gap_row(label: str, rows: Sequence[dict]) -> str:
    """One row of the gap table: trials, measured, the gap's mean and max, flagged."""
    figures = [s for s in map(seen, rows) if s is not None]
    gaps = np.array([s["gap"] for s in figures if s["gap"] is not None], dtype=float)
    flagged = sum(1 for s in figures if s["flag"])
    mean = float(gaps.mean()) if gaps.size else None
    top = float(gaps.max()) if gaps.size else None
    return (f"| {label} | {len(rows)} | {sum(1 for s in figures if s['tip'] is not None)} | {_fmt(mean)} | "
            f"{_fmt(top)} | {flagged} |")


def cameras_markdown(done: Sequence[dict], axes: Sequence[dict],
                     groups: Callable[[Sequence[dict], dict], list]) -> list[str]:
    """The report's section on the cameras ([] when no trial had them): what judged placement, the
    encoders-to-cameras gap overall and along each fault axis (``groups``: the report's grouping of
    trials by an axis's values), the cameras' tip deviation, and the trials they could not measure."""
    with_cameras = [r for r in done if seen(r) is not None]
    if not with_cameras:
        return []
    by_truth = {t: sum(1 for r in with_cameras if r.get("truth") == t) for t in ("camera", "sim", "measured")}
    lines = ["## The cameras", "",
             f"{len(with_cameras)} of {len(done)} finished trials had the two cameras: placement judged on "
             f"the cameras' tip in {by_truth['camera']} (on a rig), on the simulator's truth in "
             f"{by_truth['sim']} (the cameras' figures beside). The gap is the distance between the "
             "encoders' tip and the cameras' at the end of the insertion: what the encoders cannot see "
             "(an encoder bias, play in a slide's rack) is in it. Flagged: beyond the two tips' "
             "uncertainties together (three standard deviations).", "",
             "| trials | n | measured | gap mean (mm) | gap max (mm) | flagged |",
             "|---|---:|---:|---:|---:|---:|", _gap_row("all", with_cameras)]
    for axis in axes:
        for label, _, sel in groups(with_cameras, axis):
            lines.append(_gap_row(f"{axis['label']} = {label}", sel))
    tips = np.array([s["tip"] for s in map(seen, with_cameras) if s["tip"] is not None], dtype=float)
    if tips.size:
        mean, std = tips.mean(axis=0), tips.std(axis=0, ddof=1) if len(tips) > 1 else np.zeros(3)
        lines += ["", "The cameras' tip deviation from the target (mm, mean ± standard deviation): "
                  + ", ".join(f"{a} {m:+.2f} ± {s:.2f}" for a, m, s in zip("XYZ", mean, std)) + "."]
    unmeasured = [(r, seen(r)["problem"]) for r in with_cameras if seen(r)["tip"] is None]
    if unmeasured:
        more = " …" if len(unmeasured) > 10 else ""
        lines += ["", f"Not measured ({len(unmeasured)}): "
                  + "; ".join(f"trial {r['id']}: {why}" for r, why in unmeasured[:10]) + more]
    return lines + [""]
