"""A campaign directory read back for its report, trusted for nothing.

``campaign.db`` may have been copied, truncated or edited: before a report uses it, the
database must open as SQLite and hold the campaign's tables and columns, its metadata the
fields the report reads (of their types), and every trial row a status the store knows,
finite deviations, and a log path inside the campaign's ``trials/``. The run directory
of a trial is checked as every run directory is (:mod:`bench.core.rundir`). What is wrong
raises :class:`CampaignDirError`, one line naming the campaign (and trial) and the fault.
"""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path, PurePosixPath
from typing import Any, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bench.campaign.store import METRIC_COLUMNS, STATUSES, CampaignStore, CampaignStoreError
from bench.config.base import describe_validation_error
from drivers.errors import CampaignDirError

__all__ = ["CampaignDirError", "read_campaign", "trial_run_dir"]

DB_NAME = "campaign.db"
TRIALS_DIR = "trials"
_COLUMNS = {"id", "name", "status", "params", "completed", "passed", "reason", *METRIC_COLUMNS,
            "truth", "log_path", "error", "attempts", "seed"}


class _Acceptance(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    position_mm: float = Field(5.0, gt=0)
    angle_deg: float = Field(1.0, gt=0)


class _Axis(BaseModel):
    model_config = ConfigDict(extra="allow")

    label: str
    kind: str


class _Meta(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    name: Optional[str] = None
    description: Optional[str] = None
    acceptance: _Acceptance = _Acceptance()
    axes: list[_Axis] = []
    sessions: list[dict[str, Any]] = []


def _where(campaign_dir: Path, what: str) -> CampaignDirError:
    return CampaignDirError(f"{campaign_dir}: {what}".replace("\n", " "))


def _check_row(campaign_dir: Path, r: dict) -> None:
    tid = f"trial {r.get('id')}"
    if r["status"] not in STATUSES:
        raise _where(campaign_dir, f"{tid} has status {r['status']!r}, not one of {', '.join(STATUSES)}")
    if not isinstance(r["name"], str) or not r["name"] or "/" in r["name"] or r["name"] in (".", ".."):
        raise _where(campaign_dir, f"{tid} has the name {r['name']!r}, not a plain name")
    if not isinstance(r["params"], dict):
        raise _where(campaign_dir, f"{tid}: params is not a mapping")
    for c in ("passed", "completed"):
        if r[c] not in (None, 0, 1):
            raise _where(campaign_dir, f"{tid}: {c} is {r[c]!r}, not 0, 1 or empty")
    for c in (*METRIC_COLUMNS, "robustness"):
        v = r.get(c)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise _where(campaign_dir, f"{tid}: {c} is {v!r}, not a finite number")
    for c in ("reason", "error", "truth", "worst"):
        if r.get(c) is not None and not isinstance(r[c], str):
            raise _where(campaign_dir, f"{tid}: {c} is {r[c]!r}, not text")
    if r["log_path"] is not None:
        trial_run_dir(campaign_dir, r)


def trial_run_dir(campaign_dir: Path, row: dict) -> Path:
    """The run directory a trial row names: ``trials/<its name>/``, refused if it points elsewhere."""
    p = row["log_path"]
    parts = PurePosixPath(p).parts if isinstance(p, str) else ()
    if (len(parts) != 3 or parts[0] != TRIALS_DIR or parts[1] != row["name"] or parts[2] in (".", "..")):
        raise _where(campaign_dir, f"trial {row.get('id')}: its log path {p!r} is not "
                                   f"{TRIALS_DIR}/{row['name']}/<log>: it would leave the campaign's trials")
    run_dir = Path(campaign_dir) / TRIALS_DIR / row["name"]
    if run_dir.is_symlink() or (run_dir.exists() and
                                run_dir.resolve().parent != (Path(campaign_dir) / TRIALS_DIR).resolve()):
        raise _where(campaign_dir, f"trial {row.get('id')}: {TRIALS_DIR}/{row['name']} is a link out of "
                                   f"the campaign")
    return run_dir


def read_campaign(campaign_dir: Path | str) -> tuple[dict, list[dict], dict]:
    """(metadata, trial rows, counts) of a campaign directory, every row checked."""
    campaign_dir = Path(campaign_dir)
    db = campaign_dir / DB_NAME
    if not db.is_file():
        raise _where(campaign_dir, f"no {DB_NAME}: not a campaign directory")
    try:
        with CampaignStore(db) as store:
            cols = {r[1] for r in store._db.execute("PRAGMA table_info(trials)")}
            missing = sorted(_COLUMNS - cols)
            if missing:
                raise _where(campaign_dir, f"{DB_NAME}: the trials table has no {', '.join(missing)}")
            meta, rows, counts = store.meta(), store.trials(), store.counts()
    except CampaignDirError:
        raise
    except CampaignStoreError as e:
        raise CampaignDirError(str(e)) from None
    except sqlite3.DatabaseError as e:
        raise _where(campaign_dir, f"{DB_NAME} is not a campaign database ({e})") from None
    except (ValueError, RecursionError) as e:  # a JSON column that is not JSON
        raise _where(campaign_dir, f"{DB_NAME} holds a value that is not JSON ({str(e)[:80]})") from None
    try:
        checked = _Meta.model_validate(meta)
    except ValidationError as e:
        raise _where(campaign_dir, describe_validation_error(e, _Meta, f"{DB_NAME} metadata")) from None
    meta = {**meta, "acceptance": {**(meta.get("acceptance") or {}), **checked.acceptance.model_dump()}}
    sampled = [a.label for a in checked.axes if a.kind not in ("grid", "choice")]
    for r in rows:
        _check_row(campaign_dir, r)
        for label in sampled:
            v = r["params"].get(label)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not math.isfinite(v)):
                raise _where(campaign_dir, f"trial {r['id']}: its {label} is {v!r}, not a finite number")
    return meta, rows, counts
