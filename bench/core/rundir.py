"""A run directory read back from disk, trusted for nothing: the one loader every reader uses.

A run directory may have been copied, truncated, edited or crafted: ``report``, ``runs``,
``compare RUN_A RUN_B``, ``identify`` and the campaign report all read it through here. What
is checked, before any number is used: ``record.json`` against its schema; the log it names a
plain file inside the run directory (no ``..``, no absolute path, no link out of it) whose
size and SHA-256 match the record; the log a zip of the arrays the bench writes (read without
pickle, so no Python object ever comes out of it), each array's dtype and shape, every value
finite, time strictly increasing, segment indices among the log's segments; the journal of a
killed trial in its format; ``result.json`` against its schema. What is wrong raises
:class:`RunDirError` naming the run and the fault in one line.
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool, ValidationError

from bench.config.base import describe_validation_error
from bench.core.log import (ENCODER_SERIES, JOURNAL_META, JOURNAL_ROWS, SERIES, TIMING_SERIES,
                            TWIN_CURRENT_SERIES, TWIN_SERIES, Event, TrialLog, journal_row_width)
from bench.core.record import sha256_of
from bench.core.result_file import ResultFile
from drivers.errors import RunDirError

__all__ = ["LOG_MAX_BYTES", "RECORD", "RESULT", "RecordFile", "ResultFile", "RunDirError", "SavedRun",
           "has_run_files", "load_run", "read_journal", "read_log_file", "read_result", "refuse_links"]

RECORD = "record.json"
RESULT = "result.json"
#: The most a log may unpack to: a 600 s plan at 2 kHz with nine joints is under half of it.
LOG_MAX_BYTES = 1 << 30
#: The most a JSON file of a run directory may hold (record.json, result.json, the journal's metadata).
JSON_MAX_BYTES = 64 << 20
_FLOAT_SERIES = SERIES[2:]


class RecordFile(BaseModel):
    """``record.json``: which file is the log, its SHA-256 and size (other fields are kept, unread)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    log: str = Field(min_length=1, max_length=255)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    bytes: int = Field(ge=0)


class _EventEntry(BaseModel):
    model_config = ConfigDict(extra="allow")

    time: float  # NaN allowed: an abort on a lost bus has no clock to read
    kind: str
    message: str


class _LogMeta(BaseModel):
    """The JSON inside a log (and the journal's metadata file)."""

    model_config = ConfigDict(extra="allow")

    joint_names: list[str] = Field(min_length=1, max_length=64)
    segment_names: list[str]
    events: list[_EventEntry]
    metadata: dict[str, Any]
    timing: StrictBool = False  # the loop's timing follows each row (TIMING_SERIES): a paced trial
    encoder_joint: Optional[str] = None  # the joint whose servo encoder follows (ENCODER_SERIES)
    twin: StrictBool = False  # the twin's residual follows each row (TWIN_SERIES): a monitored trial
    twin_current: StrictBool = False  # and its current's (TWIN_CURRENT_SERIES): a monitor that watched it


class _ConfigView(BaseModel):
    """The parts of the stored config a reader uses before validating it whole (if it does)."""

    model_config = ConfigDict(extra="allow")

    name: Optional[str] = None
    robot: Optional[str] = None
    plan: Optional[dict[str, Any]] = None
    backend: Optional[dict[str, Any]] = None
    acceptance: Optional[dict[str, Any]] = None


class _AlarmView(BaseModel):
    """One alarm of the twin (bench.monitor), as a listing reads it."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    joint: str = Field(max_length=64)
    t_s: float
    score: Optional[float] = None


class _MonitorView(BaseModel):
    """What the twin said of a monitored trial (its summary), as readers use it."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    model: str = Field(max_length=4096)
    alarms: list[_AlarmView] = Field(default_factory=list, max_length=100_000)
    cusum: Optional[dict[str, float]] = None
    joints: list[str] = Field(default_factory=list, max_length=64)


