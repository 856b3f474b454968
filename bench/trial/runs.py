"""Past trials in an output directory: what ran, when, and how it ended.

Reads what each run directory already holds (``result.json``, the log's metadata,
or the journal of a run that was killed) and never rewrites anything, so it is
safe beside a trial that is still running.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from bench.core.log import JOURNAL_META

__all__ = ["RunSummary", "list_runs"]


@dataclass(frozen=True)
class RunSummary:
    """One trial's run directory, summarised (mm and degrees, like the result)."""

    run_dir: str
    started: Optional[str]  # ISO 8601, UTC
    config: Optional[str]  # the config's name
    backend: Optional[str]
    status: str  # passed | failed | stopped | incomplete (killed: journal only)
    reason: str
    tip_deviation_mm: Optional[float]  # length of the tip deviation vector
    angle_deviation_deg: Optional[float]
    report: Optional[str]  # report.html when it was drawn
    rig: Optional[str] = None  # sim, emulated or real: what the record says ran it (None: older runs)

    def as_dict(self) -> dict:
        return asdict(self)


def list_runs(out: Path) -> list[RunSummary]:
    """Every trial run directory directly under ``out``, oldest first."""
    out = Path(out)
    if not out.is_dir():
        return []
    runs = [_summary(d) for d in sorted(out.iterdir()) if d.is_dir()]
    runs = [r for r in runs if r is not None]
    return sorted(runs, key=lambda r: (r.started or "", r.run_dir))


def _summary(run_dir: Path) -> Optional[RunSummary]:
    meta = _metadata(run_dir)
    result = _read_json(run_dir / "result.json")
    if meta is None and result is None:
        return None  # not a trial's run directory (a compare or a campaign, say)
    meta = meta or {}
    config = (meta.get("config") or {}).get("name")
    if result is None:
        status, reason, tip, angle = "incomplete", "no result: the process was killed", None, None
    else:
        tip_vec = result.get("tip_deviation_mm")
        tip = math.hypot(*tip_vec) if tip_vec else None
        angle = result.get("angle_deviation_deg")
        if result.get("passed"):
            status = "passed"
        elif result.get("completed") is False:
            status = "stopped"
        else:
            status = "failed"
        reason = result.get("reason") or ""
    report = run_dir / "report.html"
    return RunSummary(str(run_dir), meta.get("start_time"), config, meta.get("backend"), status,
                      reason, None if tip is None else round(tip, 3),
                      None if angle is None else round(float(angle), 4),
                      str(report) if report.is_file() else None, meta.get("rig"))


def _metadata(run_dir: Path) -> Optional[dict]:
    log = run_dir / "trial.npz"
    if log.is_file():
        try:
            with np.load(log, allow_pickle=False) as z:
                return json.loads(str(z["meta"])).get("metadata", {})
        except (OSError, ValueError, KeyError):
            return None
    journal = _read_json(run_dir / JOURNAL_META)
    return None if journal is None else journal.get("metadata", {})


def _read_json(path: Path) -> Optional[dict]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
