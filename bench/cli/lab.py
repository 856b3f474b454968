"""``hilbench scan | doctor | calibrate | jog``: the lab-rig tools (the library is ``bench/lab/``).

Human output (tables, progress, one line per check or step) goes to stderr;
``--json`` prints one line on stdout. Bad input — an unreadable config, a
config whose backend is not the Dynamixel servos, a port that is not there —
ends with one line and exit code 2 before anything is opened; a rig problem
found while working ends with one line and exit code 1, torque off.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Optional

import typer
from rich import box
from rich.live import Live
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.status import Status
from rich.table import Table
from rich.text import Text

from bench.cli.common import (CLOCK_HELP, checked_clock, emit_json, err_console, fail, interrupted, load_config,
                               say, signum_of, styled)
from drivers.errors import ActuatorError, BackendSetupError, ExitCode, safe_stop_unconfirmed

if TYPE_CHECKING:
    from bench.config.models import TrialConfig

__all__ = ["EMULATE_OPTION", "calibrate", "config_rig", "doctor", "jog", "load_lab_config", "scan"]


_STATUS = {"pass": "[green]PASS[/]", "warn": "[yellow]WARN[/]", "fail": "[bold red]FAIL[/]"}


def load_lab_config(config: Path, tool: str) -> "TrialConfig":
    """The config, or exit 2 with one line (unreadable, or not the Dynamixel backend)."""
    from bench.lab.session import require_dynamixel  # deferred: --help and completion stay fast

    cfg = load_config(config)
    try:
        require_dynamixel(cfg, tool)
    except BackendSetupError as e:
        fail(str(e))
    return cfg


EMULATE_OPTION = typer.Option(False, "--emulate", help="Work on the config's emulated rig "
                                                 "(its own servo bus and sensor) instead of the ports.")


CLOCK_OPTION = typer.Option(None, "--clock", metavar="realtime|virtual", help=CLOCK_HELP)


@contextlib.contextmanager
def config_rig(config: Path, cfg: "TrialConfig", emulate: bool,
               clock: Optional[str] = None) -> Iterator["TrialConfig"]:
    """The config as given, or pointed at an emulated rig (on ``clock``) that lives as long as the block."""
    clock = checked_clock(emulate, clock)
    if not emulate:
        yield cfg
        return
    from bench.rig.emulated import open_emulated_rig  # deferred: --help and completion stay fast

    try:
        rig = open_emulated_rig(config, cfg, clock)
    except RuntimeError as e:
        fail(str(e))
    try:
        yield rig.retarget(cfg)
    finally:
        rig.close()


# ---------------------------------------------------------------------------
# scan
# ---------------------------------------------------------------------------


def scan(port: str = typer.Option(..., "--port", help="Serial port of the servo bus, e.g. /dev/ttyUSB0."),
         baud: Optional[list[int]] = typer.Option(
             None, "--baud", help="A rate to scan (repeat for several); default 57600 and 1000000."),
         all_bauds: bool = typer.Option(False, "--all-bauds",
                                        help="Every X-series rate, 9600 bps to 4.5 Mbps."),
         max_id: int = typer.Option(252, "--max-id", min=0, max=252,
                                    help="Highest ID to wait for (a lower one shortens each ping)."),
         as_json: bool = typer.Option(False, "--json", help="Print one line: a list of servos.")) -> None:
    """Find every servo on a bus: ID, model, firmware, baud, mode, torque, hardware error."""


    from bench.lab.scan import (  # deferred: --help and completion stay fast
        ALL_BAUDS,
        DEFAULT_BAUDS,
        check_bauds,
        scan_bus,
        servo_row,
    )
    from drivers.dynamixel.bus import open_error  # deferred: --help and completion stay fast

    if baud and all_bauds:
        fail("give --baud or --all-bauds, not both")
    try:
        rates = check_bauds(ALL_BAUDS if all_bauds else (baud or DEFAULT_BAUDS))
    except ValueError as e:
        fail(str(e))
    if not os.path.exists(port) or not os.access(port, os.R_OK | os.W_OK):
        fail(f"servo {open_error(port)}")
    progress = Progress(TextColumn("scanning {task.description}"), BarColumn(), MofNCompleteColumn(),
                        console=err_console, transient=True, disable=not err_console.is_terminal)
    try:
        with progress:
            task = progress.add_task(f"{port}", total=len(rates))

            def step(done: int, total: int) -> None:
                nxt = f" at {rates[done]} bps" if done < total else ""
                progress.update(task, completed=done, description=f"{port}{nxt}")

            progress.update(task, description=f"{port} at {rates[0]} bps")
            found = scan_bus(port, rates, max_id, progress=step)
    except ActuatorError as e:
        fail(str(e), ExitCode.FAILED if os.path.exists(port) else ExitCode.REFUSED)
    except KeyboardInterrupt as e:
        interrupted(signum_of(e), "scan stopped; nothing was written to the servos")
    if as_json:
        emit_json([servo_row(s) for s in found])
        return
    t = Table(title=f"{len(found)} servo(s) on {port}", box=box.SIMPLE_HEAD, title_justify="left")
    for col in ("ID", "model", "fw", "baud", "mode", "torque", "error", "V", "°C"):
        t.add_column(col, no_wrap=col != "error")
    for s in found:
        t.add_row(str(s.id), s.model_name, str(s.firmware), str(s.baud), s.operating_mode or "?",
                  "?" if s.torque is None else ("on" if s.torque else "off"),
                  ", ".join(s.hardware_error) or "none",
                  f"{s.voltage_v:.1f}" if s.voltage_v is not None else "?",
                  f"{s.temperature_c:.0f}" if s.temperature_c is not None else "?",
                  style="red" if s.hardware_error else None)
    err_console.print(t)
    err_console.print(f"scanned {', '.join(str(r) for r in rates)} bps, IDs 0–{max_id}", highlight=False)


# ---------------------------------------------------------------------------
# doctor
# ---------------------------------------------------------------------------


def doctor(config: Path = typer.Argument(..., help="A config with backend.kind: dynamixel."),
           listen_s: float = typer.Option(1.0, "--listen", min=0.2,
                                          help="Seconds to listen to the ultrasonic sensor."),
           verbose: bool = typer.Option(False, "--verbose", "-v",
                                        help="Print every check, the passed ones too."),
           emulate: bool = EMULATE_OPTION,
           clock: Optional[str] = CLOCK_OPTION,
           as_json: bool = typer.Option(False, "--json",
                                        help='Print {"checks": [...], "ok": bool} as one line.')) -> None:
    """Check a rig before a trial: ports, latency timer, servos, ultrasonic sensor, calibration.

    Prints the problems as they are found (every check with --verbose), then one
    count line; exit 0 when ready for a trial, 1 when a check failed.
    """

    from bench.lab.doctor import run_doctor  # deferred: --help and completion stay fast

    cfg = load_lab_config(config, "doctor")
    counts = {"pass": 0, "warn": 0, "fail": 0}
    spinner = Status(Text("doctor: checking"), console=err_console) if not as_json else contextlib.nullcontext()

    def show(c) -> None:
        counts[c.status] += 1
        if as_json:
            return
        spinner.update(Text(f"doctor: {sum(counts.values())} checks, last: {c.name}"))
        if verbose or c.status != "pass":
            say(_STATUS[c.status] + "  {}: {}", c.name, c.detail)

    try:
        with config_rig(config, cfg, emulate, clock) as cfg, spinner:
            checks = run_doctor(cfg, listen_s=listen_s, on_check=show)
    except KeyboardInterrupt as e:
        interrupted(signum_of(e), "doctor stopped; nothing was written to the servos")
    except ActuatorError as e:  # the rig itself failed in a way no check could name
        if as_json:
            emit_json({"checks": [], "ok": False, "reason": str(e)})
        fail(f"{e}; nothing was written to the servos", ExitCode.FAILED)
    ok = not any(c.status == "fail" for c in checks)
    failed = [c for c in checks if c.status == "fail"]
    reason = "; ".join(f"{c.name}: {c.detail}" for c in failed)
    if as_json:
        emit_json({"checks": [c.as_dict() for c in checks], "ok": ok, "reason": reason})
        if not ok:
            say("[bold red]not ready:[/] {}", reason)
    else:
        n = {s: sum(c.status == s for c in checks) for s in ("pass", "warn", "fail")}
        verdict = "[green]ready for a trial[/]" if ok else "[bold red]not ready[/]"
        say(verdict + ": {} failed, {} warning(s), {} passed", n["fail"], n["warn"], n["pass"])
    raise typer.Exit(ExitCode.PASSED if ok else ExitCode.FAILED)


# ---------------------------------------------------------------------------
# calibrate
# ---------------------------------------------------------------------------


def calibrate(config: Path = typer.Argument(..., help="A config with backend.kind: dynamixel."),
              stops: int = typer.Option(5, "--stops", min=0,
                                        help="Train stops for the ultrasonic fit (at least 3; 0 skips it)."),
              span_deg: Optional[float] = typer.Option(
                  None, "--span-deg", help="Arc angle the stops cover, centred on the train's travel "
                                           "(default: its central two thirds)."),
              samples: int = typer.Option(25, "--samples", min=1,
                                          help="Ultrasonic readings averaged at each stop."),
              write: str = typer.Option("config", "--write",
                                        help="Where joint zeros go: config (an override in the calibration "
                                             "file) or homing (each servo's Homing Offset register)."),
              out: Optional[Path] = typer.Option(None, "--out", help="Calibration file to write (default: "
                                                 "<config dir>/calibration/<name>-<date>.yaml)."),
              yes: bool = typer.Option(False, "--yes",
                                       help="Do not ask: the robot is already at its reference."),
              accept_large: bool = typer.Option(
                  False, "--accept-large-offsets",
                  help="Write zeros that moved more than 2° (2 mm) from the config's too."),
              emulate: bool = EMULATE_OPTION,
           clock: Optional[str] = CLOCK_OPTION,
              as_json: bool = typer.Option(False, "--json",
                                           help="Print the result as one JSON line.")) -> None:
    """Calibrate joint zero offsets and the ultrasonic sensor; write a dated calibration file."""

    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast
    from bench.lab.calibrate import calibrate as run_calibration  # deferred: --help and completion stay fast
    from bench.lab.session import check_ports  # deferred: --help and completion stay fast

    cfg = load_lab_config(config, "calibrate")
    if write not in ("config", "homing"):
        fail(f"--write must be config or homing, got {write!r}")
    if 0 < stops < 3:
        fail(f"--stops must be 0 (no ultrasonic fit) or at least 3, got {stops}")
    if not yes and not sys.stdin.isatty():
        fail("calibrate asks the technician at each step: run it in a terminal, or pass --yes")
    if not emulate:
        try:
            check_ports(cfg, ultrasonic=stops > 0)
        except ActuatorError as e:
            fail(str(e))

    def confirm(message: str) -> bool:
        if yes:
            return True
        answer = err_console.input(styled("[bold]{}[/] — Enter when ready, s to skip: ", message))
        return answer.strip().lower() not in ("s", "skip")

    def note(message: str) -> None:
        if not as_json:
            err_console.print(message, soft_wrap=True, highlight=False)

    if write == "homing" and not yes and not confirm(
            "--write homing stores the zeros in each servo's Homing Offset (EEPROM, torque off "
            "for the write); the calibration file then holds no joint offsets"):
        fail("calibration cancelled; nothing written", ExitCode.FAILED)
    if out is None and emulate:  # an emulated rig's calibration is not the rig's: keep them apart
        from bench.lab.calibrate import default_output  # deferred: --help and completion stay fast

        default = default_output(cfg)
        out = default.with_name("emulated-" + default.name)
    try:
        with config_rig(config, cfg, emulate, clock) as rig_cfg:
            res = run_calibration(rig_cfg, write=write, stops=stops, samples=samples, out=out,
                                  confirm=confirm, note=note, accept_large=accept_large,
                                  span=math.radians(span_deg) if span_deg is not None else None)
    except KeyboardInterrupt as e:
        interrupted(signum_of(e), "calibration stopped; no calibration file written")
    except (ActuatorError, ValueError) as e:
        fail(f"{e}; no calibration file written", ExitCode.FAILED)
    f = res.file
    if as_json:
        emit_json({"file": str(res.path), "write": write,
               "joints": {j: {"offset": z.offset, "change": z.change} for j, z in res.zeros.items()},
               "homing_offsets": f.homing_offsets, "refused": res.refused,
               "ultrasonic": None if f.ultrasonic is None else {
                   "offset_mm": f.ultrasonic.offset_mm, "scale": f.ultrasonic.scale,
                   "residual_mm": f.ultrasonic.residual_mm}})
        return
    robot = get_robot(cfg.robot)
    where = "Homing Offset registers" if write == "homing" else "config override"
    t = Table(title=f"joint zero offsets ({where})")
    for col in ("joint", "configured", "measured", "change"):
        t.add_column(col, justify="right")
    for j, z in res.measured.items():
        rev = robot.chain.rows[robot.joint_names.index(j)].kind == "revolute"

        def fmt(v: float, sign: str = "") -> str:
            return f"{math.degrees(v):{sign}.3f}°" if rev else f"{v * 1e3:{sign}.3f} mm"

        t.add_row(j, fmt(z.configured), fmt(z.offset),
                  Text.assemble(fmt(z.change, "+"), (" (not written)", "yellow") if j in res.refused else ""))
    err_console.print(t)
    if f.ultrasonic is not None:
        err_console.print(f"ultrasonic: reading = {f.ultrasonic.offset_mm:.2f} mm + {f.ultrasonic.scale:.5f} · d2 "
                  f"(config standoff {cfg.backend.ultrasonic.standoff_mm:.1f} mm), residual "
                  f"{f.ultrasonic.residual_mm:.2f} mm RMS over {len(f.ultrasonic.stops)} stops")
    for joint, why in res.refused.items():
        say("[yellow]warning:[/] {}: zero not written: {}", joint, why)
    say("calibration written: [bold]{}[/]; use it with `calibration: {}` in {}", res.path, res.path, config)


# ---------------------------------------------------------------------------
# jog
# ---------------------------------------------------------------------------


def jog(config: Path = typer.Argument(..., help="A config with backend.kind: dynamixel."),
        emulate: bool = EMULATE_OPTION,
        clock: Optional[str] = CLOCK_OPTION) -> None:
    """Move one joint at a time in small steps within limits (keys: 1-9, +/-, s, q); torque off on exit."""

    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast
    from bench.lab.jog import RawKeys, jog_view, run_jog  # deferred: --help and completion stay fast
    from bench.lab.session import check_ports, open_backend  # deferred: --help and completion stay fast

    cfg = load_lab_config(config, "jog")
    if checked_clock(emulate, clock) == "virtual":
        fail("jog moves the rig as keys are pressed, at the rig's pace: it keeps real time "
             "(drop --clock virtual)")
    if not (sys.stdin.isatty() and sys.stderr.isatty()):
        fail("jog reads keys from a terminal: stdin and stderr must be a TTY "
              "(not a pipe, a file or a script)")
    if not emulate:
        try:
            check_ports(cfg)
        except ActuatorError as e:
            fail(str(e))
    robot = get_robot(cfg.robot)
    revolute = [row.kind == "revolute" for row in robot.chain.rows]
    reason = "error"
    act = None
    try:
        with config_rig(config, cfg, emulate, clock) as cfg, \
                open_backend(cfg) as act:  # torque off when this block is left, however it is left
            act.enable()
            with RawKeys(sys.stdin.fileno()) as keys, \
                    Live(console=err_console, auto_refresh=False, transient=False) as live:
                reason = run_jog(act, keys, lambda s, st: live.update(jog_view(s, st, f"jog {cfg.name}"),
                                                                        refresh=True), revolute)
    except KeyboardInterrupt as e:
        _unconfirmed_stop(act, "jog stopped")
        interrupted(signum_of(e), "jog stopped; torque off")
    except ActuatorError as e:
        _unconfirmed_stop(act, str(e))
        fail(f"{e}; torque off", ExitCode.FAILED)
    _unconfirmed_stop(act, f"jog ended ({reason})")
    err_console.print(f"jog ended ({reason}): torque off on every servo", highlight=False)


def _unconfirmed_stop(act, what: str) -> None:
    """One line and exit 3 when the servos did not all read back torque off."""
    report = getattr(act, "safe_stop_report", None)
    if safe_stop_unconfirmed(report):
        fail(f"{what}; {report}", ExitCode.STOP_UNCONFIRMED)
