"""``hilbench cameras calibrate CONFIG [--emulate]``: the two cameras' intrinsics from views of a
ChArUco board, their poses in the robot's frame from the board at a known place on the bed, and a
dated calibration file; a camera whose reprojection error is beyond the bound is refused."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from bench.cli.common import emit_json, fail, load_config, say
from drivers.errors import CameraError, ExitCode

__all__ = ["cameras_app"]

cameras_app = typer.Typer(no_args_is_help=True, add_completion=False,
                          help="The cameras that measure the needle: calibrate them.")


@cameras_app.command("calibrate")
def calibrate(config: Path = typer.Argument(..., help="A trial config with a cameras: section."),
              emulate: bool = typer.Option(False, "--emulate", help="Calibrate the emulated cameras "
                                           "(the board drawn into the rendered scene)."),
              views: int = typer.Option(10, "--views", min=4, max=60,
                                        help="Views of the board held before each camera."),
              max_error: float = typer.Option(1.0, "--max-error", min=0.01, max=20.0,
                                              help="Refuse a camera reprojecting worse (pixels, rms)."),
              out: Optional[Path] = typer.Option(None, "--out", help="Folder of the calibration file "
                                                 "(default: <config dir>/calibration)."),
              seed: int = typer.Option(0, "--seed", min=0, help="The emulated views' seed."),
              as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Calibrate the config's two cameras and write a dated calibration file."""
    from bench.cameras.calibrate import write_calibration  # deferred: --help and completion stay fast
    from bench.cameras.session import calibrate_devices, calibrate_emulated  # deferred: --help stays fast
    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast

    cfg = load_config(config)
    if cfg.cameras is None:
        fail(f"{config}: no cameras: section to calibrate")
    truth = None
    try:
        if emulate:
            cals, truth = calibrate_emulated(cfg.cameras, cfg.robot_urdf, get_robot(cfg.robot).joint_names,
                                             cfg.resolve(cfg.urdf_dir), views, max_error, seed)
        else:
            cals = calibrate_devices(cfg.cameras, views, max_error, lambda what: typer.prompt(
                what, default="", show_default=False, prompt_suffix=" "))
    except CameraError as e:
        fail(str(e), code=ExitCode.FAILED)
    folder = out if out is not None else Path(config).resolve().parent / "calibration"
    path = write_calibration(cals, folder, str(config), emulate, truth)
    record = json.loads(path.read_text())
    if as_json:
        emit_json({"file": str(path), "cameras": record["cameras"]})
        return
    for c in record["cameras"]:
        against = c.get("against_config")
        say("{}: intrinsics {} px rms over {} views, pose {} px rms (board {})" + (
            "; {} mm and {}° from the configured pose" if against else ""),
            c["name"], f"{c['intrinsics_rms_px']:.3f}", c["views"], f"{c['pose_rms_px']:.3f}", c["board_place"],
            *((f"{against['position_mm']:.2f}", f"{against['angle_deg']:.3f}") if against else ()))
    say("calibration: {}", path)
