"""What the live view shows, read from the trial's own journal: the control loop never waits.

A trial journals its rows and events to its run directory at least every
:data:`bench.core.log.FLUSH_EVERY_S` (for a ``kill -9``). The live view reads
that journal from another thread, so a slow or dead browser costs the loop
nothing: it only ever reads files the loop has already handed to the operating
system. A comparison writes several runs one after another under its output
directory; the follower always shows the newest.
"""

from __future__ import annotations

import base64
import json
import os
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from bench.core.log import JOURNAL_META, JOURNAL_ROWS, TIMING_SERIES, TrialLog, journal_row_width
from bench.core.looptiming import MISSED_SHARE_LIMIT, loop_timing
from bench.core.result import PreparedTrial
from bench.monitor.detector import Cusum, CusumParams
from bench.trial.margins import MarginMeter

__all__ = ["RunFollower", "Snapshot", "MAX_POINTS_HZ", "decimate"]

#: Rows sent to the page per second of trial (the log's own rate is decimated to this).
MAX_POINTS_HZ = 50.0
#: How deep under the output directory a run directory may be (a comparison's repeats are two down).
_DEPTH = 3
_SEGMENT = re.compile(r"start (\S+) \(([\d.]+) s \+ ([\d.]+) s settle")


@dataclass
class Snapshot:
    """One run as the page sees it; ``rows`` are decimated, times in s, joints in SI."""

    run: str = ""
    run_dir: str = ""
    joints: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    segments: list[str] = field(default_factory=list)
    time: list[float] = field(default_factory=list)
    q_cmd: list[list[float]] = field(default_factory=list)
    q: list[list[float]] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    phase: str = "starting"
    progress: float = 0.0
    margins: dict = field(default_factory=dict)
    #: The loop's timing so far (a paced trial's): cycles, missed deadlines, the latest period and
    #: bus time, in s; ``paced`` False for a simulator's (no deadline), None before the journal says.
    timing: dict = field(default_factory=dict)
    result: dict | None = None
    #: The twin's detector (a monitored trial's): the joint nearest its alarm threshold and how near
    #: (share), over every row so far; {} when the trial is not monitored.
    twin: dict = field(default_factory=dict)
    #: A monitored trial's residuals as its detector sums them: each joint's CUSUM (σ) at each row of
    #: ``time`` (NaN where a joint is not watched or the row came before the detector); [] otherwise.
    twin_sum: list[list[float]] = field(default_factory=list)
    #: Changes when the rows start again (a new run followed, or the final log read in whole).
    epoch: int = 0

    def since(self, n: int) -> dict:
        """The snapshot as JSON, with only the rows after the first ``n`` (a page's increment).

        The rows go as one base64 block of little-endian float64 (``count`` rows of time, the
        commanded positions, the measured ones, and a monitored trial's detector sums): a sim trial
        faster than real time adds about a thousand rows between two polls, and writing them as JSON
        numbers took the server's thread ~10 ms of the interpreter per poll, time the control loop
        waited for."""
        n = max(0, min(int(n), len(self.time)))
        count = len(self.time) - n
        width = len(self.joints)
        twin = bool(self.twin_sum) and len(self.twin_sum) == len(self.time)
        block = np.empty((count, 1 + (3 if twin else 2) * width), dtype="<f8")
        if count:
            block[:, 0] = self.time[n:]
            block[:, 1:1 + width] = self.q_cmd[n:]
            block[:, 1 + width:1 + 2 * width] = self.q[n:]
            if twin:
                block[:, 1 + 2 * width:] = self.twin_sum[n:]
        return {"run": self.run, "run_dir": self.run_dir, "joints": self.joints, "kinds": self.kinds,
                "segments": self.segments, "first": n, "count": count,
                "rows": base64.b64encode(block.tobytes()).decode("ascii"), "events": self.events, "phase": self.phase,
                "progress": self.progress, "margins": self.margins, "timing": self.timing,
                "result": self.result, "twin": self.twin, "twin_columns": twin,
                "epoch": self.epoch}


