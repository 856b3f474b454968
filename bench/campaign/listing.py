"""A campaign's directory summarised for ``hilbench runs``, beside the trials.

A campaign directory holds ``campaign.db`` (its plan and every trial's result), the
trials' run directories under ``trials/`` and, once reported, ``report.html``. It is
read as the campaign report reads it (:func:`bench.campaign.checked.read_campaign`,
every row checked) and never written: a damaged one is listed ``broken`` in one line.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

from bench.campaign.checked import DB_NAME, CampaignDirError, read_campaign
from bench.trial.runs import RunSummary, broken, lowest_margin

__all__ = ["CAMPAIGNS", "campaign_summary", "is_campaign_dir"]

#: Where ``hilbench campaign`` puts a campaign by default, under the runs folder.
CAMPAIGNS = "campaigns"


def is_campaign_dir(directory: Path) -> bool:
    """Whether a directory is a campaign's (it holds ``campaign.db``, whatever its state)."""
    db = Path(directory) / DB_NAME
    return db.exists() or db.is_symlink()


def campaign_summary(directory: Path) -> RunSummary:
    """The campaign's tally as a verdict (``passed``: every planned trial ran and passed;
    ``failed``: all ran, some did not pass or ended in error; ``incomplete``: some never ran)
    and its worst trial's deviations; ``broken`` naming the fault when a check fails."""
    d = Path(directory)
    try:
        meta, rows, counts = read_campaign(d)
    except CampaignDirError as e:
        return broken(d, e, "campaign")
    planned, passed, errors = counts["planned"], counts["passed"], counts["error"]
    not_run = counts["pending"] + counts["running"]
    tally = f"{passed} of {planned} trials passed, {errors} in error"
    if not_run:
        status, reason = "incomplete", f"{tally}, {not_run} not run (hilbench campaign resume {d})"
    elif passed == planned:
        status, reason = "passed", ""
    else:
        status, reason = "failed", tally
    done = [r for r in rows if r["status"] == "done"]
    tips = [math.hypot(*(r[c] for c in ("tip_dx_mm", "tip_dy_mm", "tip_dz_mm")))
            for r in done if all(r[c] is not None for c in ("tip_dx_mm", "tip_dy_mm", "tip_dz_mm"))]
    angles = [r["angle_dev_deg"] for r in done if r["angle_dev_deg"] is not None]
    tip = round(max(tips), 3) if tips else None
    angle = round(float(max(angles, key=abs)), 4) if angles else None
    name, backend, created = meta.get("name"), meta.get("backend"), meta.get("created")
    report = d / "report.html"
    return RunSummary(str(d), _text(created), _text(name), _text(backend), status, reason, tip, angle,
                      str(report) if report.is_file() and not report.is_symlink() else None,
                      _rig(done), kind="campaign",
                      margin=lowest_margin([(r["worst"], r["robustness"]) for r in done
                                            if isinstance(r.get("worst"), str)]))


def _text(v: object) -> Optional[str]:
    return v if isinstance(v, str) else None


def _rig(done: list[dict]) -> Optional[str]:
    """Which rig ran the trials, as their stored metrics say (None when they do not)."""
    for r in done:
        metrics = r.get("metrics")
        if isinstance(metrics, dict) and metrics.get("rig") in ("sim", "emulated", "real"):
            return metrics["rig"]
    return None
