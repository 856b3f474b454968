"""What the excitation can tell of each joint's friction: the constant speeds its logs hold.

Friction against speed is told by motion at constant speed (the current then carries the
friction and the load, nothing of the inertia): the Stribeck velocity by constant speeds on
both sides of it, the Coulomb level and viscous friction by two past the Stribeck fade far
enough apart (at one, only their sum). A fit may still settle such a value in a narrow valley of its cost, but
what it settled on is then the model's way of following a chirp, not the gearbox's friction:
where the logs lack those speeds, the value is reported not observable, saying which speeds
are missing (:func:`speed_reasons`).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from bench.identify.logs import LoggedRun, RigSetup

__all__ = ["STEADY_S", "speed_reasons", "steady_speeds"]

#: A goal counts as at constant speed once its speed has stayed within 5 % for this long (s).
STEADY_S = 0.1
#: Speeds (rad/s at the shaft) within this factor of each other count as one.
SAME_SPEED = 1.25
#: A speed the logs hold for fewer rows than this is not counted.
MIN_ROWS = 10


def steady_speeds(setup: RigSetup, runs: Sequence[LoggedRun], joint: int) -> np.ndarray:
    """The distinct constant speeds (rad/s at the shaft, ascending) the logs' goals drove ``joint`` at."""
    found: list[np.ndarray] = []
    for run in runs:
        t = run.time
        if len(t) < 3:
            continue
        v = np.gradient(run.goal[:, joint], t) / abs(setup.ratio[joint])
        period = float(np.median(np.diff(t)))
        width = max(2, int(round(STEADY_S / max(period, 1e-6))))
        if len(v) <= width:
            continue
        windows = np.lib.stride_tricks.sliding_window_view(v, width)
        lo, hi = windows.min(axis=1), windows.max(axis=1)
        speed = np.abs(v[width - 1:])
        steady = (np.sign(lo) == np.sign(hi)) & (hi - lo <= 0.05 * speed) & (speed > 1e-3)
        found.append(speed[steady])
    speeds = np.sort(np.concatenate(found)) if found else np.zeros(0)
    if speeds.size == 0:
        return speeds
    groups = np.split(speeds, np.flatnonzero(speeds[1:] > speeds[:-1] * SAME_SPEED) + 1)
    return np.array([float(np.median(g)) for g in groups if len(g) >= MIN_ROWS])


def _speeds_text(speeds: np.ndarray) -> str:
    return ", ".join(f"{s:.2g}" for s in speeds) + " rad/s" if speeds.size else "none"


def speed_reasons(values: Mapping[str, float], speeds: np.ndarray) -> dict[str, str]:
    """Per friction key the logs' constant ``speeds`` cannot tell at the fitted ``values``, why."""
    ws = float(values["stribeck_velocity_rads"])
    held = f"the logs hold constant speeds of {_speeds_text(speeds)}"
    past = speeds[speeds >= 2 * ws]
    out: dict[str, str] = {}
    if not (np.any(speeds <= ws) and past.size):
        side = "below" if not np.any(speeds <= ws) else "past twice"
        out["stribeck_velocity_rads"] = f"no constant speed {side} it ({ws:.2g} rad/s); {held}"
    if not past.size:
        out["coulomb_nm"] = (f"no constant speed past the Stribeck fade (over {2 * ws:.2g} rad/s), where "
                             f"the friction is Coulomb's; {held}")
    if past.size < 2 or past.max() < 2 * past.min():
        out["viscous_nms"] = (f"friction rising with speed needs two constant speeds past the Stribeck fade "
                              f"(over {2 * ws:.2g} rad/s) a factor 2 apart; {held}")
        # one speed there tells Coulomb's level and the viscous slope as one sum
        out.setdefault("coulomb_nm", f"told only with the viscous slope: Coulomb's level and it need two "
                                     f"constant speeds past the Stribeck fade (over {2 * ws:.2g} rad/s) a "
                                     f"factor 2 apart; {held}")
    return out
