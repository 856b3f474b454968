"""``hilbench stand``: a test-stand config's excitation recorded as BAM-format logs.

Kept in its own module; ``bench/cli/app.py`` registers :func:`stand`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from bench.cli.common import console, emit_json, fail
from drivers.errors import ExitCode

__all__ = ["stand"]

STAND_CLOCK_HELP = ("The emulated stand's clock, with --emulate: stepped (the default: the physics advances a "
                    "period between the recorder's transactions, the bus a pseudo-terminal) or virtual (the bus a "
                    "virtual line, the wire's time on the same clock: the same logs bit for bit on any machine).")


def stand(config: Path = typer.Argument(..., metavar="CONFIG", help="A test-stand config "
                                                                   "(hil_configs/stand/test_stand_xl330.yaml)."),
          out: Path = typer.Option(Path("runs"), "--out", help="Where the run directory goes."),
          emulate: bool = typer.Option(False, "--emulate", help="Record the config's emulated stand instead."),
          serve: bool = typer.Option(False, "--serve", help="Only serve the emulated stand on a pseudo-terminal "
                                                             "(real time) until Ctrl-C, for another recorder."),
          clock: Optional[str] = typer.Option(None, "--clock", metavar="stepped|virtual", help=STAND_CLOCK_HELP),
          as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Run a test stand's excitation (BAM's trajectories) and write its logs in BAM's format.

    At the config's P gains, one log per run, for `hilbench identify` and `hilbench predict`."""
    from bench.config.base import ConfigError  # deferred: --help and completion stay fast
    from bench.stand.config import load_stand_config  # deferred: --help and completion stay fast
    from bench.stand.session import record_session, serve_stand  # deferred: --help and completion stay fast
    from drivers import BenchError  # deferred: --help and completion stay fast

    if clock is not None and clock not in ("stepped", "virtual"):
        fail(f"--clock {clock}: choose stepped or virtual")
    if clock is not None and not emulate:
        fail(f"--clock {clock} sets the emulated stand's clock: add --emulate (a real stand keeps the wall clock)")
    try:
        cfg = load_stand_config(config)
    except ConfigError as e:
        fail(str(e))
    if serve:
        serve_stand(cfg, lambda port: console.print(f"emulated stand on {port} at {cfg.baud} bps, servo ID {cfg.servo_id} "
                                                    "(Ctrl-C to stop)", highlight=False))
        return
    try:
        run_dir, logs = record_session(cfg, out, emulate=emulate, clock=clock)
    except BenchError as e:
        fail(str(e), ExitCode.FAILED)
    if as_json:
        emit_json({"run_dir": str(run_dir), "logs": [str(p) for p in logs]})
        return
    for p in logs:
        console.print(f"wrote {p}", highlight=False)
    console.print(f"identify with: hilbench identify {run_dir} --out {run_dir / 'stand_model.yaml'}",
                  highlight=False)
