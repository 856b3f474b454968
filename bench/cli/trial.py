"""``hilbench check | trial | emulate | report``: one trial, from the check before moving to its
report (the list of past runs: ``bench.cli.runs``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from bench.cli.common import (CAPTURE_HELP, CLOCK_HELP, checked_clock, console, emit_json, err_console, fail,
                               load_config, say, stopped, styled, wire_capture)
from bench.cli.live import LIVE_HELP, LIVE_WAIT_HELP, LIVE_WAIT_S, live_view
from bench.cli.monitor import MONITOR_HELP, monitor_line, with_monitor
from bench.core.interrupts import NO_SIGNALS, SignalGuard, TrialInterrupted
from drivers.errors import (
    ActuatorError,
    ConfigError,
    ExitCode,
    TrialError,
    safe_stop_unconfirmed,
    signal_exit_code,
)

__all__ = ["check", "emulate", "report", "trial"]


# ---------------------------------------------------------------------------
# Trials
# ---------------------------------------------------------------------------


def check(config: Path = typer.Argument(..., help="A trial config to check."),
          emulate: bool = typer.Option(False, "--emulate", help="Do not check the configured serial ports (the emulated rig brings its own)."),
          clock: Optional[str] = typer.Option(None, "--clock", metavar="realtime|virtual", help=CLOCK_HELP),
          as_json: bool = typer.Option(False, "--json", help="Print the checks as one JSON line.")) -> None:
    """Check a config as a trial would before moving, without moving anything.

    Schema and bounds, target reachability and needle direction, plan length,
    the trial's interlocks along the planned path, and the serial ports of a real
    backend. Exit 0 when a trial would start, 2 when it would be refused.
    """
    from bench.trial.check import check_config  # deferred: --help and completion stay fast

    checked_clock(emulate, clock)  # the rig brings its own ports on either clock: nothing else to check

    results = check_config(config, emulate=emulate)
    ok = all(r.ok for r in results)
    failed = next((r for r in results if not r.ok), None)
    if as_json:
        emit_json({"config": str(config), "ok": ok,
                   "checks": [{"name": r.name, "ok": r.ok, "detail": r.detail} for r in results],
                   "reason": failed.detail if failed else ""})
    else:
        for r in results:
            mark = "[green]ok[/]  " if r.ok else "[red]FAIL[/]"
            console.print(styled(mark + " {}: {}", r.name, r.detail), highlight=False)
        passed = sum(r.ok for r in results)
        ports = "; the serial ports not checked (--emulate brings its own)" if emulate else ""
        console.print(f"{passed} of {len(results)} checks passed{ports}", highlight=False)
    if failed is not None:
        fail(failed.detail if as_json else f"a trial would be refused ({failed.name}, above)")


def trial(config: Path = typer.Argument(..., help="A trial config, e.g. hil_configs/sim_target1.yaml."),
          out: Path = typer.Option(Path("runs"), "--out", help="Directory for the run directory."),
          gui: bool = typer.Option(False, "--gui", help="Show the PyBullet window (sim backend)."),
          note: str = typer.Option("", "--note", help="Operator note stored in the trial record."),
          emulate: bool = typer.Option(False, "--emulate", help="Run the real backend against the emulated servo bus and sensor."),
          clock: Optional[str] = typer.Option(None, "--clock", metavar="realtime|virtual", help=CLOCK_HELP),
          live: bool = typer.Option(False, "--live", help=LIVE_HELP),
          live_wait: float = typer.Option(LIVE_WAIT_S, "--live-wait", min=0, help=LIVE_WAIT_HELP),
          monitor: Optional[str] = typer.Option(None, "--monitor", metavar="MODEL", help=MONITOR_HELP),
          capture: Optional[Path] = typer.Option(None, "--capture", metavar="FILE", help=CAPTURE_HELP),
          as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Run one trial: home -> Target -> insertion -> retract, with its log and report.

    Exit codes: 0 passed, 1 ran and failed, 2 refused before anything moved, 3 the safe
    stop was not confirmed (check the rig), 128 + N when stopped by signal N (130 Ctrl-C,
    143 SIGTERM, 129 SIGHUP).
    """
    if gui and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                         or os.environ.get("WAYLAND_DISPLAY")):
        fail("--gui needs a display and DISPLAY is not set; run without --gui (the report has "
             "the pictures) or under xvfb-run")
    clock = checked_clock(emulate, clock)
    with SignalGuard() as guard:  # first, so no signal can land before it
        try:
            res, name, live_url = _trial(config, out, gui, note, emulate, guard, live, live_wait, monitor,
                                         clock, capture)
        except TrialInterrupted as e:
            _interrupted(e, as_json)
    if not res.stop_confirmed:
        say("[bold red]check the rig:[/] {}", res.why_not)
    elif not res.passed:
        say("[bold red]trial failed:[/] {}", res.why_not)
    if res.timing.late:
        say("[bold yellow]warning:[/] {}", res.timing.verdict_note())
    if as_json:
        emit_json(res.summary() | ({"live_url": live_url} if live_url else {}))
    else:
        o = res.outcome
        verdict = "[green]PASSED[/]" if res.passed else "[red]FAILED[/]"
        late = res.timing.verdict_note()  # a loop that did not keep time says so in the verdict
        console.print(styled("trial {}: " + verdict + ("; [bold yellow]{}[/]" if late else "{}") + "  ({})",
                             name, late, res.run_dir), soft_wrap=True)
        if not res.completed:
            console.print(styled("[red]stopped early:[/] {}", res.reason))
        if o is not None:  # short lines: an 80-column terminal never splits a value from its name
            x, y, z = (round(v, 3) + 0.0 for v in o.tip_deviation_mm)
            console.print(f"tip deviation: X {x:+.3f}  Y {y:+.3f}  Z {z:+.3f} mm", highlight=False)
            console.print(f"depth {round(o.depth_deviation_mm, 3) + 0.0:+.3f} mm, angle "
                          f"{round(o.angle_deviation_deg, 4) + 0.0:+.4f}°", highlight=False)
        if res.requirements:
            console.print(requirements_line(res), highlight=False, soft_wrap=True)
        console.print(res.timing.summary_line(), highlight=False, soft_wrap=True)
        if res.monitor is not None:
            console.print(monitor_line(res.monitor), highlight=False, soft_wrap=True)
        console.print(f"report: {res.run_dir / 'report.html'}")
    raise typer.Exit(ExitCode.STOP_UNCONFIRMED if not res.stop_confirmed
                     else ExitCode.PASSED if res.passed else ExitCode.FAILED)


