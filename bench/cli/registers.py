"""``hilbench registers``: one servo's whole control table as Dynamixel Wizard shows it, read only.

Kept in its own module; ``bench/cli/commands.py`` registers :func:`registers`.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer
from rich.live import Live
from rich.table import Table
from rich.text import Text

from bench.cli.common import console, emit_json, fail, interrupted, signum_of
from bench.cli.lab import CLOCK_OPTION, EMULATE_OPTION, config_rig, load_lab_config
from drivers.errors import ActuatorError

if TYPE_CHECKING:
    from bench.lab.registers import ServoTable

__all__ = ["registers"]


def registers(config: Optional[Path] = typer.Argument(None, help="A config with backend.kind: dynamixel "
                                                                 "(its port and baud); or give --port and --baud."),
              port: Optional[str] = typer.Option(None, "--port", help="Serial port of the servo bus."),
              baud: Optional[int] = typer.Option(None, "--baud", help="Its rate (bps), with --port."),
              sid: int = typer.Option(..., "--id", min=0, max=252, help="The servo's ID."),
              watch: bool = typer.Option(False, "--watch", help="Refresh the RAM area live until Ctrl-C."),
              emulate: bool = EMULATE_OPTION,
              clock: Optional[str] = CLOCK_OPTION,
              as_json: bool = typer.Option(False, "--json", help="Print the table as one JSON line.")) -> None:
    """One servo's control table: name, address, size, access, raw value, value in SI and unit.

    Reads only; nothing is written to the servo.
    """
    from bench.lab.registers import read_table, watch_table  # deferred: --help and completion stay fast
    from drivers.dynamixel.bus import ServoBus  # deferred: --help and completion stay fast

    if (config is None) == (port is None):
        fail("give a CONFIG, or --port PORT --baud B (one of the two)")
    if port is not None and baud is None:
        fail("--port needs --baud (the bus's rate in bps)")
    if config is None and emulate:
        fail("--emulate goes with a CONFIG (its emulated rig)")
    if watch and as_json:
        fail("--watch shows a live table; --json prints one reading (use one of the two)")
    cfg = load_lab_config(config, "registers") if config is not None else None
    try:
        with config_rig(config, cfg, emulate, clock) if cfg is not None else contextlib.nullcontext() as rig_cfg:
            where = (rig_cfg.backend.port, rig_cfg.backend.baud) if rig_cfg is not None else (port, baud)
            with ServoBus(*where) as bus:
                if not watch:
                    table = read_table(bus, sid)
                    if as_json:
                        emit_json(table.as_dict())
                    else:
                        console.print(_render(table))
                    return
                with Live(console=console, auto_refresh=False) as live:
                    for table in watch_table(bus, sid):
                        live.update(_render(table, live=True), refresh=True)
    except KeyboardInterrupt as e:
        if not watch:
            interrupted(signum_of(e), "registers stopped; nothing was written to the servo")
    except ActuatorError as e:
        fail(f"{e}; nothing was written to the servo")


def _render(table: "ServoTable", live: bool = False) -> Table:
    t = Table(title=f"servo ID {table.id}: {table.model}" + (" (RAM refreshed live; Ctrl-C to stop)" if live else ""),
              title_justify="left")
    for col, justify in (("name", "left"), ("address", "right"), ("size", "right"), ("access", "left"),
                         ("raw", "right"), ("value", "right"), ("unit", "left")):
        t.add_column(col, justify=justify)
    for r in table.registers:
        value = "" if r.value is None else f"{r.value:.6g}"
        t.add_row(Text(r.name), str(r.address), str(r.size), r.access, str(r.raw), value, Text(r.unit))
    return t
