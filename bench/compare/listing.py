"""A comparison's directory summarised for ``hilbench runs``, beside the trials.

``compare`` writes ``<out>/<stamp>-compare-<config name>/``: ``summary.json`` and
``report.html`` when it ends (a config's session also keeps its repeats under ``real/``,
``sim/``, ``model/`` and ``homing/``). ``summary.json`` is trusted for nothing: it is
checked against the fields read here, every number finite, before any is used; what
is wrong lists the directory ``broken`` in one line. A directory with repeats but no
``summary.json`` is a session that was stopped (or is still running): ``incomplete``.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from pathlib import Path
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field, StrictBool, ValidationError

from bench.config.base import describe_validation_error
from bench.core.rundir import JSON_MAX_BYTES, has_run_files
from bench.trial.runs import RunSummary, broken
from drivers.errors import RunDirError

__all__ = ["SUMMARY", "compare_summary", "is_compare_dir"]

SUMMARY = "summary.json"
#: The folders a config's session keeps its repeats in (bench.compare.session).
_REPEAT_DIRS = ("real", "sim", "model", "homing")
_NAME = re.compile(r"^(\d{8}-\d{6})-compare-(.+)$")


class _Outcome(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    tip_deviation_mm: list[float] = Field(min_length=3, max_length=3)
    angle_deviation_deg: float


class _Side(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    label: str
    backend: Optional[str] = None
    rig: Optional[str] = None
    outcomes: list[Optional[_Outcome]] = []


class _Verdict(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    passed: StrictBool
    repeats: int = Field(ge=0)
    completed: int = Field(ge=0)
    reason: str


class _SummaryFile(BaseModel):
    """``summary.json`` as ``runs`` reads it (the rest is kept, unread)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    reference: _Side
    subject: _Side
    summary: _Verdict


def is_compare_dir(directory: Path) -> bool:
    """Whether a directory is a comparison's: its summary, or its repeats' folders, and no
    file of a trial's own."""
    d = Path(directory)
    if has_run_files(d):
        return False
    return ((d / SUMMARY).exists() or (d / SUMMARY).is_symlink()
            or any((d / sub).is_dir() for sub in _REPEAT_DIRS))


def compare_summary(directory: Path) -> RunSummary:
    """The comparison's verdict and its worst repeat (tip deviation length, largest angle);
    ``broken`` naming the fault when its summary fails a check."""
    d = Path(directory)
    stamp = _NAME.match(d.name)
    started = _started(stamp.group(1)) if stamp else None
    name = stamp.group(2) if stamp else None
    report = d / "report.html"
    report_path = str(report) if report.is_file() and not report.is_symlink() else None
    if not (d / SUMMARY).exists() and not (d / SUMMARY).is_symlink():
        return RunSummary(str(d), started, name, None, "incomplete",
                          f"no {SUMMARY}: the session was stopped before its report (or is still running)",
                          None, None, report_path, kind="compare")
    try:
        data = _read(d)
    except RunDirError as e:
        return RunSummary(**{**broken(d, e, "compare").as_dict(), "started": started, "config": name})
    verdict, sub, ref = data.summary, data.subject, data.reference
    placed = [o for o in sub.outcomes if o is not None]
    tip = max((math.hypot(*o.tip_deviation_mm) for o in placed), default=None)
    angle = max((o.angle_deviation_deg for o in placed), key=abs, default=None)
    if verdict.passed:
        status = "passed"
    elif verdict.completed < verdict.repeats or not verdict.repeats:
        status = "stopped"
    else:
        status = "failed"
    backend = f"{ref.backend or '?'} vs {sub.backend or '?'}"
    return RunSummary(str(d), started, name, backend, status, verdict.reason,
                      None if tip is None else round(tip, 3), None if angle is None else round(angle, 4),
                      report_path, sub.rig, kind="compare")


def _read(d: Path) -> _SummaryFile:
    path = d / SUMMARY
    if path.is_symlink():
        raise RunDirError(f"{d}: {SUMMARY} is a link (to {path.resolve()}), not the comparison's own file")
    if not path.is_file() or path.stat().st_size > JSON_MAX_BYTES:
        raise RunDirError(f"{d}: {SUMMARY} is not a file the bench writes")
    try:
        data = json.loads(path.read_bytes())
    except (ValueError, RecursionError) as e:
        raise RunDirError(f"{d}: {SUMMARY} is not JSON ({type(e).__name__}: {str(e)[:80]})") from None
    except OSError as e:
        raise RunDirError(f"{d}: cannot read {SUMMARY}: {e.strerror}") from None
    if not isinstance(data, dict):
        raise RunDirError(f"{d}: {SUMMARY} holds a {type(data).__name__}, not an object")
    try:
        return _SummaryFile.model_validate(data)
    except ValidationError as e:
        raise RunDirError(f"{d}: {describe_validation_error(e, _SummaryFile, SUMMARY)}") from None


def _started(stamp: str) -> Optional[str]:
    """The directory's stamp (the local time ``compare`` began) in ISO 8601 UTC, as trials give it."""
    try:
        local = dt.datetime.strptime(stamp, "%Y%m%d-%H%M%S")
    except ValueError:
        return None
    return local.astimezone(dt.timezone.utc).isoformat(timespec="seconds")