class _TrialMetadata(BaseModel):
    """The fields of a trial's metadata that readers use; each one, when present, of its type."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    robot: Optional[str] = None
    backend: Optional[str] = None
    start_time: Optional[str] = None
    config: Optional[_ConfigView] = None
    target: Optional[dict[str, float | list[float]]] = None
    q_entry: Optional[list[float]] = None
    q_insert: Optional[list[float]] = None
    control_period: Optional[float] = Field(None, gt=0)
    loop_wall_s: Optional[float] = Field(None, ge=0)  # the run's wall-clock time (a sim's speed)
    loop_priority: Optional[str] = Field(None, max_length=200)  # a paced loop's priority (nice -10)
    loop_clock: Optional[Literal["wall", "virtual"]] = None  # what a paced loop's deadlines were on
    monitor: Optional[_MonitorView] = None  # the twin's summary, in a monitored trial's log


@dataclass(frozen=True)
class SavedRun:
    """A run directory that passed every check: its record and its log."""

    run_dir: Path
    record: RecordFile
    log_path: Path
    log: TrialLog


def _refuse(where: object, what: str) -> RunDirError:
    return RunDirError(f"{where}: {what}".replace("\n", " "))


def has_run_files(run_dir: Path) -> bool:
    """Whether a directory holds any file a trial writes (else it is some other directory)."""
    return any(Path(run_dir, n).exists() or Path(run_dir, n).is_symlink()
               for n in (RECORD, RESULT, "trial.npz", JOURNAL_META, JOURNAL_ROWS))


def _inside(run_dir: Path, name: str) -> Path:
    """``run_dir/name``, refused unless ``name`` is a plain file name that stays in ``run_dir``."""
    if name in ("", ".", "..") or "/" in name or "\\" in name or "\0" in name:
        raise _refuse(run_dir, f"{name!r} is not a plain file name in the run directory")
    path = run_dir / name
    if path.is_symlink() and path.resolve().parent != run_dir.resolve():
        raise _refuse(run_dir, f"{name} is a link out of the run directory (to {path.resolve()})")
    return path


def _read_json(run_dir: Path, name: str) -> Any:
    path = _inside(run_dir, name)
    if not path.is_file():
        raise _refuse(run_dir, f"{name} is missing")
    if path.stat().st_size > JSON_MAX_BYTES:
        raise _refuse(run_dir, f"{name} is {path.stat().st_size} bytes, not a file the bench writes")
    try:
        return json.loads(path.read_bytes())
    except (ValueError, RecursionError) as e:
        raise _refuse(run_dir, f"{name} is not JSON ({type(e).__name__}: {str(e)[:80]})") from None
    except OSError as e:
        raise _refuse(run_dir, f"cannot read {name}: {e.strerror}") from None


def _model(run_dir: Path, name: str, model: type[BaseModel], data: Any) -> Any:
    if not isinstance(data, dict):
        raise _refuse(run_dir, f"{name} holds a {type(data).__name__}, not an object")
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise _refuse(run_dir, describe_validation_error(e, model, name)) from None


def refuse_links(run_dir: Path, names: tuple[str, ...]) -> None:
    """Before a reader writes ``names`` back into a run directory: none may be a link (a write
    would go through it, out of the run directory)."""
    for name in names:
        if (Path(run_dir) / name).is_symlink():
            raise _refuse(run_dir, f"{name} is a link (to {(Path(run_dir) / name).resolve()}); "
                                   f"nothing is written through it")


def read_result(run_dir: Path) -> Optional[ResultFile]:
    """``result.json`` checked against its schema; ``None`` when the run has none."""
    run_dir = Path(run_dir)
    if not (run_dir / RESULT).exists() and not (run_dir / RESULT).is_symlink():
        return None
    return _model(run_dir, RESULT, ResultFile, _read_json(run_dir, RESULT))


# -- the log's contents ---------------------------------------------------------------------


def _meta(where: object, name: str, data: Any) -> _LogMeta:
    if not isinstance(data, dict):
        raise _refuse(where, f"{name}: the log's metadata is a {type(data).__name__}, not an object")
    try:
        meta = _LogMeta.model_validate(data)
    except ValidationError as e:
        raise _refuse(where, describe_validation_error(e, _LogMeta, name)) from None
    try:
        _TrialMetadata.model_validate(meta.metadata)
    except ValidationError as e:
        raise _refuse(where, describe_validation_error(e, _TrialMetadata, f"{name}: metadata")) from None
    if len(set(meta.joint_names)) != len(meta.joint_names):
        raise _refuse(where, f"{name}: joint names repeat: {meta.joint_names}")
    return meta


def _first_bad(mask: np.ndarray) -> int:
    return int(np.argmax(mask.reshape(len(mask), -1).any(axis=1)))


def _check_series(where: object, name: str, meta: _LogMeta, arrays: dict[str, np.ndarray]) -> None:
    """Dtypes, shapes, finite values, strictly increasing time, segment indices in range."""
    n_joints = len(meta.joint_names)
    t, seg = arrays["time"], arrays["segment"]
    if t.ndim != 1 or t.dtype.kind != "f":
        raise _refuse(where, f"{name}: time is {t.dtype} of shape {t.shape}, not a float row per cycle")
    rows = t.shape[0]
    if seg.shape != (rows,) or seg.dtype.kind not in "iu":
        raise _refuse(where, f"{name}: segment is {seg.dtype} of shape {seg.shape}, "
                             f"not an integer per row ({rows} rows)")
    for k in _FLOAT_SERIES:
        a = arrays[k]
        if a.dtype.kind != "f" or a.shape != (rows, n_joints):
            raise _refuse(where, f"{name}: {k} is {a.dtype} of shape {a.shape}, not float of shape "
                                 f"({rows}, {n_joints}) for {n_joints} joints")
    for k in SERIES[:1] + _FLOAT_SERIES:
        bad = ~np.isfinite(arrays[k])
        if bad.any():
            i = _first_bad(bad)
            col = f", joint {meta.joint_names[int(np.argmax(bad[i]))]}" if bad.ndim == 2 else ""
            raise _refuse(where, f"{name}: {k} holds {arrays[k][bad].flat[0]} at row {i}{col}; "
                                 f"a log holds finite numbers only")
    if rows > 1:
        back = np.diff(t) <= 0
        if back.any():
            i = int(np.argmax(back)) + 1
            raise _refuse(where, f"{name}: time does not increase at row {i} "
                                 f"({t[i]:.6g} s after {t[i - 1]:.6g} s)")
    if rows and meta.segment_names:
        out = (seg < 0) | (seg >= len(meta.segment_names))
        if out.any():
            i = _first_bad(out)
            raise _refuse(where, f"{name}: segment index {int(seg[i])} at row {i}; the log has "
                                 f"{len(meta.segment_names)} segments")


def _check_timing(where: object, name: str, rows: int, arrays: dict[str, np.ndarray]) -> None:
    """The loop's timing, when the log has it: all three series, a float per row, no infinity
    (NaN: a cycle not timed, such as the hold after a trip), no negative bus time."""
    present = [k for k in TIMING_SERIES if k in arrays]
    if not present:
        return
    if len(present) != len(TIMING_SERIES):
        missing = [k for k in TIMING_SERIES if k not in arrays]
        raise _refuse(where, f"{name} has {', '.join(present)} but no {', '.join(missing)}: "
                             f"the loop's timing is all three or none")
    for k in TIMING_SERIES:
        a = arrays[k]
        if a.dtype.kind != "f" or a.shape != (rows,):
            raise _refuse(where, f"{name}: {k} is {a.dtype} of shape {a.shape}, not a float per row "
                                 f"({rows} rows)")
        bad = np.isinf(a) | ((a < 0) if k == "bus_s" else False)
        if np.any(bad):
            i = int(np.argmax(bad))
            raise _refuse(where, f"{name}: {k} holds {a[i]} at row {i}; the loop's timing is finite "
                                 f"seconds (NaN where a cycle was not timed)")


def _check_encoder(where: object, name: str, meta: _LogMeta, rows: int, arrays: dict[str, np.ndarray]) -> None:
    """The servo encoder's channel, when the log has it: one of the log's joints named for it, a
    float per row, no infinity (NaN: a cycle not read from the servo). A log without it (one
    written before the channel, a simulator's) reads as before."""
    has = ENCODER_SERIES in arrays
    if has != (meta.encoder_joint is not None):
        raise _refuse(where, f"{name}: " + (f"{ENCODER_SERIES} without the joint it belongs to" if has else
                                             f"encoder_joint {meta.encoder_joint!r} without {ENCODER_SERIES}"))
    if not has:
        return
    if meta.encoder_joint not in meta.joint_names:
        raise _refuse(where, f"{name}: encoder_joint {meta.encoder_joint!r} is not one of its joints "
                             f"{meta.joint_names}")
    a = arrays[ENCODER_SERIES]
    if a.dtype.kind != "f" or a.shape != (rows,):
        raise _refuse(where, f"{name}: {ENCODER_SERIES} is {a.dtype} of shape {a.shape}, not a float per row "
                             f"({rows} rows)")
    if np.any(np.isinf(a)):
        i = int(np.argmax(np.isinf(a)))
        raise _refuse(where, f"{name}: {ENCODER_SERIES} holds {a[i]} at row {i}; an encoder reads a "
                             f"finite position (NaN where a cycle was not read)")


def _check_twin(where: object, name: str, meta: _LogMeta, rows: int, arrays: dict[str, np.ndarray]) -> None:
    """The twin's residuals, when the log has them: a float per row and joint, no infinity (NaN: a
    joint or cycle not watched). A log without them (an unmonitored trial's, an older one) reads as before."""
    if meta.twin_current and not meta.twin:
        raise _refuse(where, f"{name}: twin_current: true without twin: true in its metadata")
    for series, said, what in ((TWIN_SERIES, meta.twin, "twin"), (TWIN_CURRENT_SERIES, meta.twin_current,
                                                                   "twin_current")):
        has = series in arrays
        if has != said:
            raise _refuse(where, f"{name}: " + (f"{series} without {what}: true in its metadata" if has else
                                                 f"{what}: true without {series}"))
        if not has:
            continue
        a, n = arrays[series], len(meta.joint_names)
        if a.dtype.kind != "f" or a.shape != (rows, n):
            raise _refuse(where, f"{name}: {series} is {a.dtype} of shape {a.shape}, not float of shape "
                                 f"({rows}, {n})")
        if np.any(np.isinf(a)):
            i = _first_bad(np.isinf(a))
            raise _refuse(where, f"{name}: {series} holds an infinity at row {i}; a residual is finite "
                                 f"(NaN where not watched)")


def _build(meta: _LogMeta, arrays: dict[str, np.ndarray]) -> TrialLog:
    events = [Event(e.time, e.kind, e.message) for e in meta.events]
    log = TrialLog(list(meta.joint_names), list(meta.segment_names), dict(meta.metadata), events,
                   capacity=max(1, len(arrays["time"])))
    if TIMING_SERIES[0] in arrays:
        log.start_timing()
    log.append_block(arrays["time"].astype(float), 0, *(arrays[k].astype(float) for k in _FLOAT_SERIES))
    log._seg[: len(arrays["time"])] = arrays["segment"]
    if log.timed:
        for k in TIMING_SERIES:
            log._timing[k][: len(log)] = arrays[k]
    if meta.encoder_joint is not None:
        encoder = log._encoder = np.full(len(log._t), np.nan)  # its rows are in: filled directly
        log.encoder_joint = meta.encoder_joint
        encoder[: len(log)] = arrays[ENCODER_SERIES]
    if meta.twin:
        n = len(log.joint_names)
        # its rows are in: filled directly
        log._twin = np.full((len(log._t), n * (2 if meta.twin_current else 1)), np.nan)
        log._twin[: len(log), :n] = arrays[TWIN_SERIES]
        if meta.twin_current:
            log._twin[: len(log), n:] = arrays[TWIN_CURRENT_SERIES]
    return log


def _npy_headers(where: object, name: str, zf: zipfile.ZipFile) -> None:
    """Every member an array of the bench's, by its header alone: nothing loaded yet."""
    members = {i.filename: i for i in zf.infolist()}
    want = [f"{k}.npy" for k in (*SERIES, "meta")]
    missing = [m.removesuffix(".npy") for m in want if m not in members]
    if missing:
        raise _refuse(where, f"{name} has no {', '.join(missing)}: not a trial log")
    timing = [f"{k}.npy" for k in (*TIMING_SERIES, ENCODER_SERIES, TWIN_SERIES, TWIN_CURRENT_SERIES)
              if f"{k}.npy" in members]
    total = 0
    for m in want + timing:
        with zf.open(members[m]) as f:
            version = np.lib.format.read_magic(f)
            read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                    else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read(f)
        if dtype.hasobject:
            raise _refuse(where, f"{name}: {m.removesuffix('.npy')} holds Python objects, not numbers")
        total += math.prod(shape) * dtype.itemsize
    if total > LOG_MAX_BYTES:
        raise _refuse(where, f"{name} unpacks to {total} bytes, more than any trial's log")


def read_log_file(path: Path, where: Optional[object] = None) -> TrialLog:
    """A log file's contents, every check made; ``where`` names the run in the refusal."""
    path = Path(path)
    where = where if where is not None else path.parent
    if not path.is_file():
        raise _refuse(where, f"{path.name} is missing")
    try:
        with zipfile.ZipFile(path) as zf:
            _npy_headers(where, path.name, zf)
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in (*SERIES, *TIMING_SERIES, ENCODER_SERIES, TWIN_SERIES,
                                        TWIN_CURRENT_SERIES) if k in z.files}
            raw_meta = z["meta"]
    except RunDirError:
        raise
    except Exception as e:  # noqa: BLE001 - a truncated or crafted zip fails in many ways; all say "unreadable"
        raise _refuse(where, f"{path.name} is not a readable log ({type(e).__name__}: {str(e)[:80]})") from None
    if raw_meta.shape != () or raw_meta.dtype.kind != "U":
        raise _refuse(where, f"{path.name}: meta is {raw_meta.dtype} of shape {raw_meta.shape}, not a JSON text")
    try:
        data = json.loads(str(raw_meta))
    except (ValueError, RecursionError) as e:
        raise _refuse(where, f"{path.name}: its metadata is not JSON ({str(e)[:80]})") from None
    meta = _meta(where, path.name, data)
    _check_series(where, path.name, meta, arrays)
    _check_timing(where, path.name, len(arrays["time"]), arrays)
    _check_encoder(where, path.name, meta, len(arrays["time"]), arrays)
    _check_twin(where, path.name, meta, len(arrays["time"]), arrays)
    return _build(meta, arrays)


