"""``hilbench check``: every check a trial makes before moving, run on a config file alone."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.config.models import ConfigError, load_trial_config
from bench.core.result import TrialError
from bench.trial.plan import prepare
from bench.trial.preflight import port_problems

__all__ = ["CheckResult", "check_config"]


@dataclass(frozen=True)
class CheckResult:
    """One named check of `hilbench check`: passed or not, and what it found."""

    name: str
    ok: bool
    detail: str


def check_config(path, emulate: bool = False) -> list[CheckResult]:
    """Every check a trial makes before moving, on a config file; stops at the first failure.

    ``emulate``: the ports will be the emulated rig's, so the configured ones are not checked.
    """

    try:
        config = load_trial_config(path)
    except ConfigError as e:
        return [CheckResult("config", False, str(e))]
    results = [CheckResult("config", True, f"{config.name}: {config.robot}, {config.backend.kind} "
                                           f"backend, {config.control_hz:g} Hz")]
    try:
        prep = prepare(config)
    except TrialError as e:
        return results + [CheckResult("target and plan", False, str(e))]
    entry = prep.robot.needle(prep.q_insert)
    results.append(CheckResult(
        "target and plan", True,
        f"reachable; needle {np.degrees(entry.angle):.1f}° into the bed; the planned path "
        f"clears every interlock" + ("" if config.safety.enabled else " (interlocks disabled)")))
    if config.backend.kind == "dynamixel" and not emulate:
        problems = port_problems(config)
        results.append(CheckResult("ports", not problems, "; ".join(problems) or "present and "
                                                                                 "writable"))
    return results
