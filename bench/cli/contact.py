"""``hilbench contact-protocol``: seed 001's contact experiment (Tables 2–4) in simulation."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.table import Table

from bench.cli.common import console, emit_json, err_console, fail

__all__ = ["contact_protocol"]


def contact_protocol(
    robot: str = typer.Argument(..., help="zerobot (the robot of seed 001)"),
    as_json: bool = typer.Option(False, "--json", help='Print one line {"trials": n, "correct": n}.'),
    margin_mm: float = typer.Option(20.0, "--margin-mm", help="Safety margin of the detector."),
    out: Optional[Path] = typer.Option(None, "--out", help="Also write DIR/report.md with the tables."),
) -> None:
    """Run the paper's 64 contact trials (P1-P3, six postures, 25 and 15 mm, 20 mm margin)."""
    from bench.contact.protocol import (  # deferred: --help and completion stay fast
        PAPER_CORRECT,
        POINTS,
        markdown_report,
        run_protocol,
    )
    from bench.kinematics.registry import get_robot  # deferred: --help and completion stay fast

    try:
        model = get_robot(robot)
    except KeyError as e:
        fail(str(e.args[0]))
    if robot != "zerobot":
        fail(f"the contact protocol of seed 001 is defined for zerobot, not {robot!r}")
    if not 0.0 < margin_mm < 25.0:
        fail(f"--margin-mm must lie between 0 and 25 (the trials sit at 15 and 25 mm), "
             f"got {margin_mm}")
    if out is not None and out.exists() and not out.is_dir():
        fail(f"--out {out} exists and is not a directory")
    progress = Progress(TextColumn("contact trials"), BarColumn(), MofNCompleteColumn(),
                        console=err_console, transient=True, disable=as_json or not err_console.is_terminal)
    with progress:
        task = progress.add_task("trials", total=None)
        try:
            result = run_protocol(model, margin_mm * 1e-3,
                                  progress=lambda done, total: progress.update(
                                      task, completed=done, total=total))
        except ValueError as e:
            fail(str(e))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.md").write_text(markdown_report(result))
    if as_json:
        emit_json(result.summary())
        return
    for point in POINTS:
        pts = [t for t in result.trials if t.point == point]
        ok = sum(t.correct for t in pts)
        paper = PAPER_CORRECT[point]
        table = Table(title=f"Point {point}: {ok} of {len(pts)} correct "
                            f"(real robot {paper[0]} of {paper[1]})")
        for h in result.headers(point):
            table.add_column(h, justify="center")
        for row in result.table(point):
            table.add_row(*row)
        console.print(table)
    console.print(f"{result.correct} of {len(result.trials)} trials correct with a "
                  f"{margin_mm:g} mm margin (the real robot: 57 of 64)")
    if out is not None:
        console.print(f"report: {out / 'report.md'}")
