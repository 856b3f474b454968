"""``--monitor MODEL`` on the commands that run trials, and the line that says what it saw."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from pydantic import ValidationError

from bench.cli.common import fail
from bench.config.models import TrialConfig

MONITOR_HELP = ("Run the twin beside the trial: the servo model (datasheet, or a model file from "
                "`hilbench identify`) in step with the joints; an alarm names a joint that stops behaving "
                "like its model (the config's monitor.action: warn or stop).")


def with_monitor(config: TrialConfig, model: Optional[str]) -> TrialConfig:
    """``config`` with its monitor's model set from the command line (a path relative to here)."""
    if model is None:
        return config
    from bench.config.monitor import MonitorConfig  # deferred: --help and completion stay fast

    path = Path(model)
    named = str(path.resolve()) if model != "datasheet" and path.exists() else model
    action = config.monitor.action if config.monitor is not None else "warn"
    try:
        m = MonitorConfig.model_validate({"model": named, "action": action})
    except ValidationError as e:
        fail(f"--monitor: {e.errors()[0]['msg'].removeprefix('Value error, ')}")
    return config.model_copy(update={"monitor": m})


def monitor_line(summary: dict) -> str:
    """One line: the model, and no alarm or the alarms (joint and time)."""
    alarms = summary.get("alarms") or []
    head = f"monitor ({Path(summary['model']).name}, {summary['action']}): "
    if not alarms:
        return head + f"no alarm on {len(summary.get('joints', []))} joints"
    shown = ", ".join(f"{a['joint']} at {a['t_s']:.2f} s" for a in alarms[:4])
    more = f" and {len(alarms) - 4} more" if len(alarms) > 4 else ""
    return head + f"{len(alarms)} alarm{'s' if len(alarms) > 1 else ''}: {shown}{more}"
