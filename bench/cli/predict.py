"""``hilbench predict``: how well a servo model predicts test-stand logs of a real servo.

Kept in its own module; ``bench/cli/app.py`` registers :func:`predict`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from bench.cli.common import console, emit_json, fail

__all__ = ["predict"]


def predict(model: str = typer.Argument(..., metavar="MODEL",
                                        help="A servo model file (.yaml), one of BAM's parameter files (.json), "
                                             "datasheet, or ideal (q = goal)."),
            logs: list[Path] = typer.Argument(..., metavar="LOG",
                                              help="Test-stand logs in BAM's format (raw or resampled), or "
                                                   "directories of them."),
            out: Optional[Path] = typer.Option(None, "--out", help="Write the HTML report into this directory."),
            as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Roll each log out open loop under MODEL, as BAM scores its models: MAE per log and the mean."""
    from bench.stand.errors import StandError  # deferred: --help and completion stay fast
    from bench.stand.predict import predict as run_predict  # deferred: --help and completion stay fast

    try:
        result = run_predict(model, logs)
    except StandError as e:
        fail(str(e))
    report = None
    if out is not None:
        from bench.stand.report import write_prediction_report  # deferred: matplotlib is heavy

        report = write_prediction_report(result, out / "predict.html")
    if as_json:
        emit_json(result.as_dict())
        return
    t = Table(title=f"{result.model.name}: open-loop prediction")
    for col in ("log", "trajectory", "kp", "MAE (rad)", "max error (rad)"):
        t.add_column(col)
    for s in result.scores:
        t.add_row(s.log.name, s.log.trajectory, f"{s.log.kp:g}", f"{s.mae:.4f}", f"{s.max_error:.4f}")
    console.print(t)
    console.print(f"mean MAE {result.mean_mae:.4f} rad over {len(result.scores)} log(s)", highlight=False)
    if report is not None:
        console.print(f"report: {report}", highlight=False)