def requirements_line(res) -> str:
    """Each requirement's robustness, e.g. "requirements (true placement): tip +4.91, ... gantry +94.0"."""
    from bench.core.result import PLACEMENT_BASES  # deferred: --help and completion stay fast

    fmt = lambda v: "none" if v is None else f"{v:+.3f}"  # noqa: E731
    parts = [f"{r['name']} {fmt(r['robustness'])}{'' if r['holds'] else ' FAILS'}" for r in res.requirements]
    basis = PLACEMENT_BASES.get(res.basis, "readings")
    return f"requirements ({basis}; robustness in mm or °): " + ", ".join(parts)


def _trial(config: Path, out: Path, gui: bool, note: str, emulate: bool, guard, live: bool = False,
           live_wait: float = 0.0, monitor: Optional[str] = None, clock: Optional[str] = None,
           capture: Optional[Path] = None):
    from bench.trial.plan import prepare  # deferred: --help and completion stay fast

    cfg = with_monitor(load_config(config), monitor)
    guard.check()
    if emulate and cfg.backend.kind != "dynamixel":
        fail(f"{config}: --emulate needs backend.kind: dynamixel (this config is {cfg.backend.kind})")
    if capture is not None and cfg.backend.kind != "dynamixel":
        fail(f"{config}: --capture records a serial bus; this config's backend is {cfg.backend.kind}, "
             f"which has none")
    try:
        prep = prepare(cfg)  # once; nothing starts for a trial that cannot run
    except TrialError as e:
        fail(str(e))
    guard.check()
    rig = None
    if emulate:
        from bench.rig.emulated import open_emulated_rig  # deferred: --help and completion stay fast

        try:
            rig = open_emulated_rig(config, cfg, clock)
        except RuntimeError as e:
            fail(str(e))
        prep = prep.with_config(rig.retarget(cfg))
    try:  # the backend builder attaches the emulated bus's fault hooks (bench.rig.serving)
        with live_view(live, config, out, guard, live_wait) as server:
            try:
                with wire_capture(capture):
                    res = _run_with_progress(prep, out, gui, note, guard)
            except KeyboardInterrupt as e:
                e.live_url = server.url if server else None
                raise
        return res, cfg.name, server.url if server else None
    finally:
        if rig is not None:
            rig.close()
            skipped = rig.stats.get("physics_skipped_s", 0.0)
            if skipped:
                say("warning: the emulated rig's physics fell behind real time and skipped {} s; "
                    "the machine was too busy for a faithful rehearsal", f"{skipped:.2f}")


