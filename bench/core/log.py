"""TrialLog: what a trial did, cycle by cycle, plus the metadata to reproduce it.

Saved as one ``.npz`` file: the time series as arrays and the metadata (config,
package versions, seed, events) as one JSON string inside it, so a log can be
moved, archived and compared without anything else.

While a trial runs, the log also goes to a journal beside it (raw float64
rows, and the metadata and events as JSON), flushed to the operating system
at least every :data:`FLUSH_EVERY_S`: a process killed outright (SIGKILL, out
of memory) leaves a log that :func:`bench.core.rundir.read_journal` reads back,
losing at most that last second.

Reading: :meth:`TrialLog.load` is for a log this process (or the bench's own
worker) has just written; a run directory from disk, which may have been edited,
truncated or crafted, is read through :mod:`bench.core.rundir`, which checks it.
"""

from __future__ import annotations

import json
import math
import os
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SERIES = ("time", "segment", "q_cmd", "qd_cmd", "q", "qd", "effort")
#: The loop's own timing, per cycle, in s, in a paced trial (a backend on the wall clock): when the
#: cycle started (the backend's clock), how late its work ended against its deadline (negative: the
#: slack it had), and how long its bus transactions took. NaN where a cycle was not timed.
TIMING_SERIES = ("loop_start", "loop_late", "bus_s")
#: The servo's own reading of the joint a rig reads through another sensor (the train's pinion
#: encoder under its ultrasonic reading), per cycle, in joint units; the log's ``encoder_joint``
#: names that joint. NaN where a cycle was not read from the servo.
ENCODER_SERIES = "q_encoder"
#: The twin's residual (bench.monitor), per cycle and joint, over the spread its model leaves on
#: clean trials (σ): what the monitor's detector accumulates. NaN where a joint is not watched or
#: a cycle was not (the first, the hold after a trip). Only in a monitored trial's log.
TWIN_SERIES = "twin_z"
#: The same of the joints' current (their effort as the backend reads it), where the monitor watches
#: it too (a backend that reports its servos' current).
TWIN_CURRENT_SERIES = "twin_current_z"
#: float64 records: time, segment, q_cmd qd_cmd q qd effort[, timing][, encoder][, twin[, twin current]]
JOURNAL_ROWS = "trial.journal"
JOURNAL_META = "trial.journal.json"  # joint and segment names, metadata, events
FLUSH_EVERY_S = 0.5


def journal_row_width(joints: int, timed: bool, encoder: bool, twin: bool = False,
                      twin_current: bool = False) -> int:
    """Doubles in one journal row (see :data:`JOURNAL_ROWS`): what every reader of a journal (the
    recovery, the live view, a test counting rows) derives from its metadata, in one place."""
    return (2 + 5 * joints + (len(TIMING_SERIES) if timed else 0) + (1 if encoder else 0)
            + (joints if twin else 0) + (joints if twin and twin_current else 0))


@dataclass
class Event:
    """Something that happened during a trial (segment start, interlock, abort...)."""

    time: float
    kind: str
    message: str

    def as_dict(self) -> dict:
        return {"time": self.time, "kind": self.kind, "message": self.message}


