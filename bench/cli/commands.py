"""``hilbench``'s commands: the command-line face of the bench (a thin layer over the library).

:mod:`bench.cli.app` is the entry point that loads this module once its signal handlers
are in place.

Every command that prints numbers accepts ``--json`` for scripts: lengths in
mm and angles in degrees, joint values in SI (rad, m). Bad input ends with one
line on stderr and exit code 2, before anything moves.
"""

from __future__ import annotations

import json
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Optional

import numpy as np
import typer
import typer._click as click_core
from rich.table import Table

from bench.cli.accuracy import accuracy, workspace
from bench.cli.cameras import cameras_app
from bench.cli.campaign import campaign_app
from bench.cli.common import console, emit_json, fail
from drivers.errors import ExitCode, UnreachableError
from bench.cli.compare import compare
from bench.cli.contact import contact_protocol
from bench.cli.export import export
from bench.cli.files import schema, urdf_build
from bench.cli.identify import identify
from bench.cli.init import init
from bench.cli.lab import calibrate, doctor, jog, scan
from bench.cli.predict import predict
from bench.cli.registers import registers
from bench.cli.stand import stand
from bench.cli.runs import runs
from bench.cli.trial import check, emulate, report, trial

app = typer.Typer(no_args_is_help=True,
                  help="Hardware-in-the-loop test bench for CT-guided needle-placement robots.")
urdf_app = typer.Typer(no_args_is_help=True, help="Generate or check the URDF scene files.")
app.add_typer(urdf_app, name="urdf")


def _version(value: bool) -> None:
    if value:

        try:
            v = version("needle-hil-bench")
        except PackageNotFoundError:  # run from a source tree that was never installed
            v = "unknown"
        console.print(f"hilbench {v}", highlight=False)
        raise typer.Exit(ExitCode.PASSED)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Hardware-in-the-loop test bench for CT-guided needle-placement robots."""


ROBOT_HELP = "arc-train, zerobot or para-brachy"


def _robot(name: str):
    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast

    try:
        return get_robot(name)
    except KeyError as e:
        fail(str(e.args[0]))


def _trial_support(name: str) -> dict:
    from bench.kinematics.registry import trial_refusal  # deferred: --help and completion stay fast

    why = trial_refusal(name)
    return {"runs": why is None, "why": why or "URDF, servo table, plan and interlocks all present"}


def _mm(v) -> list[float]:
    return [round(float(x) * 1e3, 6) + 0.0 for x in v]


# ---------------------------------------------------------------------------
# Kinematics
# ---------------------------------------------------------------------------


@app.command()
def robot(name: Optional[str] = typer.Argument(None, metavar="[ROBOT]", help=ROBOT_HELP + "; none: list them"),
          as_json: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
    """List a robot's joints (type, limits and home, SI units) and whether `trial` can run it."""
    if name is None:
        from bench.kinematics.registry import robot_names  # deferred: --help and completion stay fast

        listing = {n: {"joints": len(_robot(n).joint_names), "trial": _trial_support(n)} for n in robot_names()}
        if as_json:
            emit_json({"robots": listing})
            return
        for n, info in listing.items():
            trial = "trial: yes" if info["trial"]["runs"] else f"trial: no ({info['trial']['why']})"
            console.print(f"{n}: {info['joints']} joints; {trial}")
        return
    r = _robot(name)
    joints = [{"name": row.name, "type": row.kind, "lower": row.lower, "upper": row.upper,
               "home": row.home} for row in r.chain.rows]
    trial = _trial_support(name)
    if as_json:
        emit_json({"robot": name, "joints": joints, "trial": trial})
        return
    t = Table(title=f"{name} joints (rad or m)")
    for col in ("name", "type", "lower", "upper", "home"):
        t.add_column(col)
    for j in joints:
        t.add_row(j["name"], j["type"], f"{j['lower']:.4f}", f"{j['upper']:.4f}", f"{j['home']:.4f}")
    console.print(t)
    console.print("trial: yes" if trial["runs"] else f"trial: no, {trial['why']}")


def _needle_json(pose) -> dict:
    return {"entry_mm": _mm(pose.entry), "tip_mm": _mm(pose.tip),
            "angle_deg": round(float(np.degrees(pose.angle)), 9),
            "tilt_deg": round(float(np.degrees(pose.out_of_plane)), 9),
            "depth_mm": round(pose.depth * 1e3, 9)}


@app.command()
def fk(name: str = typer.Argument(..., metavar="ROBOT", help=ROBOT_HELP),
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
def ik(name: str = typer.Argument(..., metavar="ROBOT", help=ROBOT_HELP),
       x_mm: float = typer.Option(..., "--x-mm"), y_mm: float = typer.Option(..., "--y-mm"),
       z_mm: float = typer.Option(..., "--z-mm"),
       depth_mm: float = typer.Option(..., "--depth-mm", help="Insertion depth beyond the entry point."),
       angle_deg: float = typer.Option(..., "--angle-deg", help="From the downward vertical towards +Y."),
       tilt_deg: float = typer.Option(0.0, "--tilt-deg", help="Out of the axial plane, towards +X."),
       render: Optional[Path] = typer.Option(None, "--render", help="Also write a PNG of the robot at the solution."),
       as_json: bool = typer.Option(False, "--json")) -> None:
    """Inverse kinematics to a needle target (entry point, depth, angle)."""
    from bench.kinematics.needle import NeedleTarget  # deferred: --help and completion stay fast
    from bench.paths import robot_urdf  # deferred: --help and completion stay fast

    r = _robot(name)
    if render is not None and not robot_urdf(name).exists():
        fail(f"--render: {name} has no URDF to draw (urdf/ has none for it); drop --render")
    target = NeedleTarget(np.array([x_mm, y_mm, z_mm]) * 1e-3, depth_mm * 1e-3, np.radians(angle_deg),
                          np.radians(tilt_deg))
    try:
        q = r.ik(target)
    except UnreachableError as e:
        fail(str(e))
    pose = r.needle(q)
    out = {"joints": {n: float(v) for n, v in zip(r.joint_names, q)}, **_needle_json(pose)}
    if render is not None:
        from bench.scene.render import render_robot  # deferred: --help and completion stay fast

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


# Registered in the order `hilbench --help` lists them.
for command in (init, check, trial, emulate, report, runs, export, schema):
    app.command()(command)
urdf_app.command("build")(urdf_build)
for command in (accuracy, workspace):
    app.command()(command)
app.command("contact-protocol")(contact_protocol)
app.add_typer(campaign_app, name="campaign")
app.add_typer(cameras_app, name="cameras")
for command in (scan, doctor, registers, calibrate, jog, compare, identify, predict, stand):
    app.command()(command)


def _tidy_help(command) -> None:
    """Help texts without type placeholders on flags, and arguments in capitals."""

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


def run() -> None:
    """Parse the command line and run the command (typer's standalone mode: ends in SystemExit)."""
    command = typer.main.get_command(app)
    _tidy_help(command)
    command()
