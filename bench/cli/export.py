"""``hilbench export``: a trial's log as a file other robotics tools open (MCAP, ROS 2 messages).

Kept in its own module; ``bench/cli/app.py`` registers :func:`export`.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bench.cli.common import console, emit_json, fail

__all__ = ["export"]


def _result_of(run_dir: Path) -> dict | None:
    """result.json's fields when it passes its checks (the MCAP file carries them as metadata);
    read as every reader reads it, so a link out of the run directory is never followed."""
    from bench.core.rundir import RunDirError, read_result  # deferred: --help and completion stay fast

    try:
        res = read_result(run_dir)
    except RunDirError:
        return None
    return json.loads(res.model_dump_json()) if res is not None else None


def export(run_dir: Path = typer.Argument(..., help="A trial's run directory."),
           mcap: Path = typer.Option(..., "--mcap", help="The MCAP file to write (ROS 2 messages: "
                                                         "Foxglove and PlotJuggler open it as a bag)."),
           as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Write a trial's log as an MCAP file: joint states and commands, interlock margins, events."""
    from drivers import BenchError  # deferred: --help and completion stay fast
    from bench.export.mcap_bag import TIMING_TOPICS, TOPICS, write_mcap  # deferred: --help stays fast
    from bench.trial.record import load_record  # deferred: --help and completion stay fast

    if mcap.exists() and mcap.is_dir():
        fail(f"--mcap {mcap} is a directory; name the file to write")
    if not mcap.parent.is_dir():
        fail(f"--mcap {mcap}: the directory {mcap.parent} does not exist")
    try:
        log, prep = load_record(run_dir)
    except (BenchError, FileNotFoundError) as e:  # a run directory that fails a check says which
        fail(str(e))
    if len(log) == 0:
        fail(f"{run_dir}: the trial's log holds no cycle; nothing to export")
    path = write_mcap(log, prep, mcap, _result_of(Path(run_dir)))
    topics = list(TOPICS) + (list(TIMING_TOPICS) if log.timed else [])  # a paced trial's loop timing
    if as_json:
        emit_json({"run_dir": str(run_dir), "mcap": str(path), "messages": len(log), "topics": topics})
    else:
        console.print(f"wrote {path} ({len(log)} cycles; topics {', '.join(topics)})", highlight=False,
                      markup=False)
