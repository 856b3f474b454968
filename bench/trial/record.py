"""A trial's record on disk: its metadata, log, record.json and result.json; read back, recovered,
its report rebuilt from the record alone."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from bench.config.calibration import CalibrationFile, calibration_path, calibration_record
from bench.config.models import TrialConfig
from bench.core.log import JOURNAL_META, JOURNAL_ROWS, TrialLog
from bench.core.record import package_versions, sha256_of, write_record
from bench.core.result import PreparedTrial, TrialError, TrialResult, result_from_log, write_result_json
from bench.report.trial import write_trial_report
from bench.rig.live import rig_kind
from bench.trial.plan import prepare

__all__ = ["RECORD_FIELDS", "finish_record", "load_record", "rebuild_report", "record_fields", "recover_run",
           "trial_metadata"]


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


def finish_record(run_dir: Path, log: TrialLog, prep: PreparedTrial) -> TrialResult:
    """The log, record.json and result.json on disk; the journal removed once they are."""
    log_path = Path(run_dir) / "trial.npz"
    log.flush()
    log.save(log_path)
    write_record(run_dir, log_path, record_fields(log.metadata))
    log.close_journal()
    res = result_from_log(run_dir, log, prep)
    write_result_json(res)
    return res


def load_record(run_dir: Path) -> tuple[TrialLog, PreparedTrial]:
    """The log and the prepared trial of a run directory, after checking the log's checksum."""
    run_dir = Path(run_dir)
    rec_path = run_dir / "record.json"
    if not rec_path.is_file() and (run_dir / JOURNAL_META).is_file():
        recover_run(run_dir)
    if not rec_path.is_file():
        raise TrialError(f"{run_dir} has no record.json: not a trial run directory")
    rec = json.loads(rec_path.read_text())
    log_path = run_dir / rec["log"]
    if not log_path.is_file():
        raise TrialError(f"{log_path} is missing")
    if sha256_of(log_path) != rec["sha256"]:
        raise TrialError(f"{log_path.name} does not match the checksum in record.json: "
                         f"the log was modified after the trial")
    log = TrialLog.load(log_path)
    try:
        config = TrialConfig.model_validate(log.metadata["config"])
    except Exception as e:  # a record written by an incompatible version
        raise TrialError(f"the config stored in {log_path.name} is not readable: {e}") from None
    cal = log.metadata.get("calibration")
    if cal:  # the calibration as the trial applied it, not the file as it is now
        try:
            config._calibration_read = (calibration_path(config), CalibrationFile.model_validate(cal["content"]))
        except Exception as e:  # a record written by an incompatible version
            raise TrialError(f"the calibration stored in {log_path.name} is not readable: {e}") from None
    return log, prepare(config)


def recover_run(run_dir: Path) -> Path:
    """trial.npz and record.json of a trial whose process was killed, from its journal."""
    log = TrialLog.recover(run_dir)
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
    res = result_from_log(run_dir, log, prep)
    write_trial_report(res, log, prep)
    return res
