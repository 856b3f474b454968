"""Past trials in an output directory: what ran, when, and how it ended.

One :class:`RunSummary` per run directory; a comparison and a campaign are summarised
in the same shape by their own packages (``bench.compare.listing``,
``bench.campaign.listing``), and ``hilbench runs`` lists the three kinds together.

Reads what each run directory already holds (``result.json``, the log's metadata,
or the journal of a run that was killed), each file checked as every reader checks it
(:mod:`bench.core.rundir`), and never rewrites anything, so it is safe beside a trial
that is still running. A run directory that fails a check is listed ``broken``, with
what is wrong, and the listing goes on.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

from bench.core.log import JOURNAL_META
from bench.core.rundir import RECORD, RunDirError, has_run_files, load_run, read_journal, read_result

__all__ = ["RunSummary", "broken", "camera_line", "list_runs", "lowest_margin", "trial_summary"]


@dataclass(frozen=True)
class RunSummary:
    """One trial's run directory, summarised (mm and degrees, like the result); a comparison's
    or a campaign's in the same shape, its deviations those of its worst repeat or trial."""

    run_dir: str
    started: Optional[str]  # ISO 8601, UTC
    config: Optional[str]  # the config's name
    backend: Optional[str]
    status: str  # passed | failed | stopped | incomplete (killed: journal only) | broken
    reason: str
    tip_deviation_mm: Optional[float]  # length of the tip deviation vector
    angle_deviation_deg: Optional[float]
    report: Optional[str]  # report.html when it was drawn
    rig: Optional[str] = None  # sim, emulated or real: what the record says ran it (None: older runs)
    kind: str = "trial"  # trial | compare | campaign
    #: The twin's alarms, "theta5 at 2.13 s, …" (a monitored trial), "" when it raised none; None unmonitored.
    alarms: Optional[str] = None
    #: The requirement with the lowest robustness, "tip +4.912" (mm or °; "tip none": no value);
    #: a campaign's: the lowest over its trials. None when the record holds no requirements.
    margin: Optional[str] = None
    #: What the cameras saw: "tip 0.95 mm from the encoders'" (", flagged" beyond the two's
    #: uncertainty), or why they measured nothing; None for a trial without cameras.
    cameras: Optional[str] = None

    def as_dict(self) -> dict:
        return asdict(self)


def list_runs(out: Path) -> list[RunSummary]:
    """Every trial run directory directly under ``out``, oldest first; a broken one listed as such."""
    out = Path(out)
    if not out.is_dir():
        return []
    runs = [trial_summary(d) for d in sorted(out.iterdir()) if d.is_dir() and has_run_files(d)]
    return sorted(runs, key=lambda r: (r.started or "", r.run_dir))


def broken(where: Path, why: Exception, kind: str = "trial") -> RunSummary:
    """A directory that failed a check, listed as such: what is wrong, in one line."""
    return RunSummary(str(where), None, None, None, "broken",
                      " ".join(str(why).removeprefix(f"{where}: ").split()), None, None, None, kind=kind)


def trial_summary(run_dir: Path) -> RunSummary:
    """One trial's run directory summarised; ``broken`` with the fault when a file fails its checks."""
    try:
        return _checked_summary(run_dir)
    except RunDirError as e:
        return broken(run_dir, e)


def _checked_summary(run_dir: Path) -> RunSummary:
    """The run's summary from its files, each checked as ``report`` checks it (config aside)."""
    if (run_dir / RECORD).exists() or (run_dir / RECORD).is_symlink() or not (run_dir / JOURNAL_META).is_file():
        meta = load_run(run_dir).log.metadata
    else:
        meta = read_journal(run_dir).metadata  # killed: read, never recovered here
    result = read_result(run_dir)
    config = meta.get("config") or {}
    name = config.get("name")
    margin = cameras = None
    if result is not None and result.camera is not None:
        cameras = camera_line(result.camera.encoder_gap_mm, result.camera.flag, result.camera.problem)
    if result is None:
        status, reason, tip, angle = "incomplete", "no result: the process was killed", None, None
    else:
        margin = lowest_margin([(r.name, r.robustness) for r in result.requirements])
        tip = math.hypot(*result.tip_deviation_mm) if result.tip_deviation_mm else None
        angle = result.angle_deviation_deg
        if result.passed:
            status = "passed"
        elif not result.completed:
            status = "stopped"
        else:
            status = "failed"
        reason = result.reason
    report = run_dir / "report.html"
    monitor = meta.get("monitor")  # checked with the log's metadata
    alarms = None if monitor is None else ", ".join(f"{a['joint']} at {a['t_s']:.2f} s" for a in monitor["alarms"])
    return RunSummary(str(run_dir), meta.get("start_time"), name if isinstance(name, str) else None,
                      meta.get("backend"), status, reason, None if tip is None else round(tip, 3),
                      None if angle is None else round(float(angle), 4),
                      str(report) if report.is_file() else None, meta.get("rig"), alarms=alarms,
                      margin=margin, cameras=cameras)


def camera_line(gap_mm: Optional[float], flag: Optional[bool], problem: str) -> str:
    """What the cameras saw, in a few words: the gap between their tip and the encoders', flagged
    or not, or why there is no measurement."""
    if problem:
        return f"no measurement: {problem}"
    if gap_mm is None:
        return "tip measured; the encoders placed none"
    return f"tip {gap_mm:.2f} mm from the encoders'" + (", flagged" if flag else "")


def lowest_margin(rows: list[tuple[str, Optional[float]]]) -> Optional[str]:
    """"name +r.rrr" of the lowest robustness among (name, robustness); no value counts lowest."""
    if not rows:
        return None
    name, value = min(rows, key=lambda r: -math.inf if r[1] is None else r[1])
    return f"{name} {'none' if value is None else format(value, '+.3f')}"