class RunFollower:
    """Follows the newest run directory under ``out`` created after it started."""

    def __init__(self, out: Path, prepared: Callable[[], PreparedTrial]) -> None:
        self.out = Path(out)
        prep = prepared()  # the margins' geometry is built here, before the loop starts: never beside it
        self.meter = MarginMeter(prep)
        self.kinds: list[str] = [r.kind for r in prep.robot.chain.rows]
        self._started = time.time() - 1.0
        self._lock = threading.Lock()
        self._dir: Path | None = None
        self._offset = 0  # bytes of the rows file read so far
        self._width = 0
        self._signals = 1  # the twin's signals in the journal: position, and current where watched
        self._meta_mtime = -1.0
        self._meta: dict = {}
        self._rows = np.empty((0, 0))
        self._timed = False
        self._next_t = -np.inf
        self._twin_at: int | None = None  # the journal row's first column of the twin's residuals
        self._cusum: Cusum | None = None
        self._watched: list[int] = []
        self.snapshot = Snapshot()

    def _newest(self) -> Path | None:
        """The run directory written to last, among those made since the follower started.

        Only directories changed since then are opened (a runs/ folder of a thousand past
        trials costs a scan of its top level), at most :data:`_DEPTH` down (a comparison's
        repeats), homing runs left out."""
        found = list(self._fresh(self.out, _DEPTH))
        return max(found)[2] if found else None

    def _fresh(self, root: Path, depth: int):
        try:
            entries = list(os.scandir(root))
        except OSError:
            return
        for entry in entries:
            try:
                if not entry.is_dir(follow_symlinks=False) or entry.name == "homing":
                    continue
                changed = entry.stat(follow_symlinks=False).st_mtime
            except OSError:
                continue
            if changed < self._started:
                continue
            path = Path(entry.path)
            if (path / JOURNAL_META).exists() or (path / "record.json").exists():
                yield changed, entry.path, path
            elif depth > 1:
                yield from self._fresh(path, depth - 1)

    def poll(self) -> Snapshot:
        """Read what the journal gained since the last poll (cheap when nothing did)."""
        with self._lock:
            newest = self._newest()
            if newest is not None and newest != self._dir:
                self._switch(newest)
            if self._dir is not None:
                self._read_meta()
                self._read_rows()
                self._read_result()
            return self.snapshot

    def _switch(self, run_dir: Path) -> None:
        self._dir, self._offset, self._meta_mtime, self._meta = run_dir, 0, -1.0, {}
        self._next_t = -np.inf
        self._cusum, self._twin_at = None, None  # a comparison's next run: its own detector, from zero
        self.snapshot = Snapshot(run=run_dir.name, run_dir=str(run_dir), kinds=self.kinds,
                                 epoch=self.snapshot.epoch + 1)

    def _read_meta(self) -> None:
        path = self._dir / JOURNAL_META
        try:
            mtime = path.stat().st_mtime
            if mtime == self._meta_mtime:
                return
            meta = json.loads(path.read_text())
        except (OSError, ValueError):
            return  # not there yet, or replaced under us: the next poll reads it
        self._meta_mtime, self._meta = mtime, meta
        s = self.snapshot
        s.joints = list(meta.get("joint_names", []))
        s.segments = list(meta.get("segment_names", []))
        s.events = [e for e in meta.get("events", []) if isinstance(e, dict)]
        self._timed = meta.get("timing") is True
        self._signals = 2 if meta.get("twin") and meta.get("twin_current") is True else 1
        self._width = journal_row_width(len(s.joints), self._timed, bool(meta.get("encoder_joint")),
                                        bool(meta.get("twin")), self._signals == 2)
        self._follow_twin(meta)
        if not s.timing:
            s.timing = {"cycles": 0, "missed": 0, "worst_late_s": None}
        s.timing["paced"] = self._timed
        self._phase()

    def _read_rows(self) -> None:
        if not self._width:
            return
        try:
            with open(self._dir / JOURNAL_ROWS, "rb") as f:
                f.seek(self._offset)
                raw = f.read()
        except OSError:
            return
        row_bytes = 8 * self._width
        whole = len(raw) // row_bytes * row_bytes  # a row still being written waits for the next poll
        if not whole:
            return
        self._offset += whole
        rows = np.frombuffer(raw[:whole], dtype=float).reshape(-1, self._width)
        n = len(self.snapshot.joints)
        if self._timed:
            self._count_deadlines(rows[:, 2 + 5 * n:2 + 5 * n + len(TIMING_SERIES)])
        sums = None
        if self._cusum is not None and self._twin_at is not None:
            sums = self._detect(rows[:, self._twin_at:self._twin_at + n * self._signals])
        keep, self._next_t = decimate(rows[:, 0], self._next_t)
        rows = rows[keep]
        q_cmd, q = rows[:, 2:2 + n], rows[:, 2 + 2 * n:2 + 3 * n]
        s = self.snapshot
        if sums is not None:  # rows the page got before the detector started have none
            s.twin_sum.extend([[np.nan] * n] * (len(s.time) - len(s.twin_sum)))
            s.twin_sum.extend(sums[keep].tolist())
        s.time.extend(rows[:, 0].tolist())
        s.q_cmd.extend(q_cmd.tolist())
        s.q.extend(q.tolist())
        self._margins(q[-1], q_cmd[-1], int(rows[-1, 1]))
        self._phase()

    def _count_deadlines(self, timing: np.ndarray) -> None:
        """Every row's timing counted (before the page's decimation): a miss is never skipped."""
        start, late, bus = timing.T
        timed = np.isfinite(late)
        tm = self.snapshot.timing
        tm["cycles"] += int(timed.sum())
        missed = timed & (late > 0)
        tm["missed"] += int(missed.sum())
        if missed.any():
            worst = float(late[missed].max())
            tm["worst_late_s"] = max(worst, tm["worst_late_s"] or 0.0)
        periods = np.diff(start[np.isfinite(start)])
        if periods.size:  # the latest half second's, as a meter shows it
            tm["period_s"] = float(np.median(periods))
        if np.isfinite(bus).any():
            tm["bus_s"] = float(np.nanmedian(bus))
        tm["late"] = tm["missed"] > MISSED_SHARE_LIMIT * tm["cycles"]

    def _follow_twin(self, meta: dict) -> None:
        """A monitored trial's journal: where its residuals are, and the detector as the trial runs it."""
        if self._cusum is not None or not meta.get("twin") or not self._start_detector(meta.get("metadata")):
            return
        n = len(self.snapshot.joints)
        self._twin_at = 2 + 5 * n + (len(TIMING_SERIES) if self._timed else 0) + (1 if meta.get("encoder_joint") else 0)

    def _start_detector(self, metadata: object) -> bool:
        """The detector as the monitor's summary in the log's metadata sets it; False if there is none."""
        monitor = metadata.get("monitor") if isinstance(metadata, dict) else None
        try:
            params = CusumParams(float(monitor["cusum"]["drift_sigma"]), float(monitor["cusum"]["threshold_sigma"]))
            names = self.snapshot.joints
            self._watched = [names.index(j) for j in monitor["joints"]]
        except (KeyError, TypeError, ValueError):
            return False
        self._cusum = Cusum(len(self.snapshot.joints) * self._signals, params)
        return True

    def _detect(self, z: np.ndarray) -> np.ndarray:
        """Every row's residual through the detector (before the page's decimation): the nearest a
        joint has come to its threshold is never skipped. Each row's sums (σ; NaN where a joint is
        not watched), for the page's residual panel."""
        c, n = self._cusum, len(self.snapshot.joints)
        sums = np.full((len(z), n), np.nan)
        # per joint the larger of its signals' sums (position, and current where it is watched)
        sums[:, self._watched] = c.sums(z).reshape(len(z), -1, n).max(axis=1)[:, self._watched]
        score = c.score.reshape(-1, n).max(axis=0)
        j = max(self._watched, key=lambda k: score[k]) if self._watched else 0
        names = self.snapshot.joints
        self.snapshot.twin = {"joint": names[j], "share": float(score[j] / c.params.threshold),
                              "alarms": sum(1 for e in self.snapshot.events if e.get("kind") == "monitor"),
                              "watched": len(self._watched), "joints": [names[k] for k in self._watched],
                              "threshold": c.params.threshold}
        return sums

    def _margins(self, q: np.ndarray, q_cmd: np.ndarray, segment: int) -> None:
        m = self.meter(q, q_cmd)
        self.snapshot.kinds = self.kinds
        names = self.snapshot.joints
        worst_limit = int(np.argmin(m.joint_limits[0]))
        ratio = 1.0 - m.tracking[0] / self.meter.bound  # tracking error as a share of its bound
        worst_track = int(np.argmax(ratio))
        self.snapshot.margins = {
            "gantry_mm": None if m.gantry is None else float(m.gantry[0]) * 1e3,
            "joint_limit": {"joint": names[worst_limit], "margin": float(m.joint_limits[0][worst_limit]),
                            "kind": self.kinds[worst_limit]},
            "tracking": {"joint": names[worst_track], "share_of_bound": float(ratio[worst_track])},
            "segment": segment,
        }

    def _phase(self) -> None:
        """The phase and a progress fraction from the segments' start events (planned durations)."""
        s = self.snapshot
        starts = [(e["time"], _SEGMENT.match(str(e.get("message", ""))))
                  for e in s.events if e.get("kind") == "segment"]
        starts = [(t, m) for t, m in starts if m]
        if not starts:
            return
        t_now = s.time[-1] if s.time else starts[-1][0]
        t0, m = starts[-1]
        length = float(m.group(2)) + float(m.group(3))
        within = min(1.0, max(0.0, (t_now - t0) / length)) if length > 0 else 1.0
        total = max(len(s.segments), 1)
        s.phase = m.group(1)
        s.progress = min(1.0, (len(starts) - 1 + within) / total)

    def _read_result(self) -> None:
        if self.snapshot.result is not None:
            return
        try:
            res = json.loads((self._dir / "result.json").read_text())
        except (OSError, ValueError):
            return
        if isinstance(res, dict):
            self.snapshot.result = res
            self.snapshot.progress = 1.0 if res.get("completed") else self.snapshot.progress
            self.snapshot.phase = "done"
            try:  # the whole log: the journal is removed once the log is saved
                log = TrialLog.load(self._dir / "trial.npz")
            except (OSError, ValueError, KeyError):
                return
            self.snapshot.events = [e.as_dict() for e in log.events]
            if not self.snapshot.joints:  # first seen finished (its journal already gone): the log says
                self.snapshot.joints, self.snapshot.segments = list(log.joint_names), list(log.segment_names)
            self._final_rows(log)

    def _final_rows(self, log: TrialLog) -> None:
        """The page's rows rebuilt from the saved log, so the end shows every cycle's share."""
        s = self.snapshot
        if not len(log):
            return
        keep, _ = decimate(log.time, -np.inf)
        whole = loop_timing(log)
        if whole.state == "paced":  # the saved log's count: the journal's last half second included
            s.timing = {"paced": True, "cycles": whole.cycles, "missed": whole.missed,
                        "worst_late_s": whole.worst_late_s, "period_s": whole.period_median_s,
                        "bus_s": whole.bus_median_s, "late": whole.late}
        s.twin_sum = []
        self._signals = 2 if log.twin_current else 1
        if log.twin_z is not None and self._start_detector(log.metadata):  # the saved log's, every row
            s.twin_sum = self._detect(log.twin_columns)[keep].tolist()
        s.epoch += 1
        s.time = log.time[keep].tolist()
        s.q_cmd = log.q_cmd[keep].tolist()
        s.q = log.q[keep].tolist()
        self._margins(log.q[-1], log.q_cmd[-1], int(log.segment[-1]))


def decimate(times: np.ndarray, next_t: float) -> tuple[list[int], float]:
    """Rows at most :data:`MAX_POINTS_HZ` apart, and always the newest, so the page is never
    behind; returns them and the time the next kept row must reach."""
    keep = []
    for i, t in enumerate(times):
        if t >= next_t:
            keep.append(i)
            next_t = t + 1.0 / MAX_POINTS_HZ
    if len(times) and (not keep or keep[-1] != len(times) - 1):
        keep.append(len(times) - 1)
    return keep, next_t
