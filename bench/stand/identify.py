"""``identify`` on test-stand logs: a real servo's physics from BAM-format pendulum logs, as a
servo model file (robot ``test-stand``) and its HTML report.

The file holds the physics over the servo's datasheet in the keys every servo model file uses
(``kt_scale`` and ``ke_scale`` for Kt = Ke, ``resistance_ohm``, ``armature_kgm2``, friction
with ``load_friction``), the stand's gravity offset, ``supply: measured`` and the logs'
SHA-256; ``hilbench predict FILE LOG...`` rolls other logs out under it.
"""

from __future__ import annotations

import hashlib
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import yaml

from bench.config.servo_model import (STAND_JOINT, STAND_ROBOT, LogSource, ServoModelFile, ServoPhysics,
                                      StandSetup)
from bench.core.rundir import has_run_files
from bench.stand.errors import StandError
from bench.stand.fit import LOWER, PARAMS, UPPER, StandFit, batch_cost, fit_stand, init_worker
from bench.stand.fit_errors import stand_errors
from bench.stand.identify_report import write_stand_report
from bench.stand.logs import StandLog, read_stand_logs
from bench.stand.model import load_stand_model
from bench.stand.predict import Prediction, predict_logs
from drivers.dynamixel.control_table import model_spec
from drivers.errors import IdentifyError
from drivers.servo import ServoParams

__all__ = ["StandIdentifyResult", "identify_stand", "is_stand_input", "stand_model_file"]

Progress = Callable[[str, float], None]


@dataclass
class StandIdentifyResult:
    """What the stand's identification found and where it wrote it."""

    logs: list[StandLog]
    fit: StandFit
    model: ServoModelFile
    model_path: Path
    report_path: Optional[Path]
    before: Prediction
    after: Prediction
    seconds: float

    def as_dict(self) -> dict:
        return {"model": str(self.model_path), "report": str(self.report_path) if self.report_path else None,
                "logs": [{"log": str(b.log.path), "mae_before": b.mae, "mae_after": a.mae}
                         for b, a in zip(self.before.scores, self.after.scores)],
                "mae_before": self.before.mean_mae, "mae_after": self.after.mean_mae,
                "values": self.fit.as_values(), "uncertainty": self.model.uncertainty.get(STAND_JOINT, {}),
                "unobservable": self.model.unobservable.get(STAND_JOINT, []), "seconds": round(self.seconds, 3)}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def stand_model_file(logs: Sequence[StandLog], fit: StandFit, datasheet: ServoParams,
                     errors: np.ndarray | None = None, told: np.ndarray | None = None) -> ServoModelFile:
    """The fitted values as a servo model file over the datasheet of the logs' servo, with each
    value's standard error (in the fit's terms: Kt = Ke in N·m/A, R in Ω, ...) and those the logs
    could not tell."""
    v = fit.as_values()
    uncertainty, unobservable = {}, []
    if errors is not None and told is not None:
        # in the file's keys: Kt's error as a factor on the datasheet's (Ke follows it)
        key = {"kt_nma": "kt_scale"}
        unit = {"kt_nma": float(datasheet.kt[0])}
        uncertainty = {STAND_JOINT: {key.get(k, k): float(e) / unit.get(k, 1.0)
                                     for k, e in zip(PARAMS, errors) if np.isfinite(e)}}
        unobservable = [key.get(k, k) for k, t in zip(PARAMS, told) if not t]
    kt_scale = v["kt_nma"] / float(datasheet.kt[0])
    ke_scale = v["kt_nma"] / (float(datasheet.ke[0]) * kt_scale)  # Ke = Kt
    physics = ServoPhysics(kt_scale=kt_scale, ke_scale=ke_scale, resistance_ohm=v["resistance_ohm"],
                           armature_kgm2=v["armature_kgm2"], coulomb_nm=v["coulomb_nm"],
                           viscous_nms=v["viscous_nms"], load_friction=v["load_friction"])
    name = model_spec(logs[0].model_number).name
    return ServoModelFile(
        robot=STAND_ROBOT, servo=name, joints={STAND_JOINT: physics}, supply="measured",
        uncertainty=uncertainty, unobservable={STAND_JOINT: unobservable} if unobservable else {},
        stand=StandSetup(gravity_offset_rad=v["gravity_offset_rad"]),
        sources=[LogSource(run=str(g.path), sha256=_sha256(g.path)) for g in logs],
        notes=[f"identified from {len(logs)} test-stand log(s) of an {name} "
               f"({fit.generations} CMA-ES generations): "
               f"mean open-loop MAE {fit.mae_after.mean():.4f} rad; Kt = Ke = {v['kt_nma']:.4f} N·m/A"])


def _write_model(model: ServoModelFile, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = model.model_dump(exclude_none=True, exclude_defaults=False)
    path.write_text("# servo model identified from test-stand logs (hilbench identify)\n"
                    + yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")


def identify_stand(paths: Sequence[Path], out: Path, *, workers: int = 0, generations: int = 40,
                   seed: int = 0, progress: Progress | None = None, report: bool = True) -> StandIdentifyResult:
    """Read and check every log, fit, write the model file and (``report``) its HTML report."""
    started = time.monotonic()
    say = progress or (lambda what, fraction: None)
    say("reading logs", 0.0)
    try:
        logs = read_stand_logs(paths)
    except StandError as e:
        raise IdentifyError(str(e)) from None
    motors = sorted({g.motor for g in logs})
    if len(motors) > 1:
        raise IdentifyError(f"logs of different servos ({', '.join(motors)}): identify one servo at a time")
    datasheet = ServoParams.datasheet([logs[0].model_number])
    workers = workers or min(os.cpu_count() or 1, 2)
    pool = (ProcessPoolExecutor(workers, initializer=init_worker, initargs=(logs, datasheet))
            if workers > 1 else None)
    try:
        fit = fit_stand(logs, datasheet, generations=generations, seed=seed, pool=pool, workers=workers,
                        progress=lambda g, n: say("fitting", g / max(n, 1)))
        say("standard errors", 1.0)
        errors, told = stand_errors(lambda values: batch_cost(logs, datasheet, values, pool, workers),
                                    fit.values, LOWER, UPPER)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    model = stand_model_file(logs, fit, datasheet, errors, told)
    out = Path(out)
    _write_model(model, out)
    say("report", 1.0)
    before = predict_logs(load_stand_model("datasheet", logs[0].model_number), logs, "datasheet")
    after = predict_logs(load_stand_model(out, logs[0].model_number), logs, str(out))
    report_path = None
    if report:
        report_path = write_stand_report(before, after, model, out.with_suffix(".html"), fit.as_values())
    return StandIdentifyResult(logs, fit, model, out, report_path, before, after, time.monotonic() - started)


def is_stand_input(path: Path) -> bool:
    """Whether ``path`` is a test-stand log (a JSON file) or a directory of them, rather than a
    trial run directory (which holds a trial's log, record or journal, however damaged)."""
    path = Path(path)
    if path.is_dir():
        return not has_run_files(path) and any(path.glob("*.json"))
    return path.suffix.lower() == ".json"
