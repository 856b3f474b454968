"""``hilbench``: the command-line face of the bench (a thin layer over the library).

Every command that prints numbers accepts ``--json`` for scripts: lengths in
mm and angles in degrees, joint values in SI (rad, m). Bad input ends with one
line on stderr and exit code 2, before anything moves.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from bench.cli.common import console, emit_json, err_console, fail
from rich.table import Table

app = typer.Typer(no_args_is_help=True,
                  help="Hardware-in-the-loop test bench for CT-guided needle-placement robots.")
urdf_app = typer.Typer(no_args_is_help=True, help="Generate or check the URDF scene files.")
app.add_typer(urdf_app, name="urdf")







def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            v = version("needle-hil-bench")
        except PackageNotFoundError:  # run from a source tree that was never installed
            v = "unknown"
        console.print(f"hilbench {v}", highlight=False)
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Hardware-in-the-loop test bench for CT-guided needle-placement robots."""


def _robot(name: str):
    from bench.kinematics.registry import get_robot

    try:
        return get_robot(name)
    except KeyError as e:
        fail(str(e.args[0]))


def _mm(v) -> list[float]:
    return [round(float(x) * 1e3, 6) + 0.0 for x in v]


# ---------------------------------------------------------------------------
# Kinematics
# ---------------------------------------------------------------------------