@dataclass
class TrialLog:
    """Recorded samples in SI units; arrays grow in chunks so a cycle costs little."""

    joint_names: list[str]
    segment_names: list[str] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    capacity: int = 4096

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        self._n = 0
        self._t = np.empty(self.capacity)
        self._seg = np.empty(self.capacity, dtype=np.int16)
        self._arr = {k: np.empty((self.capacity, n)) for k in ("q_cmd", "qd_cmd", "q", "qd", "effort")}

        self._timing: dict[str, np.ndarray] | None = None  # TIMING_SERIES once timing started
        self.encoder_joint: str | None = None  # the joint of ENCODER_SERIES once it started
        self._encoder: np.ndarray | None = None
        self._twin: np.ndarray | None = None  # TWIN_SERIES (then TWIN_CURRENT_SERIES) once the monitor starts
        self._journal = None  # (rows file, meta path) while journaling
        self._journaled = 0
        self._meta_dirty = True
        self._next_flush = 0.0

    def __len__(self) -> int:
        return self._n

    def _grow(self, need: int = 0) -> None:
        cap = max(2 * len(self._t), need)
        self._t = np.resize(self._t, cap)
        self._seg = np.resize(self._seg, cap)
        for k, a in self._arr.items():
            grown = np.empty((cap, a.shape[1]))
            grown[: self._n] = a[: self._n]
            self._arr[k] = grown
        if self._timing is not None:
            for k, a in self._timing.items():
                grown = np.full(cap, np.nan)  # rows not yet timed read as NaN, whatever follows
                grown[: self._n] = a[: self._n]
                self._timing[k] = grown
        if self._encoder is not None:
            grown = np.full(cap, np.nan)
            grown[: self._n] = self._encoder[: self._n]
            self._encoder = grown
        if self._twin is not None:
            grown = np.full((cap, self._twin.shape[1]), np.nan)
            grown[: self._n] = self._twin[: self._n]
            self._twin = grown

    def start_encoder(self, joint: str) -> None:
        """Record ``joint``'s servo encoder (:data:`ENCODER_SERIES`) from the first row on; a log
        that already holds rows, or a joint it does not have, is refused."""
        if self._n:
            raise ValueError(f"the encoder's channel starts with the first cycle; this log has {self._n} rows")
        if joint not in self.joint_names:
            raise ValueError(f"no joint {joint!r} to record the encoder of; the log has {self.joint_names}")
        self.encoder_joint = joint
        self._encoder = np.full(len(self._t), np.nan)
        self._meta_dirty = True
        if self._journal is not None:
            self._write_meta()

    def encode(self, position: float) -> None:
        """The encoder's reading (joint units) of the cycle last appended."""
        self._encoder[self._n - 1] = position

    def start_twin(self, current: bool = False) -> None:
        """Record the twin's residual (:data:`TWIN_SERIES`, and with ``current``
        :data:`TWIN_CURRENT_SERIES`) from the first row on (a monitored trial); a log that already
        holds rows is refused."""
        if self._n:
            raise ValueError(f"the twin's channel starts with the first cycle; this log has {self._n} rows")
        self._twin = np.full((len(self._t), len(self.joint_names) * (2 if current else 1)), np.nan)
        self._meta_dirty = True
        if self._journal is not None:
            self._write_meta()

    @property
    def twin_columns(self) -> np.ndarray | None:
        """The residuals as the monitor's detector has its columns: each joint's position, then
        (where the current was watched) each joint's current; None in a log without a monitor."""
        if self._twin is None:
            return None
        return self._twin[: self._n]

    @property
    def twin_current(self) -> bool:
        """Whether the log holds the twin's current residual beside its position's."""
        return self._twin is not None and self._twin.shape[1] > len(self.joint_names)

    def twin_rows(self, first: int, z: np.ndarray) -> None:
        """The twin's normalised residuals of rows ``first`` on (rows already appended): per row the
        joints' position residuals, then (a log that holds it) their current residuals."""
        self._twin[first:first + len(z)] = z

    def start_timing(self) -> None:
        """Record the loop's timing from the first row on (a paced trial); a log that already holds
        rows is refused, so every timed log is timed from its start."""
        if self._n:
            raise ValueError(f"the loop's timing starts with the first cycle; this log has {self._n} rows")
        self._timing = {k: np.full(len(self._t), np.nan) for k in TIMING_SERIES}
        self._meta_dirty = True
        if self._journal is not None:  # a reader of the journal learns the rows' width before any row
            self._write_meta()

    @property
    def timed(self) -> bool:
        """Whether the log holds the loop's timing (:data:`TIMING_SERIES`)."""
        return self._timing is not None

    def time_cycle(self, start: float, late: float, bus: float) -> None:
        """The timing of the cycle last appended: its start (s, backend clock), how late it ended
        against its deadline (s) and its bus time (s). Three stores, nothing allocated."""
        i, t = self._n - 1, self._timing
        t["loop_start"][i] = start
        t["loop_late"][i] = late
        t["bus_s"][i] = bus

    def append(self, t: float, segment: int, q_cmd, qd_cmd, q, qd, effort) -> None:
        i = self._n
        if i == len(self._t):
            self._grow()
        self._t[i] = t
        self._seg[i] = segment
        a = self._arr
        a["q_cmd"][i] = q_cmd
        a["qd_cmd"][i] = qd_cmd
        a["q"][i] = q
        a["qd"][i] = qd
        a["effort"][i] = effort
        self._n = i + 1

    def append_block(self, t, segment: int, q_cmd, qd_cmd, q, qd, effort) -> None:
        """Rows of consecutive cycles at once (arrays with one row per cycle)."""
        i, k = self._n, len(t)
        if i + k > len(self._t):
            self._grow(i + k)
        self._t[i:i + k] = t
        self._seg[i:i + k] = segment
        a = self._arr
        a["q_cmd"][i:i + k] = q_cmd
        a["qd_cmd"][i:i + k] = qd_cmd
        a["q"][i:i + k] = q
        a["qd"][i:i + k] = qd
        a["effort"][i:i + k] = effort
        self._n = i + k

    def event(self, t: float, kind: str, message: str) -> None:
        """Record an event at ``t`` on the trial's clock. Events are kept in the order they
        happened, and their times never go back: a time earlier than the last event's (a caller
        that only knows the last row's time, a clock unreadable after a lost bus: NaN) is taken
        as the last event's, so the log, the report and the live view list them in time order."""
        t = float(t)
        if self.events and not t >= self.events[-1].time:
            t = self.events[-1].time
        elif math.isnan(t):
            t = float(self.time[-1]) if len(self) else 0.0
        self.events.append(Event(t, kind, message))
        self._meta_dirty = True

    # -- journal (what survives a kill) -----------------------------------------
    def journal_to(self, directory: Path) -> None:
        """Start journaling into ``directory`` (rows so far included) and flush now."""
        directory = Path(directory)
        self._journal = (open(directory / JOURNAL_ROWS, "wb"), directory / JOURNAL_META)
        self._journaled = 0
        self._meta_dirty = True
        self.flush()

    def maybe_flush(self) -> None:
        """Flush the journal if the last flush is older than FLUSH_EVERY_S (cheap otherwise)."""
        if self._journal is not None and _time.monotonic() >= self._next_flush:
            self.flush()

    def flush(self) -> None:
        """Hand the rows and events recorded since the last flush to the operating system."""
        if self._journal is None:
            return
        rows, meta_path = self._journal
        i, n = self._journaled, self._n
        if n > i:
            a = self._arr
            cols = [self._t[i:n, None], self._seg[i:n, None].astype(float), a["q_cmd"][i:n],
                    a["qd_cmd"][i:n], a["q"][i:n], a["qd"][i:n], a["effort"][i:n]]
            if self._timing is not None:
                cols += [self._timing[k][i:n, None] for k in TIMING_SERIES]
            if self._encoder is not None:
                cols.append(self._encoder[i:n, None])
            if self._twin is not None:
                cols.append(self._twin[i:n])
            block = np.hstack(cols)
            rows.write(block.tobytes())
            rows.flush()
            self._journaled = n
        if self._meta_dirty:
            self._write_meta()
        self._next_flush = _time.monotonic() + FLUSH_EVERY_S

    def _write_meta(self) -> None:
        meta_path = self._journal[1]
        tmp = meta_path.with_name(meta_path.name + ".part")
        tmp.write_text(json.dumps(self._meta(), default=_json_default))
        tmp.replace(meta_path)
        self._meta_dirty = False

    def close_journal(self, remove: bool = True) -> None:
        """Stop journaling; ``remove`` deletes the journal (once the .npz holds everything)."""
        if self._journal is None:
            return
        rows, meta_path = self._journal
        rows.close()
        self._journal = None
        if remove:
            for path in (Path(rows.name), meta_path):
                try:
                    os.unlink(path)
                except FileNotFoundError:
                    pass

    # -- views ---------------------------------------------------------------
    @property
    def time(self) -> np.ndarray:
        return self._t[: self._n]

    @property
    def segment(self) -> np.ndarray:
        return self._seg[: self._n]

    def __getattr__(self, name: str) -> np.ndarray:
        if name in ("q_cmd", "qd_cmd", "q", "qd", "effort"):
            return self.__dict__["_arr"][name][: self.__dict__["_n"]]
        if name in TIMING_SERIES:  # None in a log without the loop's timing (a sim's, an old one)
            timing = self.__dict__["_timing"]
            return None if timing is None else timing[name][: self.__dict__["_n"]]
        if name == ENCODER_SERIES:  # None in a log without it (no joint read through another sensor)
            enc = self.__dict__["_encoder"]
            return None if enc is None else enc[: self.__dict__["_n"]]
        if name == TWIN_SERIES:  # None in a log without a monitor
            twin = self.__dict__["_twin"]
            return None if twin is None else twin[: self.__dict__["_n"], : len(self.__dict__["joint_names"])]
        if name == TWIN_CURRENT_SERIES:  # None in a log whose monitor watched no current
            twin, n = self.__dict__["_twin"], len(self.__dict__["joint_names"])
            return None if twin is None or twin.shape[1] == n else twin[: self.__dict__["_n"], n:]
        raise AttributeError(name)

    def joint(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r} in this log; it has {self.joint_names}") from None

    # -- persistence -----------------------------------------------------------
    def save(self, path: Path) -> Path:
        """Write the log atomically (a temporary file renamed into place)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = self._meta()
        tmp = path.with_name(path.name + ".part")
        with open(tmp, "wb") as f:
            timing = {k: getattr(self, k) for k in TIMING_SERIES} if self.timed else {}
            if self._encoder is not None:
                timing[ENCODER_SERIES] = self.q_encoder
            if self._twin is not None:
                timing[TWIN_SERIES] = self.twin_z
            if self.twin_current:
                timing[TWIN_CURRENT_SERIES] = self.twin_current_z
            np.savez_compressed(f, time=self.time, segment=self.segment,
                                **{k: getattr(self, k) for k in SERIES[2:]}, **timing,
                                meta=np.array(json.dumps(meta, default=_json_default)))
        tmp.replace(path)
        return path

    def _meta(self) -> dict:
        return {"joint_names": self.joint_names, "segment_names": self.segment_names,
                "events": [e.as_dict() for e in self.events], "metadata": self.metadata,
                "timing": self.timed, "encoder_joint": self.encoder_joint, "twin": self._twin is not None,
                "twin_current": self.twin_current}

    @classmethod
    def load(cls, path: Path) -> "TrialLog":
        """A log the bench wrote (no pickle); an untrusted run directory goes through bench.core.rundir."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"trial log not found: {path}")
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            log = cls(meta["joint_names"], meta["segment_names"], meta["metadata"],
                      [Event(**e) for e in meta["events"]], capacity=max(1, len(z["time"])))
            n = len(z["time"])
            log._t[:n] = z["time"]
            log._seg[:n] = z["segment"]
            for k in SERIES[2:]:
                log._arr[k][:n] = z[k]
            if "loop_start" in z.files:
                log.start_timing()
                for k in TIMING_SERIES:
                    log._timing[k][:n] = z[k]
            if ENCODER_SERIES in z.files and meta.get("encoder_joint"):
                log.start_encoder(meta["encoder_joint"])
                log._encoder[:n] = z[ENCODER_SERIES]
            if TWIN_SERIES in z.files and meta.get("twin"):
                current = TWIN_CURRENT_SERIES in z.files and bool(meta.get("twin_current"))
                log.start_twin(current)
                log._twin[:n, : len(log.joint_names)] = z[TWIN_SERIES]
                if current:
                    log._twin[:n, len(log.joint_names):] = z[TWIN_CURRENT_SERIES]
            log._n = n
        return log


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot store {type(o).__name__} in trial metadata")
