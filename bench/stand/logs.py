"""Test-stand logs in BAM's format (Rhoban's "Better Actuator Models"): one servo driving a
pendulum, read whole and checked before anything uses them, resampled to 5 ms as BAM does.

A raw log (as recorded) has a header — ``mass`` (kg), ``length`` (m), optional ``arm_mass``
(kg), ``kp`` (the Position P Gain register), ``vin`` (nominal supply, V), ``motor`` — and
``entries``, each with ``timestamp`` (s), ``position`` (rad), ``speed`` (rad/s),
``goal_position`` (rad), ``torque_enable`` and, where recorded, ``input_volts`` (the measured
supply). BAM's resampled form adds ``dt`` and holds its entries on that grid already.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from bench.stand.errors import StandError
from drivers.dynamixel.control_table import XL330_M288

__all__ = ["MOTORS", "SAMPLE_S", "StandLog", "read_stand_log", "read_stand_logs", "resample"]

#: BAM's resampling period (s): every fit and score runs on this grid.
SAMPLE_S = 0.005
#: The ``motor`` names of BAM's logs the bench knows -> the servo's model number.
MOTORS = {"xl330": XL330_M288}

_HEADER = ("mass", "length", "kp", "vin", "motor", "entries")
_ENTRY = ("timestamp", "position", "speed", "goal_position", "torque_enable")


@dataclass(frozen=True)
class StandLog:
    """One test-stand log on BAM's 5 ms grid, SI units (rad, rad/s, V, kg, m)."""

    path: Path
    mass: float
    length: float
    arm_mass: float
    motor: str
    model_number: int
    kp: float
    vin: float
    trajectory: str
    time: np.ndarray
    goal: np.ndarray
    torque: np.ndarray  # bool
    position: np.ndarray
    velocity: np.ndarray
    volts: Optional[np.ndarray]  # the measured supply, None where the log has none

    @property
    def name(self) -> str:
        return self.path.stem

    def __len__(self) -> int:
        return len(self.time)


def _number(path: Path, where: str, value, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StandError(f"{path}: {where}: not a number ({value!r})")
    if not math.isfinite(value):
        raise StandError(f"{path}: {where}: not finite ({value!r})")
    if positive and value <= 0:
        raise StandError(f"{path}: {where}: must be positive, got {value!r}")
    return float(value)


def resample(time: np.ndarray, columns: dict[str, np.ndarray],
             dt: float = SAMPLE_S) -> tuple[np.ndarray, dict]:
    """BAM's resampling (``bam/process.py``): samples at 0, dt, ... up to the last timestamp, each
    interpolated linearly between the two recorded entries around it (the first extrapolated back
    from the first two); torque on where its interpolation exceeds one half."""
    grid = np.arange(0.0, time[-1], dt)
    frame = np.minimum(np.searchsorted(time[1:], grid, side="left"), len(time) - 2)
    t1, t2 = time[frame], time[frame + 1]
    r = (grid - t1) / (t2 - t1)
    out = {k: v[frame] + (v[frame + 1] - v[frame]) * r for k, v in columns.items()}
    if "torque_enable" in out:
        out["torque_enable"] = out["torque_enable"] > 0.5
    return grid, out


def read_stand_log(path: Path | str) -> StandLog:
    """A test-stand log, raw or resampled, checked whole; StandError naming the file and the field
    (missing, not a number, NaN, time not increasing, unknown motor, torque never on)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StandError(f"{path}: no such log") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise StandError(f"{path}: not a JSON log ({e})") from None
    if not isinstance(data, dict):
        raise StandError(f"{path}: not a test-stand log (a JSON object with a header and entries)")
    for key in _HEADER:
        if key not in data:
            raise StandError(f"{path}: {key}: missing")
    motor = data["motor"]
    if motor not in MOTORS:
        raise StandError(f"{path}: motor: unknown motor {motor!r}; known: {', '.join(sorted(MOTORS))}")
    mass = _number(path, "mass", data["mass"], positive=True)
    length = _number(path, "length", data["length"], positive=True)
    arm = data.get("arm_mass", data.get("arm-mass", 0.0))
    arm_mass = _number(path, "arm_mass", arm)
    if arm_mass < 0:
        raise StandError(f"{path}: arm_mass: must not be negative, got {arm!r}")
    kp = _number(path, "kp", data["kp"], positive=True)
    vin = _number(path, "vin", data["vin"], positive=True)
    entries = data["entries"]
    if not isinstance(entries, list) or len(entries) < 2:
        raise StandError(f"{path}: entries: needs a list of at least two entries")
    volts_given = any(isinstance(e, dict) and "input_volts" in e for e in entries)
    fields = _ENTRY + (("input_volts",) if volts_given else ())
    cols: dict[str, list[float]] = {k: [] for k in fields}
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise StandError(f"{path}: entries[{i}]: not an object")
        for key in fields:
            if key not in e:
                raise StandError(f"{path}: entries[{i}].{key}: missing")
            v = e[key]
            if key == "torque_enable" and isinstance(v, bool):
                v = float(v)
            cols[key].append(_number(path, f"entries[{i}].{key}", v))
    arrays = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    t = arrays.pop("timestamp")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise StandError(f"{path}: entries[{i}].timestamp: time not increasing ({t[i - 1]!r} then {t[i]!r})")
    if "dt" in data:  # BAM's resampled form: already on its grid
        time, res = t, dict(arrays)
        res["torque_enable"] = res["torque_enable"] > 0.5
    else:
        time, res = resample(t, arrays)
    if not res["torque_enable"].any():
        raise StandError(f"{path}: torque_enable: torque never on; the servo never drove the stand")
    return StandLog(path=path, mass=mass, length=length, arm_mass=arm_mass, motor=motor,
                    model_number=MOTORS[motor], kp=kp, vin=vin, trajectory=str(data.get("trajectory", "")),
                    time=time, goal=res["goal_position"], torque=res["torque_enable"],
                    position=res["position"], velocity=res["speed"], volts=res.get("input_volts"))


def read_stand_logs(paths: Sequence[Path | str]) -> list[StandLog]:
    """Every log read and checked before any is used (a directory stands for its ``*.json``)."""
    files: list[Path] = []
    for p in map(Path, paths):
        files += sorted(p.glob("*.json")) if p.is_dir() else [p]
    if not files:
        raise StandError(f"{', '.join(map(str, paths))}: no test-stand logs (*.json)")
    return [read_stand_log(f) for f in files]
