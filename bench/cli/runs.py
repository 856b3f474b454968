"""``hilbench runs``: what an output directory holds — trials, comparisons and campaigns — oldest
first, each with its verdict and a link to its report.

Each kind is read by its own package, as its own readers check it (``bench.trial.runs``,
``bench.compare.listing``, ``bench.campaign.listing``); nothing is written. Campaigns are
found directly in the directory and in its ``campaigns/`` folder, where ``hilbench campaign``
puts them by default.
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.style import Style
from rich.table import Table
from rich.text import Text

from bench.cli.common import console, emit_json, fail

__all__ = ["list_outputs", "runs"]

_COLOUR = {"passed": "green", "failed": "red", "stopped": "red", "incomplete": "yellow", "broken": "magenta"}


def list_outputs(out: Path) -> list:
    """Every trial, comparison and campaign directly under ``out`` (and every campaign under
    ``out/campaigns``), as ``RunSummary`` rows, oldest first."""
    from bench.campaign.listing import (  # deferred: --help and completion stay fast
        CAMPAIGNS,
        campaign_summary,
        is_campaign_dir,
    )
    from bench.compare.listing import compare_summary, is_compare_dir  # deferred: as above
    from bench.core.rundir import has_run_files  # deferred: as above
    from bench.trial.runs import trial_summary  # deferred: as above

    out = Path(out)
    found = []
    for d in _subdirs(out):
        if is_campaign_dir(d):
            found.append(campaign_summary(d))
        elif has_run_files(d):
            found.append(trial_summary(d))
        elif is_compare_dir(d):
            found.append(compare_summary(d))
    if not is_campaign_dir(out / CAMPAIGNS):
        found += [campaign_summary(d) for d in _subdirs(out / CAMPAIGNS) if is_campaign_dir(d)]
    return sorted(found, key=lambda r: (r.started or "", r.run_dir))


def runs(out: Path = typer.Option(Path("runs"), "--out", help="The directory trials, compares and campaigns wrote into."),
         as_json: bool = typer.Option(False, "--json", help="Print the runs as one JSON line.")) -> None:
    """List past trials, comparisons and campaigns, oldest first, with verdicts and reports."""
    if not out.is_dir():
        fail(f"--out {out}: no such directory" if not out.exists() else f"--out {out}: not a directory")
    found = list_outputs(out)
    if as_json:
        emit_json({"out": str(out), "runs": [r.as_dict() for r in found]})
        return
    if not found:
        console.print(f"no trials, comparisons or campaigns in {out}", highlight=False)
        return
    names = [_shown(Path(r.run_dir), out) for r in found]
    t = Table(title=f"runs in {out}", title_justify="left", show_edge=False, pad_edge=False)
    # the run's name is never wrapped (it is copied into the next command); what ran it goes under it
    t.add_column("run (what ran it)", no_wrap=True, min_width=max(map(len, names)))
    t.add_column("verdict", no_wrap=True)
    t.add_column("tip dist. mm", justify="right", no_wrap=True)
    t.add_column("angle °", justify="right", no_wrap=True)
    for r, name in zip(found, names):
        tip = "" if r.tip_deviation_mm is None else f"{r.tip_deviation_mm:.2f}"
        angle = "" if r.angle_deviation_deg is None else f"{r.angle_deviation_deg:+.3f}"
        backend = f"{r.backend or '?'} ({r.rig})" if r.rig and r.rig != "sim" else (r.backend or "?")
        cell = _linked(name, r.report).append(f"\n{r.kind}, {backend}", style="dim")
        t.add_row(cell, Text(r.status, style=_COLOUR.get(r.status)), tip, angle)
    # as wide as the longest name needs: a narrow terminal wraps the line, never a name
    console.print(t, width=max(console.width, max(map(len, names)) + _OTHER_COLUMNS))
    for r, name in zip(found, names):
        if r.reason:
            console.print(f"{name}: {r.reason}", highlight=False, soft_wrap=True)
        if r.margin:
            console.print(f"{name}: lowest margin {r.margin}", highlight=False, soft_wrap=True)
        if r.alarms:
            console.print(f"{name}: the twin's alarms: {r.alarms}", highlight=False, soft_wrap=True)
        if r.cameras:
            console.print(f"{name}: cameras: {r.cameras}", highlight=False, soft_wrap=True)
    kinds = {k: sum(r.kind == k for r in found) for k in ("trial", "compare", "campaign")}
    console.print(f"{_count(len(found), 'run')} ({', '.join(f'{n} {k}' for k, n in kinds.items() if n)}); "
                  f"tip dist.: how far the needle tip ended from its target; lowest margin: the "
                  f"requirement with the lowest robustness (mm or °, negative: missed by); cameras: "
                  f"their tip's distance from the encoders', flagged beyond the two's uncertainty; "
                  f"reports: {out}/RUN/report.html (the run's name links to it)",
                  highlight=False, soft_wrap=True)


#: The verdict, tip and angle columns with the separators between the four columns.
_OTHER_COLUMNS = len("incomplete") + len("tip dist. mm") + len("angle °") + 3 * 3


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _subdirs(parent: Path) -> list[Path]:
    return sorted(d for d in parent.iterdir() if d.is_dir()) if parent.is_dir() else []


def _shown(d: Path, out: Path) -> str:
    """The directory as listed: its name, with ``campaigns/`` for one in the campaigns folder."""
    try:
        return str(d.relative_to(out))
    except ValueError:
        return d.name


def _linked(name: str, report: str | None) -> Text:
    """The run's name, a terminal hyperlink to its report when it has one."""
    if report is None:
        return Text(name)
    return Text(name, style=Style(link=Path(report).resolve().as_uri()))
