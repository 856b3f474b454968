"""A trial's record on disk: its metadata, log, record.json and result.json; read back, recovered,
its report rebuilt from the record alone."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from pydantic import ValidationError

from bench.config.base import describe_validation_error
from bench.config.calibration import CalibrationFile, calibration_path, calibration_record
from bench.config.models import TrialConfig
from bench.core.log import JOURNAL_META, JOURNAL_ROWS, TrialLog
from bench.core.record import package_versions, write_record
from bench.core.result import PreparedTrial, TrialResult, judge_requirements, result_from_log, write_result_json
from bench.core.rundir import RECORD, RunDirError, SavedRun, load_run, read_journal, refuse_links
from bench.report.trial import write_trial_report
from bench.rig.serving import rig_kind
from bench.trial.plan import prepare
from drivers import BenchError

#: What rebuilding a report writes into the run directory.
REPORT_FILES = ("result.json", "report.md", "report.html", "joints.png", "robot.png", "twin.png", "cameras.png")

__all__ = ["RECORD_FIELDS", "finish_record", "load_checked", "load_record", "rebuild_report", "record_fields",
           "recover_run", "trial_metadata"]


#: What record.json holds beside the log's checksum, copied from the log's metadata: the config,
#: the calibration as applied, the servos read from the bus, the versions, and what ran it.
RECORD_FIELDS = ("config", "config_file", "calibration", "servos", "versions", "robot", "backend",
                 "rig", "seed", "start_time", "note")


def trial_metadata(prep: PreparedTrial, note: str) -> dict:
    config = prep.config
    return {
        "config": json.loads(config.model_dump_json()),
        "config_file": str(config.source) if config.source else None,
        # path and the content read once, applied by the backend; None when none applies
        "calibration": calibration_record(prep.calibration, prep.calibration_path),
        "robot": config.robot, "backend": config.backend.kind, "seed": config.seed,
        "rig": rig_kind(config),  # sim, emulated or real: what the backend drove
        "start_time": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(), "note": note,
        "target": {"entry_m": prep.target.entry.tolist(), "depth_m": prep.target.depth,
                   "angle_rad": prep.target.angle, "tilt_rad": prep.target.tilt},
        "q_entry": prep.q_entry.tolist(), "q_insert": prep.q_insert.tolist(),
        "control_period": config.control_period,
    }


def record_fields(metadata: dict) -> dict:
    """What record.json holds beside the log's checksum (:data:`RECORD_FIELDS`)."""
    return {k: metadata.get(k) for k in RECORD_FIELDS}


def finish_record(run_dir: Path, log: TrialLog, prep: PreparedTrial, truth: object = None) -> TrialResult:
    """The log, record.json and result.json on disk; the journal removed once they are. The
    requirements are judged first (on ``truth``, a GroundTruth recorder, where it saw the backend's
    joints), so the log keeps what they came to."""
    log_path = Path(run_dir) / "trial.npz"
    log.flush()
    judge_requirements(log, prep, truth)
    log.save(log_path)
    write_record(run_dir, log_path, record_fields(log.metadata))
    log.close_journal()
    res = result_from_log(run_dir, log, prep)
    write_result_json(res)
    return res


def load_record(run_dir: Path) -> tuple[TrialLog, PreparedTrial]:
    """The log and the prepared trial of a run directory, every file checked first
    (:mod:`bench.core.rundir`); a killed trial's journal is recovered into its log first."""
    saved, prep = load_checked(run_dir)
    return saved.log, prep


def load_checked(run_dir: Path) -> tuple[SavedRun, PreparedTrial]:
    """:func:`load_record` with the record itself (the log's checksum, for a reader that cites it)."""
    run_dir = Path(run_dir)
    if not (run_dir / RECORD).exists() and (run_dir / JOURNAL_META).is_file():
        recover_run(run_dir)
    saved = load_run(run_dir)
    log = saved.log
    try:
        config = TrialConfig.model_validate(_stored_config(log.metadata.get("config")),
                                            context={"record": True})
    except ValidationError as e:  # a record written by an incompatible version, or edited
        raise RunDirError(f"{run_dir}: the config stored in the log is not readable: "
                          f"{describe_validation_error(e, TrialConfig)}") from None
    except (BenchError, ValueError, TypeError) as e:
        raise RunDirError(f"{run_dir}: the config stored in the log is not readable: {e}") from None
    cal = log.metadata.get("calibration")
    if config.calibration is not None and config.backend.kind == "dynamixel" and not cal:
        raise RunDirError(f"{run_dir}: the config stored in the log names a calibration the record "
                          f"does not hold; nothing outside the run directory is read")
    if cal:  # the calibration as the trial applied it, not the file as it is now
        try:
            config._calibration_read = (calibration_path(config), CalibrationFile.model_validate(cal["content"]))
        except (ValidationError, KeyError, TypeError) as e:
            raise RunDirError(f"{run_dir}: the calibration stored in the log is not readable: {e}") from None
    try:  # the monitor's model file is not read again (the record holds what its twin said)
        prep = prepare(config.model_copy(update={"monitor": None})).with_config(config)
    except BenchError as e:
        raise RunDirError(f"{run_dir}: the config stored in the log: {e}") from None
    if list(log.joint_names) != list(prep.robot.joint_names):
        raise RunDirError(f"{run_dir}: the log's joints {log.joint_names} are not the joints of its "
                          f"robot {config.robot} ({list(prep.robot.joint_names)})")
    return saved, prep


def _stored_config(stored: object) -> object:
    """The config a record holds, to validate without following a path it names: the scene is
    the installed package's URDFs for its robot (a record travels; the folder it ran from does
    not, and a crafted one may name any file)."""
    if not isinstance(stored, dict):
        return stored
    return {**stored, "urdf_dir": "urdf"}


def recover_run(run_dir: Path) -> Path:
    """trial.npz and record.json of a trial whose process was killed, from its journal (checked)."""
    refuse_links(run_dir, ("trial.npz", RECORD))
    log = read_journal(run_dir)
    if not any(e.kind in ("done", "abort") for e in log.events):
        log.event(log.time[-1] if len(log) else 0.0, "abort",
                  "the trial's process ended without saving its log (killed?); "
                  "recovered from the journal")
    log_path = Path(run_dir) / "trial.npz"
    log.save(log_path)
    write_record(run_dir, log_path, record_fields(log.metadata))
    for name in (JOURNAL_ROWS, JOURNAL_META):
        (Path(run_dir) / name).unlink(missing_ok=True)
    return log_path


def rebuild_report(run_dir: Path) -> TrialResult:
    """Write the report of a run directory again, from its record alone."""

    log, prep = load_record(run_dir)
    refuse_links(run_dir, REPORT_FILES)
    res = result_from_log(run_dir, log, prep)
    write_trial_report(res, log, prep)
    return res
