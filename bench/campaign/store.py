"""One SQLite database per campaign: the plan, and every trial's status and result.

Only the campaign's parent process writes (WAL mode, so readers — a report,
an export, a second terminal — never block it). A trial moves
``pending → running → done | error``; its result lands in one transaction,
so a row is either whole or untouched. A process killed mid-campaign leaves
``running`` rows behind, and those count as missing on resume, like
``pending`` rows and ``error`` rows that have not used up their attempts.
"""

from __future__ import annotations

import csv
import datetime as dt
import json
import sqlite3
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

from drivers.errors import CampaignStoreError

__all__ = ["CampaignStore", "CampaignStoreError", "METRIC_COLUMNS", "STATUSES", "TrialRow"]

STATUSES = ("pending", "running", "done", "error")
METRIC_COLUMNS = ("tip_dx_mm", "tip_dy_mm", "tip_dz_mm", "entry_dx_mm", "entry_dy_mm", "entry_dz_mm",
                  "depth_dev_mm", "angle_dev_deg")
SCHEMA_VERSION = 1

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS campaign (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS trials (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    grid_index INTEGER NOT NULL,
    sample_index INTEGER NOT NULL,
    repeat_index INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    params TEXT NOT NULL,          -- JSON: the varying parameters, by axis label
    faults TEXT NOT NULL,          -- JSON: the trial's fault list as in YAML
    config TEXT NOT NULL,          -- JSON: the full trial config
    status TEXT NOT NULL DEFAULT 'pending' CHECK (status IN {STATUSES!r}),
    attempts INTEGER NOT NULL DEFAULT 0,
    completed INTEGER,
    passed INTEGER,
    reason TEXT,
    {", ".join(f"{c} REAL" for c in METRIC_COLUMNS)},
    truth TEXT,                    -- 'sim' (backend truth) or 'measured'
    robustness REAL,               -- the lowest requirement's robustness (its units: mm or deg)
    worst TEXT,                    -- that requirement's name (robustness/scale lowest)
    metrics TEXT,                  -- JSON: true and measured outcomes in full
    log_path TEXT,                 -- relative to the campaign directory
    worker TEXT,
    started_at REAL,
    finished_at REAL,
    duration_s REAL,               -- wall time of the trial in its worker
    cpu_s REAL,                    -- CPU time of the trial in its worker
    error TEXT
);
CREATE INDEX IF NOT EXISTS trials_status ON trials (status);
"""

TrialRow = dict[str, Any]


class CampaignStore:
    """The campaign's database; a context manager that closes the connection."""

    def __init__(self, path: Path | str, create: bool = False) -> None:
        self.path = Path(path)
        if not create and not self.path.is_file():
            raise FileNotFoundError(f"campaign database not found: {self.path}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        try:
            self._db.row_factory = sqlite3.Row
            if not create:  # an existing campaign's: its tables are there, never made up here
                tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
                if not {"campaign", "trials"} <= tables:
                    raise sqlite3.DatabaseError(f"no {' or '.join(sorted({'campaign', 'trials'} - tables))} "
                                                f"table")
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            columns = {r[1] for r in self._db.execute("PRAGMA table_info(trials)")}
            for name, kind in (("robustness", "REAL"), ("worst", "TEXT")):  # a campaign from before them
                if name not in columns:
                    self._db.execute(f"ALTER TABLE trials ADD COLUMN {name} {kind}")
        except sqlite3.DatabaseError as e:  # not SQLite, truncated, or another program's tables
            self._db.close()
            raise CampaignStoreError(f"{self.path} is not a campaign database ({e})") from None

    # -- plumbing -------------------------------------------------------------
    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "CampaignStore":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _tx(self) -> "_Transaction":
        return _Transaction(self._db)

    # -- the plan -------------------------------------------------------------
    def set_meta(self, **values: Any) -> None:
        with self._tx():
            self._db.executemany("INSERT OR REPLACE INTO campaign (key, value) VALUES (?, ?)",
                                 [(k, json.dumps(v)) for k, v in values.items()])

    def meta(self) -> dict[str, Any]:
        return {r["key"]: json.loads(r["value"]) for r in self._db.execute("SELECT * FROM campaign")}

    def add_trials(self, trials: Iterable[Any], meta: dict[str, Any]) -> int:
        """Write the plan (every trial pending) and the campaign's metadata in one transaction."""
        rows = [(t.id, t.name, t.grid_index, t.sample_index, t.repeat_index, t.seed,
                 json.dumps(t.params), json.dumps(t.faults), json.dumps(t.config)) for t in trials]
        with self._tx():
            self._db.executemany(
                "INSERT INTO trials (id, name, grid_index, sample_index, repeat_index, seed, params, "
                "faults, config) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
            self._db.executemany("INSERT OR REPLACE INTO campaign (key, value) VALUES (?, ?)",
                                 [(k, json.dumps(v)) for k, v in
                                  {**meta, "schema": SCHEMA_VERSION}.items()])
        return len(rows)

    # -- the life of a trial ---------------------------------------------------
    def missing(self, max_attempts: int) -> list[int]:
        """Trials still to run: pending, running (left by a killed process), errors with attempts left."""
        cur = self._db.execute(
            "SELECT id FROM trials WHERE status IN ('pending', 'running') "
            "OR (status = 'error' AND attempts < ?) ORDER BY id", (max_attempts,))
        return [r[0] for r in cur]

    def mark_running(self, trial_id: int) -> None:
        with self._tx():
            self._db.execute("UPDATE trials SET status = 'running', attempts = attempts + 1, "
                             "started_at = ? WHERE id = ?", (time.time(), trial_id))

    def release(self, trial_ids: Sequence[int]) -> None:
        """Running trials that will not finish (Ctrl-C) go back to pending, attempt uncounted."""
        if not trial_ids:
            return
        with self._tx():
            self._db.executemany("UPDATE trials SET status = 'pending', attempts = MAX(attempts - 1, 0), "
                                 "started_at = NULL WHERE id = ? AND status = 'running'",
                                 [(i,) for i in trial_ids])

    def finish(self, trial_id: int, result: dict[str, Any]) -> None:
        """Record a trial's result (status done or error) in one transaction."""
        m = result.get("columns") or {}
        values = {
            "status": result["status"], "completed": _int(result.get("completed")),
            "passed": _int(result.get("passed")), "reason": result.get("reason"),
            **{c: m.get(c) for c in METRIC_COLUMNS},
            "truth": result.get("truth"), "robustness": result.get("robustness"), "worst": result.get("worst"),
            "metrics": json.dumps(result["metrics"]) if result.get("metrics") is not None else None,
            "log_path": result.get("log_path"), "worker": result.get("worker"),
            "finished_at": time.time(), "duration_s": result.get("duration_s"),
            "cpu_s": result.get("cpu_s"),
            "error": result.get("error"),
        }
        sets = ", ".join(f"{k} = ?" for k in values)
        with self._tx():
            self._db.execute(f"UPDATE trials SET {sets} WHERE id = ?", (*values.values(), trial_id))

    # -- reading ---------------------------------------------------------------
    def trial(self, trial_id: int) -> TrialRow:
        row = self._db.execute("SELECT * FROM trials WHERE id = ?", (trial_id,)).fetchone()
        if row is None:
            n = self._db.execute("SELECT COUNT(*) FROM trials").fetchone()[0]
            raise KeyError(f"no trial {trial_id} in {self.path}; trial ids are 0..{n - 1}")
        return _decode(row)

    def trials(self, status: str | None = None) -> list[TrialRow]:
        if status is None:
            cur = self._db.execute("SELECT * FROM trials ORDER BY id")
        else:
            cur = self._db.execute("SELECT * FROM trials WHERE status = ? ORDER BY id", (status,))
        return [_decode(r) for r in cur]

    def counts(self) -> dict[str, int]:
        out = {s: 0 for s in STATUSES}
        for status, n in self._db.execute("SELECT status, COUNT(*) FROM trials GROUP BY status"):
            out[status] = n
        out["planned"] = sum(out[s] for s in STATUSES)
        out["passed"] = self._db.execute(
            "SELECT COUNT(*) FROM trials WHERE status = 'done' AND passed = 1").fetchone()[0]
        return out

    def export_csv(self, path: Path | str) -> Path:
        """The trials table as CSV: one row per trial, axis values as their own columns."""
        rows = self.trials()
        labels: list[str] = []
        for r in rows:
            labels += [k for k in r["params"] if k not in labels]
        skip = {"params", "faults", "config", "metrics"}
        cols = [c for c in (rows[0].keys() if rows else ["id"]) if c not in skip]
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(cols + labels + ["faults"])
            for r in rows:
                w.writerow([_iso(r[c]) if c in _TIME_COLUMNS else r[c] for c in cols]
                           + [r["params"].get(k) for k in labels] + [json.dumps(r["faults"])])
        return path


#: Columns holding wall-clock instants (epoch seconds in the database, ISO 8601 in a CSV).
_TIME_COLUMNS = frozenset({"started_at", "finished_at"})


def _iso(epoch: float | None) -> str | None:
    """Epoch seconds as ISO 8601 UTC to the millisecond (what a spreadsheet parses)."""
    if epoch is None:
        return None
    return dt.datetime.fromtimestamp(epoch, dt.timezone.utc).isoformat(timespec="milliseconds")


def _int(v: Any) -> int | None:
    return None if v is None else int(bool(v))


def _decode(row: sqlite3.Row) -> TrialRow:
    out = dict(row)
    for k in ("params", "faults", "config", "metrics"):
        if out.get(k) is not None:
            out[k] = json.loads(out[k])
    return out


class _Transaction:
    """BEGIN IMMEDIATE ... COMMIT, rolled back on any exception (Ctrl-C included)."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self._db = db

    def __enter__(self) -> None:
        self._db.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self._db.execute("COMMIT")
        else:
            self._db.execute("ROLLBACK")

