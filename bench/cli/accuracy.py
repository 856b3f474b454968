"""``hilbench accuracy`` and ``hilbench workspace``: the accuracy study and the parallel robot's workspace map.

Registered on the main app by :mod:`bench.cli.app`. As every command there:
``--json`` prints one line (lengths in mm, angles in degrees, joint values
SI), and bad input ends with one line on stderr and exit code 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.table import Table

from bench.cli.common import console, emit_json, fail, styled

__all__ = ["accuracy", "workspace"]

def _message(e: BaseException) -> str:
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return " ".join(str(text).split())


def accuracy(
    robot: str = typer.Argument(..., metavar="ROBOT", help="arc-train, zerobot or para-brachy"),
    pose: Optional[str] = typer.Option(
        None, "--pose", help='JSON object {"joint": value} (rad or m); missing joints at the default pose.'),
    tol_deg: Optional[float] = typer.Option(
        None, "--tol-deg", help="Servo position tolerance, ± degrees [default: the servos' own, seed 000]."),
    samples: int = typer.Option(20000, "--samples", help="Monte-Carlo draws."),
    seed: int = typer.Option(0, "--seed", help="Seed of the joint-error sampler."),
    out: Optional[Path] = typer.Option(None, "--out", help="Directory for the report (Markdown, HTML, figures)."),
    as_json: bool = typer.Option(False, "--json", help="Print the budget as one JSON line."),
) -> None:
    """Needle-tip error budget for servo tolerances: Monte Carlo, worst case, joint shares, eqs 12-14 sweep."""
    from bench.accuracy.report import (  # deferred: --help and completion stay fast
        run_study,
        summary,
        write_report,
    )

    overrides: dict = {}
    if pose is not None:
        try:
            overrides = json.loads(pose)
        except json.JSONDecodeError as e:
            fail(f"--pose is not valid JSON: {e.msg} at character {e.pos}")
        if not isinstance(overrides, dict):
            fail(f"--pose must be a JSON object of joint values, got {pose!r}")
    if tol_deg is None:
        from bench.kinematics.arc_train import SERVO_TOL_DEG  # deferred: --help and completion stay fast

        tol_deg = SERVO_TOL_DEG
    if not (math.isfinite(tol_deg) and tol_deg >= 0.0):
        fail(f"--tol-deg must be a non-negative number of degrees, got {tol_deg!r}")
    if samples < 2:
        fail(f"--samples must be at least 2, got {samples}")
    if out is not None and out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} exists and is not a directory")
    from bench.accuracy.analysis import pose_from_joints  # deferred: --help and completion stay fast
    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast

    try:
        model = get_robot(robot)
    except KeyError as e:
        fail(_message(e))
    try:
        q = pose_from_joints(model, overrides)
    except ValueError as e:
        fail(f"--pose: {_message(e)}")
    try:
        study = run_study(model, q, tol_deg=tol_deg, samples=samples, seed=seed)
    except ValueError as e:  # an unreachable configuration, a bad tolerance
        fail(_message(e))
    result = summary(study)
    if out is not None:
        paths = write_report(study, out)
        result["report"] = str(paths["html"])
    if as_json:
        emit_json(result)
        return
    _print_human(result)


def _print_human(s: dict) -> None:
    console.print(styled("[bold]{}[/] at {}; ±{}° servos, {} errors, {} draws (seed {})", s["robot"],
                         s["pose_note"], f"{s['tol_deg']:g}", s["distribution"], s["samples"], s["seed"]))
    t = Table(title="needle error budget (mm, °)")
    for col in ("quantity", "mean", "std", "p95", "max", "worst case"):
        t.add_column(col, justify="right")
    for a in ("x", "y", "z"):
        d = s["tip_mm"][a]
        t.add_row(f"tip {a.upper()}", f"{d['mean']:+.3f}", f"{d['std']:.3f}", f"{d['p95']:.3f}", f"{d['max']:.3f}",
                  f"{s['worst_case_mm'][a]:.3f}")
    d = s["angle_deg"]
    t.add_row("insertion angle", f"{d['mean']:+.3f}", f"{d['std']:.3f}", f"{d['p95']:.3f}", f"{d['max']:.3f}",
              f"{s['worst_case_angle_deg']:.3f}")
    d = s["axis_deg"]
    t.add_row("axis (3-D)", f"{d['mean']:.3f}", f"{d['std']:.3f}", f"{d['p95']:.3f}", f"{d['max']:.3f}",
              f"{s['worst_case_axis_deg']:.3f}")
    console.print(t)
    shares = ", ".join(f"{n} {v:.1%}" for n, v in sorted(s["shares"]["tip"].items(), key=lambda kv: -kv[1]) if v > 0)
    console.print(f"tip variance shares: {shares}")
    if s["table3"]:
        t3 = s["table3"]
        console.print("Table 3 (five measured repeats of Target 1), mean / max |deviation|: "
                       + ", ".join(f"{k} {v['mean_abs']:.2f}/{v['max_abs']:.2f}" for k, v in t3.items()))
    if "report" in s:
        console.print(f"report: {s['report']}")


def workspace(
    robot: str = typer.Argument(..., help="para-brachy (the only robot with a workspace map)."),
    out: Path = typer.Option(Path("runs") / "workspace", "--out", help="Directory for the map and its plot."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as one JSON line."),
) -> None:
    """The parallel robot's workspace map: reachability, conditioning and singularity margin (.npz, .csv, .png)."""

    if robot != "para-brachy":
        fail(f"no workspace map for robot {robot!r}; the map exists for para-brachy only")
    if out.exists() and not out.is_dir():
        fail(f"--out {str(out)!r} exists and is not a directory")
    from bench.accuracy.workspace_figure import plot_workspace  # deferred: --help and completion stay fast
    from bench.kinematics import para_brachy as pb  # deferred: --help and completion stay fast

    result = pb.workspace_map()
    npz = pb.save_workspace(result, out / "workspace.npz", csv_path=out / "workspace.csv")
    png = plot_workspace(result, out / "workspace.png")
    reach = result.reachable

    def low(a: np.ndarray) -> Optional[float]:
        return float(f"{np.nanmin(a):.6g}") if reach.any() else None

    s = {"robot": robot, "npz": str(npz), "csv": str(out / "workspace.csv"), "png": str(png),
         "grid_shape": list(result.grid.shape), "poses": int(reach.size),
         "reachable_fraction": round(result.reachable_fraction, 6),
         "min_inv_cond_A": low(result.inv_cond_A), "min_inv_cond_B": low(result.inv_cond_B),
         "min_singularity_margin": low(result.margin)}
    if as_json:
        emit_json(s)
        return
    console.print(f"{robot}: {s['poses']} poses on a {'×'.join(map(str, s['grid_shape']))} grid, "
                   f"{s['reachable_fraction']:.1%} reachable; min 1/cond(A) {s['min_inv_cond_A']}, "
                   f"min 1/cond(B) {s['min_inv_cond_B']}, min singularity margin {s['min_singularity_margin']}")
    console.print(f"wrote {npz}, {s['csv']}, {png}")
