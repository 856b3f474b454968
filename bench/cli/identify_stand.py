"""``hilbench identify LOG...`` on test-stand logs (BAM's pendulum format): the servo's physics
as a servo model file, its report, a table of each log's error before and after."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from bench.cli.common import console, emit_json, err_console, fail

__all__ = ["identify_stand_logs", "split_inputs"]


def split_inputs(paths: Sequence[Path]) -> bool:
    """True when every path is a test-stand log (or a directory of them), False when none is;
    mixing the two kinds is refused in one line."""
    from bench.stand.identify import is_stand_input  # deferred: --help and completion stay fast

    kinds = [is_stand_input(p) for p in paths]
    if any(kinds) and not all(kinds):
        stand = next(p for p, k in zip(paths, kinds) if k)
        run = next(p for p, k in zip(paths, kinds) if not k)
        fail(f"{stand} is a test-stand log and {run} a trial run directory: identify one kind at a time")
    return all(kinds)


def identify_stand_logs(paths: Sequence[Path], out: Path, workers: int, generations: int,
                        as_json: bool) -> None:
    """Fit, write, and print the result (one JSON line with ``as_json``)."""
    from bench.identify.errors import IdentifyError  # deferred: --help and completion stay fast
    from bench.stand.identify import identify_stand  # deferred: --help and completion stay fast

    refused: IdentifyError | None = None
    with Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task("reading logs", total=1.0)
        try:
            result = identify_stand(list(paths), out, workers=workers, generations=generations,
                                    progress=lambda what, f: bar.update(task, description=what, completed=f))
        except IdentifyError as e:
            refused = e
    if refused is not None:
        fail(str(refused))
    if as_json:
        emit_json(result.as_dict())
        return
    t = Table(title=f"identified {result.model.servo} ({len(result.logs)} test-stand log(s), "
                    f"{result.seconds:.0f} s)")
    for col in ("log", "trajectory", "kp", "MAE datasheet (rad)", "MAE identified (rad)"):
        t.add_column(col)
    for b, a in zip(result.before.scores, result.after.scores):
        t.add_row(b.log.name, b.log.trajectory, f"{b.log.kp:g}", f"{b.mae:.4f}", f"{a.mae:.4f}")
    console.print(t)
    console.print(f"mean MAE {result.before.mean_mae:.4f} -> {result.after.mean_mae:.4f} rad",
                  highlight=False)
    console.print(f"model: {result.model_path}", highlight=False)
    if result.report_path:
        console.print(f"report: {result.report_path}", highlight=False)