@app.command()
def robot(name: str = typer.Argument(..., help="arc-train"),
          as_json: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
    """List a robot's joints: type, limits and home (SI units)."""
    r = _robot(name)
    joints = [{"name": row.name, "type": row.kind, "lower": row.lower, "upper": row.upper,
               "home": row.home} for row in r.chain.rows]
    if as_json:
        emit_json({"robot": name, "joints": joints})
        return
    t = Table(title=f"{name} joints (rad or m)")
    for col in ("name", "type", "lower", "upper", "home"):
        t.add_column(col)
    for j in joints:
        t.add_row(j["name"], j["type"], f"{j['lower']:.4f}", f"{j['upper']:.4f}", f"{j['home']:.4f}")
    console.print(t)


def _needle_json(pose) -> dict:
    return {"entry_mm": _mm(pose.entry), "tip_mm": _mm(pose.tip),
            "angle_deg": round(float(np.degrees(pose.angle)), 9),
            "depth_mm": round(pose.depth * 1e3, 9)}


@app.command()
def fk(name: str = typer.Argument(..., help="arc-train"),
       joints: str = typer.Option("{}", "--joints", help='JSON object {"joint": value}; missing joints take home.'),
       as_json: bool = typer.Option(False, "--json")) -> None:
    """Forward kinematics to the needle: entry point, tip, insertion angle and depth."""
    r = _robot(name)
    try:
        values = json.loads(joints)
        if not isinstance(values, dict):
            raise ValueError("--joints must be a JSON object")
        q = r.joint_vector(values)
    except (ValueError, KeyError, TypeError) as e:
        fail(f"--joints: {e.args[0] if e.args else e}")
    lo, hi = r.chain.lower, r.chain.upper
    outside = [f"{n}={v:.4g} not in [{a:.4g}, {b:.4g}]"
               for n, v, a, b in zip(r.joint_names, q, lo, hi) if not a - 1e-12 <= v <= b + 1e-12]
    if outside:
        fail("joint values outside limits: " + "; ".join(outside))
    out = _needle_json(r.needle(q))
    if as_json:
        emit_json(out)
        return
    for k, v in out.items():
        console.print(f"{k:>10}: {v}")


@app.command()
def ik(name: str = typer.Argument(..., help="arc-train"),
       x_mm: float = typer.Option(..., "--x-mm"), y_mm: float = typer.Option(..., "--y-mm"),
       z_mm: float = typer.Option(..., "--z-mm"),
       depth_mm: float = typer.Option(..., "--depth-mm", help="Insertion depth beyond the entry point."),
       angle_deg: float = typer.Option(..., "--angle-deg", help="From the downward vertical towards +Y."),
       tilt_deg: float = typer.Option(0.0, "--tilt-deg", help="Out of the axial plane, towards +X."),
       render: Optional[Path] = typer.Option(None, "--render", help="Also write a PNG of the robot at the solution."),
       as_json: bool = typer.Option(False, "--json")) -> None:
    """Inverse kinematics to a needle target (entry point, depth, angle)."""
    from bench.kinematics.arc_train import NeedleTarget, UnreachableError

    r = _robot(name)
    target = NeedleTarget(np.array([x_mm, y_mm, z_mm]) * 1e-3, depth_mm * 1e-3, np.radians(angle_deg),
                          np.radians(tilt_deg))
    try:
        q = r.ik(target)
    except UnreachableError as e:
        fail(str(e))
    pose = r.needle(q)
    out = {"joints": {n: float(v) for n, v in zip(r.joint_names, q)}, **_needle_json(pose)}
    if render is not None:
        from bench.scene.render import render_robot

        render_robot(name, q, render)
        out["render"] = str(render)
    if as_json:
        emit_json(out)
        return
    t = Table(title=f"{name}: joints for the target")
    t.add_column("joint")
    t.add_column("value (rad or m)")
    t.add_column("deg or mm")
    for n, v, row in zip(r.joint_names, q, r.chain.rows):
        t.add_row(n, f"{v:.6f}", f"{np.degrees(v):.3f}°" if row.kind == "revolute" else f"{v * 1e3:.3f} mm")
    console.print(t)
    console.print(f"tip at {out['tip_mm']} mm, angle {out['angle_deg']:.4f}°")
    if render is not None:
        console.print(f"picture: {render}")


# ---------------------------------------------------------------------------
# Trials
# ---------------------------------------------------------------------------


@app.command()
def check(config: Path = typer.Argument(..., help="A trial config to check."),
          emulate: bool = typer.Option(False, "--emulate", help="Do not check the configured serial ports (the emulated rig brings its own)."),
          as_json: bool = typer.Option(False, "--json", help="Print the checks as one JSON line.")) -> None:
    """Check a config as a trial would before moving, without moving anything.

    Schema and bounds, target reachability and needle direction, plan length,
    the trial's interlocks along the planned path, and the serial ports of a real
    backend. Exit 0 when a trial would start, 2 when it would be refused.
    """
    from bench.trial.preflight import check_config

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
            console.print(f"{mark} {r.name}: {r.detail}", highlight=False, soft_wrap=True)
    if failed is not None:
        line = failed.detail if as_json else f"a trial would be refused ({failed.name}, above)"
        err_console.print(f"[bold red]error:[/] {line}", highlight=False, soft_wrap=True)
        raise typer.Exit(2)


@app.command()
def trial(config: Path = typer.Argument(..., help="A trial config, e.g. hil_configs/sim_target1.yaml."),
          out: Path = typer.Option(Path("runs"), "--out", help="Directory for the run directory."),
          gui: bool = typer.Option(False, "--gui", help="Show the PyBullet window (sim backend)."),
          note: str = typer.Option("", "--note", help="Operator note stored in the trial record."),
          emulate: bool = typer.Option(False, "--emulate", help="Run the real backend against the emulated servo bus and sensor."),
          as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Run one trial: home -> Target -> insertion -> retract, with its log and report.

    Exit codes: 0 passed, 1 ran and failed, 2 refused before anything moved,
    128 + N when stopped by signal N (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP).
    """
    from bench.core.interrupts import SignalGuard, TrialInterrupted

    if gui and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                         or os.environ.get("WAYLAND_DISPLAY")):
        fail("--gui needs a display and DISPLAY is not set; run without --gui (the report has "
             "the pictures) or under xvfb-run")
    with SignalGuard() as guard:  # first, so no signal can land before it
        try:
            res, name = _trial(config, out, gui, note, emulate, guard)
        except TrialInterrupted as e:
            _interrupted(e)
    if not res.passed:
        err_console.print(f"[bold red]trial failed:[/] {res.why_not}", highlight=False, soft_wrap=True)
    if as_json:
        emit_json(res.summary())
    else:
        o = res.outcome
        verdict = "[green]PASSED[/]" if res.passed else "[red]FAILED[/]"
        console.print(f"trial {name}: {verdict}  ({res.run_dir})")
        if not res.completed:
            console.print(f"[red]stopped early:[/] {res.reason}")
        if o is not None:  # short lines: an 80-column terminal never splits a value from its name
            x, y, z = (round(v, 3) + 0.0 for v in o.tip_deviation_mm)
            console.print(f"tip deviation: X {x:+.3f}  Y {y:+.3f}  Z {z:+.3f} mm", highlight=False)
            console.print(f"depth {round(o.depth_deviation_mm, 3) + 0.0:+.3f} mm, angle "
                          f"{round(o.angle_deviation_deg, 4) + 0.0:+.4f}°", highlight=False)
        console.print(f"report: {res.run_dir / 'report.html'}")
    raise typer.Exit(0 if res.passed else 1)


def _trial(config: Path, out: Path, gui: bool, note: str, emulate: bool, guard):
    from bench.config.models import ConfigError, load_trial_config
    from bench.trial.run import TrialError

    try:
        cfg = load_trial_config(config)
    except ConfigError as e:
        fail(str(e))
    guard.check()
    rig = None
    if emulate:
        from bench.rig.emulated import EmulatorProcess
        from bench.trial.run import prepare

        if cfg.backend.kind != "dynamixel":
            fail(f"{config}: --emulate needs backend.kind: dynamixel (this config is {cfg.backend.kind})")
        try:
            prepare(cfg)  # nothing starts for a trial that cannot run
            rig = EmulatorProcess(config)
        except (TrialError, RuntimeError) as e:
            fail(str(e))
        cfg = rig.retarget(cfg)
    factory = None
    if rig is not None:
        from bench.trial.run import make_backend

        def factory(prep):  # bus-level faults reach the emulator through the backend's hooks
            backend = make_backend(prep)
            backend.fault_hooks = rig.faults
            return backend
    try:
        return _run_with_progress(cfg, out, gui, note, factory, guard), cfg.name
    finally:
        if rig is not None:
            rig.close()
            skipped = rig.stats.get("physics_skipped_s", 0.0)
            if skipped:
                err_console.print(f"warning: the emulated rig's physics fell behind real time and "
                                  f"skipped {skipped:.2f} s; the machine was too busy for a faithful "
                                  f"rehearsal", highlight=False, soft_wrap=True)


def _interrupted(e) -> None:
    """One line on stderr for a trial stopped by a signal, then exit 128 + N."""
    from bench.core.interrupts import signal_name

    run_dir = getattr(e, "run_dir", None)
    stop = getattr(e, "safe_stop", None)
    where = f"log saved in {run_dir}" if run_dir else "nothing had moved; no log"
    what = f"; {stop}" if stop else ""
    err_console.print(f"[bold red]interrupted by {signal_name(e.signum)}:[/] trial stopped{what}; "
                      f"{where}", highlight=False, soft_wrap=True)
    raise typer.Exit(e.exit_code)


def _run_with_progress(cfg, out: Path, gui: bool, note: str, backend_factory=None, guard=None):
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from bench.config.models import ConfigError
    from bench.core.interrupts import NO_SIGNALS
    from bench.trial.run import TrialError, run_trial
    from drivers import ActuatorError

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeRemainingColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task(f"trial {cfg.name}: checking", total=None)

        def on_phase(what: str) -> None:
            moving = what not in ("connecting", "planning", "report")  # a segment of the plan
            bar.update(task, description=f"trial {cfg.name}: {what}",
                       total=1.0 if moving else None)

        try:
            return run_trial(cfg, out, gui=gui, note=note, backend_factory=backend_factory,
                             progress=lambda f: bar.update(task, completed=f),
                             interrupts=guard or NO_SIGNALS, phase=on_phase)
        except (TrialError, ConfigError, ActuatorError) as e:
            fail(str(e))


@app.command()
def emulate(config: Path = typer.Argument(..., help="A config with backend.kind: dynamixel."),
            as_json: bool = typer.Option(False, "--json", help="Print the ports as one JSON line.")) -> None:
    """Serve the emulated servo bus and ultrasonic sensor of a config until Ctrl-C or SIGTERM."""
    from bench.config.models import ConfigError, load_trial_config
    from bench.rig.emulated import serve

    try:
        cfg = load_trial_config(config)
    except ConfigError as e:
        fail(str(e))
    if cfg.backend.kind != "dynamixel":
        fail(f"{config}: backend.kind must be dynamixel to emulate its rig")

    def announce(ports) -> None:
        if as_json:
            emit_json({"dynamixel_port": ports.dynamixel_port, "ultrasonic_port": ports.ultrasonic_port})
        else:
            console.print(f"Dynamixel bus on [bold]{ports.dynamixel_port}[/], ultrasonic sensor on "
                          f"[bold]{ports.ultrasonic_port}[/]; Ctrl-C to stop")

    def report(stats: dict) -> None:
        if as_json:
            emit_json({"stats": stats})
        elif stats.get("physics_skipped_s"):
            err_console.print(f"warning: the emulator's physics fell behind real time and skipped "
                              f"{stats['physics_skipped_s']:.2f} s (the machine was too busy)")

    try:
        serve(cfg, announce, report)
    except (ValueError, RuntimeError) as e:
        fail(str(e))


@app.command()
def report(run_dir: Path = typer.Argument(..., help="A trial's run directory."),
           as_json: bool = typer.Option(False, "--json")) -> None:
    """Rebuild a trial's report (Markdown, HTML, figures) from its record alone."""
    from bench.trial.run import TrialError, rebuild_report

    try:
        res = rebuild_report(run_dir)
    except (TrialError, FileNotFoundError) as e:
        fail(str(e))
    if as_json:
        emit_json(res.summary())
    else:
        console.print(f"rebuilt {res.run_dir / 'report.md'} and {res.run_dir / 'report.html'}")


@app.command()
def runs(out: Path = typer.Option(Path("runs"), "--out", help="The directory trials wrote into."),
         as_json: bool = typer.Option(False, "--json", help="Print the runs as one JSON line.")) -> None:
    """List past trials: date, config, verdict, deviations and report, oldest first."""
    from bench.trial.runs import list_runs

    found = list_runs(out)
    if as_json:
        emit_json({"out": str(out), "runs": [r.as_dict() for r in found]})
        return
    if not found:
        console.print(f"no trial runs in {out}", highlight=False)
        return
    colour = {"passed": "green", "failed": "red", "stopped": "red", "incomplete": "yellow"}
    t = Table(title=f"trials in {out}", title_justify="left")
    t.add_column("run (started, config)", no_wrap=True)
    t.add_column("backend", no_wrap=True)
    t.add_column("verdict", no_wrap=True)
    t.add_column("tip mm", justify="right", no_wrap=True)
    t.add_column("angle °", justify="right", no_wrap=True)
    for r in found:
        tip = "" if r.tip_deviation_mm is None else f"{r.tip_deviation_mm:.2f}"
        angle = "" if r.angle_deviation_deg is None else f"{r.angle_deviation_deg:+.3f}"
        t.add_row(Path(r.run_dir).name, r.backend or "?", f"[{colour[r.status]}]{r.status}[/]",
                  tip, angle)
    console.print(t)
    for r in found:
        if r.reason:
            console.print(f"{Path(r.run_dir).name}: {r.reason}", highlight=False, soft_wrap=True)
    console.print(f"{len(found)} runs; reports: {out}/RUN/report.html", highlight=False)


@app.command()
def schema(markdown: bool = typer.Option(False, "--markdown", help="The field reference (docs/config.md) instead."),
           out: Optional[Path] = typer.Option(None, "--out", help="Write to this file instead of stdout.")) -> None:
    """The trial config's JSON Schema, generated from the models (or its Markdown reference)."""
    from bench.config.reference import json_schema, markdown_reference

    text = markdown_reference() if markdown else json.dumps(json_schema(), indent=2) + "\n"
    if out is None:
        sys.stdout.write(text)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    err_console.print(f"wrote {out}", highlight=False)


@urdf_app.command("build")
def urdf_build(check: bool = typer.Option(False, "--check", help="Fail if the files differ instead of writing.")) -> None:
    """Write urdf/ from the parameter sets in bench/kinematics and bench/scene/room.py."""
    from bench.scene.room import URDF_DIR, generated_files, write_scene

    if check:
        stale = [rel for rel, text in generated_files().items()
                 if not (URDF_DIR / rel).exists() or (URDF_DIR / rel).read_text() != text]
        if stale:
            fail(f"out of date: {', '.join(stale)}; run `hilbench urdf build`", 1)
        console.print("urdf/ is up to date")
        return
    for p in write_scene():
        console.print(f"wrote {p}")


from bench.cli.accuracy import accuracy, workspace  # noqa: E402  (kept in its own module)

app.command()(accuracy)
app.command()(workspace)

from bench.cli.contact import contact_protocol  # noqa: E402  (kept in its own module)

app.command("contact-protocol")(contact_protocol)

from bench.cli.campaign import campaign_app  # noqa: E402  (kept in its own module)

app.add_typer(campaign_app, name="campaign")

from bench.cli.lab import calibrate, doctor, jog, scan  # noqa: E402  (kept in its own module)

app.command()(scan)
app.command()(doctor)
app.command()(calibrate)
app.command()(jog)

from bench.cli.compare import compare  # noqa: E402  (kept in its own module)

app.command()(compare)


def _tidy_help(command) -> None:
    """Help texts without type placeholders on flags, and arguments in capitals."""
    import typer._click as click_core

    ctx = click_core.Context(command)
    params = list(command.params)
    help_option = command.get_help_option(ctx)
    if help_option is not None:
        params.append(help_option)
    for p in params:
        if getattr(p, "is_flag", False):
            p.metavar = ""
        elif p.param_type_name == "argument" and p.metavar is None:
            p.metavar = p.name.upper()
    for sub in getattr(command, "commands", {}).values():
        _tidy_help(sub)


def main() -> None:  # pragma: no cover - console entry point
    command = typer.main.get_command(app)
    _tidy_help(command)
    command()


if __name__ == "__main__":  # pragma: no cover
    main()