def _interrupted(e, as_json: bool = False) -> None:
    """One line on stderr for a trial stopped by a signal (and with ``--json`` the result line
    saying so), then exit 128 + N, or 3 when the safe stop was not confirmed."""
    run_dir = getattr(e, "run_dir", None)
    stop = getattr(e, "safe_stop", None)
    where = f"log saved in {run_dir}" if run_dir else "nothing had moved; no log"
    what = f"; {stop}" if stop else ""
    unconfirmed = safe_stop_unconfirmed(stop)
    code = ExitCode.STOP_UNCONFIRMED if unconfirmed else signal_exit_code(e.signum)
    said = str(e)  # "interrupted by SIGINT", and who asked when it was not a signal from outside
    reason = said + (f"; {stop}" if unconfirmed else "")
    if as_json:
        live_url = getattr(e, "live_url", None)
        emit_json({"run_dir": str(run_dir) if run_dir else None, "passed": False, "completed": False,
                   "reason": reason, "safe_stop": stop, "exit_code": int(code)}
                  | ({"live_url": live_url} if live_url else {}))
    if unconfirmed:
        fail(f"{said}: trial stopped{what}; {where}", code)
    say("[bold red]{}:[/] trial stopped{}; {}", said, what, where)
    stopped(e.signum)


def _run_with_progress(prep, out: Path, gui: bool, note: str, guard=None):

    from bench.trial.run import TrialHooks, run_trial  # deferred: --help and completion stay fast

    cfg = prep.config
    with Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"),
                  TimeRemainingColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task(f"trial {cfg.name}: checking", total=None)

        def on_phase(what: str) -> None:
            moving = what not in ("connecting", "planning", "report")  # a segment of the plan
            bar.update(task, description=f"trial {cfg.name}: {what}",
                       total=1.0 if moving else None)

        try:
            return run_trial(prep, out, TrialHooks(
                note=note, gui=gui, progress=lambda f: bar.update(task, completed=f),
                interrupts=guard or NO_SIGNALS, phase=on_phase))
        except (TrialError, ConfigError, ActuatorError) as e:
            fail(str(e))


def emulate(config: Path = typer.Argument(..., help="A config with backend.kind: dynamixel."),
            as_json: bool = typer.Option(False, "--json", help="Print the ports as one JSON line.")) -> None:
    """Serve the emulated servo bus and ultrasonic sensor of a config until Ctrl-C or SIGTERM."""
    from bench.rig.emulated import serve  # deferred: --help and completion stay fast

    cfg = load_config(config)
    if cfg.backend.kind != "dynamixel":
        fail(f"{config}: backend.kind must be dynamixel to emulate its rig")

    def announce(ports) -> None:
        if as_json:
            emit_json({"dynamixel_port": ports.dynamixel_port, "ultrasonic_port": ports.ultrasonic_port})
        else:
            console.print(styled("Dynamixel bus on [bold]{}[/], ultrasonic sensor on [bold]{}[/]; "
                                 "Ctrl-C to stop", ports.dynamixel_port, ports.ultrasonic_port))

    def report(stats: dict) -> None:
        if as_json:
            emit_json({"stats": stats})
        elif stats.get("physics_skipped_s"):
            say("warning: the emulator's physics fell behind real time and skipped {} s (the "
                "machine was too busy)", f"{stats['physics_skipped_s']:.2f}")

    def applied(seq: int, answer: dict) -> None:  # a parent driving faults through our stdin waits for this
        if as_json:
            emit_json({"applied": seq} | answer)

    try:
        serve(cfg, announce, report, applied)
    except (ValueError, RuntimeError) as e:
        fail(str(e))


def report(run_dir: Path = typer.Argument(..., help="A trial's run directory."),
           as_json: bool = typer.Option(False, "--json")) -> None:
    """Rebuild a trial's report (Markdown, HTML, figures) from its record alone."""
    from bench.trial.record import rebuild_report  # deferred: --help and completion stay fast
    from drivers import BenchError  # deferred: --help and completion stay fast

    try:
        res = rebuild_report(run_dir)
    except BenchError as e:  # a run directory that fails a check (bench.core.rundir), or its config
        fail(str(e))
    if as_json:
        emit_json(res.summary())
    else:
        console.print(f"rebuilt {res.run_dir / 'report.md'} and {res.run_dir / 'report.html'}")
