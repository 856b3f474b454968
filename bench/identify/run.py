"""``identify``: trial logs in, a servo model file and its report out.

The model file speaks the schema of ``emulator.servo_physics`` (so a sim config or
``compare --sim-model`` takes it as it is), with each value's standard error, the values the
logs could not tell (kept at the datasheet's) and the logs it came from.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import yaml

from bench.config.servo_model import LogSource, ServoModelFile, ServoPhysics
from bench.identify.errors import IdentifyError
from bench.identify.fit import FitResult, JointFit, fit_servos, goal_moving
from bench.identify.logs import LoggedRun, RigSetup, load_runs
from bench.identify.report import write_report
from bench.monitor.build import DEFAULT_SIGMA_CURRENT_A, default_sigma, encoder_tick
from bench.monitor.spread import twin_spread
from bench.monitor.twin import TwinSetup
from bench.paths import robot_urdf
from bench.rig.backends import with_physics

__all__ = ["IdentifyResult", "identify", "model_file_of"]

#: Phases reported to ``progress(what, fraction)``.
Progress = Callable[[str, float], None]


@dataclass
class IdentifyResult:
    """What ``identify`` found and where it wrote it."""

    setup: RigSetup
    runs: list[LoggedRun]
    fit: FitResult
    model: ServoModelFile
    model_path: Path
    report_path: Optional[Path]
    seconds: float

    def mae(self, which: str) -> float:
        """Position MAE over every fitted joint (rad for revolute, m for slides: each in its unit,
        averaged as the issue's JSON asks, SI)."""
        values = [getattr(j, which) for j in self.fit.joints.values()]
        return float(np.mean(values)) if values else math.nan

    def as_dict(self) -> dict:
        joints = {name: {"mae_before": j.mae_before, "mae_after": j.mae_after,
                         "current_mae_before": j.current_mae_before, "current_mae_after": j.current_mae_after,
                         "unobservable": self.model.unobservable.get(name, []),
                         "why": dict(j.reasons), "left_out_s": [[a, b] for _, a, b in j.left_out]}
                  for name, j in self.fit.joints.items()}
        return {"model": str(self.model_path), "report": str(self.report_path) if self.report_path else None,
                "joints": joints, "skipped": self.fit.skipped,
                "mae_before": self.mae("mae_before"), "mae_after": self.mae("mae_after"),
                "logs": [str(r.run_dir) for r in self.runs], "seconds": round(self.seconds, 3)}


#: A joint whose goals moved it for less than this (s, over all its logs) is fitted to too little
#: (the way to and from the excitation, about 5 s on the lab plan): its file takes its peers' physics.
MIN_MOTION_S = 8.0


def motion_seconds(setup: RigSetup, runs: Sequence[LoggedRun], joint: int) -> float:
    """How long the logs' goals moved ``joint`` (s), at a degree or a millimetre a second or more."""
    total = 0.0
    for run in runs:
        if len(run.time) < 2:
            continue
        total += float(np.sum(np.diff(run.time)[goal_moving(setup, run)[1:, joint]]))
    return total


def model_file_of(setup: RigSetup, runs: Sequence[LoggedRun], fit: FitResult) -> ServoModelFile:
    """The servo model file of a fit: every value as fitted (what the logs cannot tell on its own
    was held near the datasheet's by the fit's prior, and its combination with the others is what
    the logs do tell), each with its standard error, the ones the logs cannot tell listed."""
    joints: dict[str, ServoPhysics] = {}
    uncertainty: dict[str, dict[str, float]] = {}
    unobservable: dict[str, list[str]] = {}
    notes_at_bound: list[str] = []
    notes_why: list[str] = []
    for name, jf in fit.joints.items():
        values = dict(jf.values)
        if jf.at_bound:
            peers = peer_values(setup, fit, name, jf.at_bound)
            if peers is not None:
                values.update(peers[0])
                notes_at_bound.append(f"{name}: {', '.join(jf.at_bound)} ran to the edge of the fit's range "
                                      f"(the logs cannot tell them); the median of "
                                      f"{', '.join(peers[1])} instead")
            else:
                notes_at_bound.append(f"{name}: {', '.join(jf.at_bound)} ran to the edge of the fit's range "
                                      f"(the logs cannot tell them) and no joint with its servo model has them")
        joints[name] = ServoPhysics(**{k: max(v, 0.0) if k in ("coulomb_nm", "stribeck_nm", "viscous_nms")
                                       else v for k, v in values.items()})
        uncertainty[name] = {k: v for k, v in jf.stderr.items() if math.isfinite(v)}
        hidden = [key for key, ok in jf.observable.items() if not ok]
        if hidden:
            unobservable[name] = hidden
            notes_why.append(f"{name}: not observable: " + "; ".join(f"{k} ({jf.reasons[k]})" for k in hidden
                                                                       if k in jf.reasons))
    notes = [f"identified from {len(runs)} log(s) by hilbench identify: each joint's servo simulated "
             f"along its logged motion, position and current fitted (CMA-ES, then Levenberg-Marquardt)"]
    notes += notes_at_bound + notes_why
    # a joint whose logs do not tell even its motor constant (moved only on the way to the
    # excitation, say) was fitted to too little: it takes its told peers' physics instead
    weak = {}
    for name, jf in fit.joints.items():
        moved = motion_seconds(setup, runs, setup.joint_names.index(name))
        if moved < MIN_MOTION_S:
            weak[name] = f"its logs move it for {moved:.1f} s only (at least {MIN_MOTION_S:g} s to fit on)"
        elif not jf.observable["kt_scale"]:
            weak[name] = (f"its logs do not tell even its motor constant "
                          f"({jf.reasons.get('kt_scale', 'not observable')})")
    # each joint fitted to too little, then each not fitted, takes its told peers' physics
    takes = [(n, f"too little to fit on: {weak[n]}") for n in sorted(weak, key=setup.joint_names.index)]
    takes += [(n, f"not fitted, {why}") for n, why in fit.skipped.items()]
    for name, what in takes:
        pooled = pooled_physics(setup, fit, name, joints, exclude=frozenset(weak))
        if pooled is None:  # no told peer: a joint fitted to too little keeps its fit
            if name in fit.skipped:
                notes.append(f"{name}: {what}; datasheet values")
            continue
        physics, peers = pooled
        joints[name] = ServoPhysics(**physics)
        unobservable[name] = list(physics)
        notes.append(f"{name}: {what}; the median of the fitted joints with its servo model "
                     f"({', '.join(peers)})")
    return ServoModelFile(robot=setup.robot, joints=joints, uncertainty=uncertainty, unobservable=unobservable,
                          sources=[LogSource(run=str(r.run_dir), sha256=r.sha256) for r in runs], notes=notes)


def spread_of(setup: RigSetup, runs: Sequence[LoggedRun], model: ServoModelFile,
              fitted: Sequence[str]) -> tuple[dict[str, float], dict[str, float]]:
    """Per joint its servo drives by its own goals (the train on its sensor aside), the spread the
    identified model's twin leaves on these logs, of the position and of the current: what the
    monitor divides its residuals by.

    A joint the logs did not move (not among ``fitted``) has its peers' physics, and the logs
    measured nothing of how far those are from its own: its σ is the largest its fitted peers left,
    in encoder ticks through its transmission (a slide at insertion speed drifts by the borrowed
    model's error, not by the tick it sat still within), and in amps of the same motors."""
    params = with_physics(setup.datasheet, [model.physics_of(n) for n in setup.joint_names])
    twin = TwinSetup(str(robot_urdf(setup.robot)), setup.joint_names, params, setup.ratio, setup.offset,
                     setup.lower, setup.upper, setup.kt_datasheet)
    floor = default_sigma(setup.ratio, setup.kinds)
    n = len(setup.joint_names)
    sigma, amps = twin_spread(twin, ((r.time, r.goal, r.q, r.qd, r.current) for r in runs), floor,
                              np.full(n, DEFAULT_SIGMA_CURRENT_A))
    tick = encoder_tick(setup.ratio)
    moved = [j for j, name in enumerate(setup.joint_names)
             if name in fitted and j != setup.train and np.isfinite(sigma[j])]
    if moved:
        still = [j for j, name in enumerate(setup.joint_names) if name not in fitted]
        sigma[still] = np.maximum(sigma[still], max(sigma[j] / tick[j] for j in moved) * tick[still])
        amps[still] = np.maximum(amps[still], max(amps[j] for j in moved))
    kept = [j for j in range(n) if j != setup.train and np.isfinite(sigma[j])]
    return ({setup.joint_names[j]: float(sigma[j]) for j in kept},
            {setup.joint_names[j]: float(amps[j]) for j in kept if np.isfinite(amps[j])})


def peer_values(setup: RigSetup, fit: FitResult, joint: str,
                keys: Sequence[str]) -> tuple[dict[str, float], list[str]] | None:
    """For values a joint's fit ran to the edge of their range: the median of the fitted joints
    with the same servo model whose own fit kept them inside it; None when there is none."""
    model = setup.models[setup.joint_names.index(joint)]
    peers = [n for n, jf in fit.joints.items() if n != joint
             and setup.models[setup.joint_names.index(n)] == model and not set(keys) & set(jf.at_bound)]
    if not peers:
        return None
    return {k: float(np.median([fit.joints[n].values[k] for n in peers])) for k in keys}, peers


def pooled_physics(setup: RigSetup, fit: FitResult, joint: str, written: dict[str, ServoPhysics],
                   exclude: frozenset[str] = frozenset()) -> tuple[dict[str, float], list[str]] | None:
    """For a joint the logs never moved (or barely): the median physics of the fitted joints with
    the same servo model (the same motor and gearbox, so closer than the datasheet's bare values),
    as ``written`` for them (a value a peer's fit ran to the edge of is pooled as its file holds
    it), ``exclude`` left out; None when no such joint was fitted."""
    model = setup.models[setup.joint_names.index(joint)]
    peers = [n for n in fit.joints if setup.models[setup.joint_names.index(n)] == model
             and n != joint and n not in exclude]
    if not peers:
        return None
    keys = list(fit.joints[peers[0]].values)
    return {k: float(np.median([getattr(written[n], k) for n in peers])) for k in keys}, peers


def write_model_file(model: ServoModelFile, path: Path) -> None:
    """The model as commented YAML (written whole, then moved into place)."""
    header = ("# Servo model identified from the rig's trial logs (hilbench identify).\n"
              "# Physics over the datasheet at each output shaft: N·m, N·m·s/rad, rad/s, kg·m²; kt_scale\n"
              "# is a factor on the motor constant. Use it as backend.servo_model: THIS_FILE in a sim\n"
              "# config, or hilbench compare CONFIG --sim-model THIS_FILE.\n")
    data = model.model_dump(mode="json", exclude_defaults=False)
    text = header + yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def identify(run_dirs: Sequence[Path], out: Path, *, workers: int = 0, generations: int = 40,
             max_iterations: int = 8, report: bool = True, progress: Progress | None = None) -> IdentifyResult:
    """Fit the servos of the logs' rig and write ``out`` (the model file) and its HTML report
    beside it (``out`` with ``.html``). ``workers``: processes for the simulations (0: one per
    core, 1: none)."""
    started = time.perf_counter()
    out = Path(out)
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise IdentifyError(f"--out {out}: a servo model file ends in .yaml or .yml")
    if out.exists() and out.is_dir():
        raise IdentifyError(f"--out {out}: is a directory; give the model file's path")
    if progress:
        progress("reading logs", 0.0)
    setup, runs = load_runs(run_dirs)
    n_workers = (os.cpu_count() or 1) if workers == 0 else max(1, workers)
    pool = ProcessPoolExecutor(n_workers) if n_workers > 1 else None
    try:
        fit = fit_servos(setup, runs, max_iterations=max_iterations, generations=generations, pool=pool,
                         workers=n_workers,
                         progress=(lambda done, total: progress("fitting", done / total)) if progress else None)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if not fit.joints:
        raise IdentifyError("no joint moved enough in these logs to identify (goals spanning at least "
                            "0.5° or 0.5 mm); run the excitation (hil_configs/identify.yaml) first")
    model = model_file_of(setup, runs, fit)
    if progress:
        progress("the twin's spread", 0.9)
    sigma, amps = spread_of(setup, runs, model, list(fit.joints))
    model = model.model_copy(update={"twin_sigma": sigma, "twin_sigma_current": amps})
    write_model_file(model, out)
    report_path = None
    if report:
        if progress:
            progress("report", 0.95)
        report_path = write_report(setup, runs, fit, model, out.with_suffix(".html"))
    if progress:
        progress("done", 1.0)
    return IdentifyResult(setup, runs, fit, model, out, report_path, time.perf_counter() - started)


def joint_rows(result: IdentifyResult) -> list[tuple[str, JointFit]]:
    """The fitted joints in the robot's order."""
    return [(n, result.fit.joints[n]) for n in result.setup.joint_names if n in result.fit.joints]
