"""``hilbench identify``: the rig's servo physics from its trial logs, as a servo model file.

Kept in its own module; ``bench/cli/app.py`` registers :func:`identify`.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from bench.cli.common import console, emit_json, err_console, fail
from drivers.errors import IdentifyError

__all__ = ["identify"]


def identify(run_dirs: list[Path] = typer.Argument(..., metavar="RUN_DIR",
                                                   help="Trial run directories of the rig (real or "
                                                        "--emulate): excitation runs (hil_configs/identify.yaml) "
                                                        "or any trials; or test-stand logs (BAM's format)."),
             out: Path = typer.Option(..., "--out", help="The servo model file to write (.yaml); its report "
                                                         "goes beside it (.html, .md)."),
             workers: int = typer.Option(0, "--workers", min=0, max=64,
                                         help="Processes for the simulations (0: one per core); a batch too small to gain from them runs in one."),
             generations: int = typer.Option(40, "--generations", min=0, max=500,
                                             help="CMA-ES generations of the search (0: none)."),
             iterations: int = typer.Option(8, "--iterations", min=1, max=50,
                                            help="Most Levenberg-Marquardt steps that polish the search's best."),
             as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Fit the servos' physics (motor constant, armature, friction) to the rig's or a test stand's logs.

    Trial run directories give each joint's; test-stand logs (BAM's pendulum format), one servo's."""
    from bench.cli.identify_stand import identify_stand_logs, split_inputs  # deferred: --help stays fast

    if split_inputs(run_dirs):
        identify_stand_logs(run_dirs, out, workers, generations, as_json)
        return
    from bench.identify.run import identify as run_identify  # deferred: --help and completion stay fast
    from bench.identify.run import joint_rows  # deferred: --help and completion stay fast

    refused: IdentifyError | None = None
    with Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task("reading logs", total=1.0)

        def progress(what: str, fraction: float) -> None:
            bar.update(task, description=what, completed=fraction)

        try:
            result = run_identify(run_dirs, out, workers=workers, generations=generations,
                                  max_iterations=iterations, progress=progress)
        except IdentifyError as e:
            refused = e
    if refused is not None:
        fail(str(refused))
    if as_json:
        emit_json(result.as_dict())
        return
    t = Table(title=f"identified servos ({len(result.runs)} log(s), {result.seconds:.0f} s)")
    for col in ("joint", "position MAE before", "after", "current MAE before (A)", "after (A)", "not observable"):
        t.add_column(col)
    for name, jf in joint_rows(result):
        k = result.setup.joint_names.index(name)
        scale, unit = (math.degrees(1.0), "°") if result.setup.kinds[k] == "revolute" else (1e3, "mm")
        t.add_row(name, f"{jf.mae_before * scale:.3f} {unit}", f"{jf.mae_after * scale:.3f} {unit}",
                  f"{jf.current_mae_before:.3f}", f"{jf.current_mae_after:.3f}",
                  ", ".join(result.model.unobservable.get(name, [])) or "—")
    console.print(t)
    for note in result.model.notes[1:]:  # the joints the logs never moved, and what they took instead
        console.print(note, highlight=False)
    console.print(f"model: {result.model_path}", highlight=False)
    if result.report_path:
        console.print(f"report: {result.report_path}", highlight=False)