# -- the run directory --------------------------------------------------------------------------


def load_run(run_dir: Path) -> SavedRun:
    """A finished run directory: ``record.json``, and the log it names with its checksum, checked."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise _refuse(run_dir, "no such run directory")
    if not (run_dir / RECORD).exists() and not (run_dir / RECORD).is_symlink():
        raise _refuse(run_dir, f"no {RECORD}: not a trial's run directory")
    record = _model(run_dir, RECORD, RecordFile, _read_json(run_dir, RECORD))
    log_path = _inside(run_dir, record.log)
    if not log_path.is_file():
        raise _refuse(run_dir, f"{record.log}, the log {RECORD} names, is missing")
    size = log_path.stat().st_size
    if size != record.bytes:
        raise _refuse(run_dir, f"{record.log} does not match the checksum in {RECORD} ({size} bytes, "
                               f"the record says {record.bytes}): the log was changed after the trial")
    if sha256_of(log_path) != record.sha256:
        raise _refuse(run_dir, f"{record.log} does not match the checksum in {RECORD}: "
                               f"the log was changed after the trial")
    return SavedRun(run_dir, record, log_path, read_log_file(log_path, run_dir))


def read_journal(run_dir: Path) -> TrialLog:
    """The log of a killed trial from its journal (a torn last row dropped), every check made."""
    run_dir = Path(run_dir)
    data = _read_json(run_dir, JOURNAL_META)
    meta = _meta(run_dir, JOURNAL_META, data)
    rows_path = _inside(run_dir, JOURNAL_ROWS)
    if not rows_path.is_file():
        raise _refuse(run_dir, f"{JOURNAL_ROWS} is missing beside {JOURNAL_META}")
    if rows_path.stat().st_size > LOG_MAX_BYTES:
        raise _refuse(run_dir, f"{JOURNAL_ROWS} is larger than any trial's log")
    n = len(meta.joint_names)
    timed = len(TIMING_SERIES) if meta.timing else 0
    width = journal_row_width(n, bool(timed), meta.encoder_joint is not None, meta.twin, meta.twin_current)
    raw = np.frombuffer(rows_path.read_bytes(), dtype="<f8")
    rows = raw[: len(raw) // width * width].reshape(-1, width)
    seg = rows[:, 1]
    if not np.all(np.isfinite(seg)) or np.any(seg != np.round(seg)) or np.any(np.abs(seg) > 2 ** 15):
        i = _first_bad(~np.isfinite(seg) | (seg != np.round(seg)) | (np.abs(seg) > 2 ** 15))
        raise _refuse(run_dir, f"{JOURNAL_ROWS}: row {i} has segment {seg[i]}, not a segment index")
    arrays = {"time": rows[:, 0].copy(), "segment": seg.astype(np.int16)}
    for j, k in enumerate(_FLOAT_SERIES):
        arrays[k] = rows[:, 2 + j * n: 2 + (j + 1) * n].copy()
    if meta.timing:
        for j, k in enumerate(TIMING_SERIES):
            arrays[k] = rows[:, 2 + 5 * n + j].copy()
    encoder = int(meta.encoder_joint is not None)
    if encoder:
        arrays[ENCODER_SERIES] = rows[:, 2 + 5 * n + timed].copy()
    if meta.twin:
        first = 2 + 5 * n + timed + encoder
        arrays[TWIN_SERIES] = rows[:, first:first + n].copy()
        if meta.twin_current:
            arrays[TWIN_CURRENT_SERIES] = rows[:, first + n:first + 2 * n].copy()
    _check_series(run_dir, JOURNAL_ROWS, meta, arrays)
    _check_timing(run_dir, JOURNAL_ROWS, len(rows), arrays)
    _check_encoder(run_dir, JOURNAL_ROWS, meta, len(rows), arrays)
    _check_twin(run_dir, JOURNAL_ROWS, meta, len(rows), arrays)
    return _build(meta, arrays)
