"""``hilbench campaign``: run, resume, re-run, export and report fault-injection campaigns, and the
searches over a spec's axes (falsify, boundary).

``hilbench campaign SPEC`` is short for ``hilbench campaign run SPEC``: the
group rewrites a first argument that is not one of its commands into a
``run``. Bad input ends with one line on stderr and exit code 2; a Ctrl-C
ends with 130 (128 + SIGINT) after the trials in flight are recorded.
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Optional

import typer
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from typer.core import TyperGroup

from bench.cli.common import console, emit_json, err_console, fail, say, stopped
from drivers.errors import CampaignError, CampaignSpecError, ExitCode

__all__ = ["campaign_app"]



class _RunByDefault(TyperGroup):
    """``campaign SPEC ...`` means ``campaign run SPEC ...``."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


campaign_app = typer.Typer(
    cls=_RunByDefault, no_args_is_help=True, add_completion=False,
    help="Fault-injection campaigns: `hilbench campaign SPEC` (= run), resume, rerun, export, report; "
         "falsify and boundary search a spec's axes.")






def _progress_bar():

    return Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
                    TextColumn("[red]{task.fields[failed]} failed[/] · {task.fields[errors]} errors"),
                    TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                    console=err_console, transient=False)


def _run(campaign_dir: Path, workers: Optional[int], scheduler: Optional[str], as_json: bool,
         report: bool = True) -> None:
    from bench.campaign.lock import CampaignBusy, CampaignLock  # deferred: --help and completion stay fast
    from bench.campaign.run import CampaignError, open_store, run_campaign  # deferred: --help stays fast

    try:  # one writer per campaign, and a database that is one: refused in one line, before the bar draws
        open_store(campaign_dir).close()
        lock = CampaignLock(campaign_dir).acquire()
    except (CampaignBusy, CampaignError) as e:
        fail(str(e))
    with lock, _progress_bar() as bar:
        task = bar.add_task("campaign", total=None, failed=0, errors=0)

        def on_progress(state) -> None:
            bar.update(task, total=state.to_run, completed=state.finished, failed=state.failed,
                       errors=state.errors)

        try:
            summary = run_campaign(campaign_dir, workers=workers, scheduler=scheduler,
                                   progress=on_progress, report=report,
                                   notify=lambda m: say("[yellow]note:[/] {}", m))
        except (CampaignError, RuntimeError, ValueError) as e:
            fail(str(e))
    if as_json:
        emit_json(summary.as_json())
    else:
        rate = f" ({100 * summary.passed / summary.completed:.1f} %)" if summary.completed else ""
        console.print(f"campaign {campaign_dir}: planned {summary.planned}, done {summary.completed}, "
                      f"passed {summary.passed}{rate}, errors {summary.errors}, "
                      f"not run {summary.pending}; {summary.ran} trials in {summary.wall_s:.1f} s"
                      + (f" on {summary.pool}" if summary.pool else ""), highlight=False)
        if (campaign_dir / "report.html").is_file():
            console.print(f"report: {campaign_dir / 'report.html'}", highlight=False)
    if summary.reason:
        say("[bold red]campaign incomplete:[/] {}", summary.reason)
    if summary.interrupted:  # the line above says so and how to resume
        stopped(signal.SIGINT)
    raise typer.Exit(ExitCode.PASSED if summary.completed == summary.planned else ExitCode.FAILED)


_WORKERS = typer.Option(None, "--workers", min=1, help="Local worker processes (default: one per core).")
_SCHEDULER = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://host:8786.")
_JSON = typer.Option(False, "--json", help='Print {"db", "planned", "completed", "passed", "errors"}.')


def _search_dir(kind: str):
    """A search's ``--out``: its directory, resumed when it already holds this search."""
    return typer.Option(None, "--out", help=f"Search directory (default runs/campaigns/<stamp>-<name>-{kind}); "
                                            "one that holds this search already is resumed.")


@campaign_app.command("run")
def run(spec: Path = typer.Argument(..., help="A campaign spec, e.g. hil_configs/campaigns/tolerance_sweep.yaml."),
        workers: Optional[int] = _WORKERS, scheduler: Optional[str] = _SCHEDULER,
        out: Optional[Path] = typer.Option(None, "--out", help="Campaign directory (default runs/campaigns/<stamp>-<name>)."),
        as_json: bool = _JSON,
        report: bool = typer.Option(True, "--report/--no-report", help="Write report.md/.html at the end.")) -> None:
    """Plan a campaign into DIR/campaign.db and run it."""
    from bench.campaign.run import create_campaign  # deferred: --help and completion stay fast

    try:
        campaign_dir = create_campaign(spec, out)
    except (CampaignSpecError, CampaignError) as e:
        fail(str(e))
    err_console.print(f"campaign directory: {campaign_dir}", highlight=False)
    _run(campaign_dir, workers, scheduler, as_json, report)


@campaign_app.command("resume")
def resume(campaign_dir: Path = typer.Argument(..., help="A campaign directory (holding campaign.db)."),
           workers: Optional[int] = _WORKERS, scheduler: Optional[str] = _SCHEDULER, as_json: bool = _JSON,
           report: bool = typer.Option(True, "--report/--no-report")) -> None:
    """Run what is missing: pending trials, trials a killed run left running, errors with attempts left."""
    _run(campaign_dir, workers, scheduler, as_json, report)


@campaign_app.command("rerun")
def rerun(campaign_dir: Path = typer.Argument(...), trial_id: int = typer.Argument(..., help="Trial id (see export)."),
          out: Optional[Path] = typer.Option(None, "--out", help="Where the run directory goes (default DIR/reruns)."),
          as_json: bool = typer.Option(False, "--json")) -> None:
    """Run one trial again from its stored config and seed, with its full report; compare the numbers."""
    from bench.campaign.run import rerun_trial  # deferred: --help and completion stay fast

    try:
        res = rerun_trial(campaign_dir, trial_id, out)
    except (CampaignError, KeyError) as e:
        fail(str(e.args[0] if isinstance(e, KeyError) else e))
    if as_json:
        emit_json(res)
    else:
        console.print(f"trial {res['trial']} ({res['name']}, seed {res['seed']}): "
                      + ("identical to the record" if res["identical"] else
                         f"differs from the record (stored status {res['stored_status']})"), highlight=False)
        unmeasured = [k for k in res["stored"] if res["stored"][k] is None and res["rerun"][k] is None]
        for k in res["stored"]:
            if k not in unmeasured:
                console.print(f"  {k:>14}: {res['stored'][k]!s:>12}  ->  {res['rerun'][k]!s}",
                              highlight=False)
        if unmeasured:
            console.print(f"  not measured in either: {', '.join(unmeasured)}", highlight=False)
        console.print(f"report: {Path(res['run_dir']) / 'report.html'}", highlight=False)
    raise typer.Exit(ExitCode.PASSED if res["identical"] else ExitCode.FAILED)


@campaign_app.command("export")
def export(campaign_dir: Path = typer.Argument(...),
           csv: Path = typer.Option(..., "--out", "--csv", help="CSV file to write (--csv: the same)."),
           as_json: bool = typer.Option(False, "--json", help='Print {"csv": PATH}.')) -> None:
    """Write the trials table as CSV: one row per trial, one column per varying parameter,
    times in ISO 8601 UTC."""
    from bench.campaign.run import export_csv  # deferred: --help and completion stay fast

    try:
        path = export_csv(campaign_dir, csv)
    except CampaignError as e:
        fail(str(e))
    if as_json:
        emit_json({"csv": str(path)})
    else:
        err_console.print(f"wrote {path}", highlight=False)


@campaign_app.command("report")
def report_cmd(campaign_dir: Path = typer.Argument(...),
               beside: list[Path] = typer.Option([], "--beside", metavar="DIR",
                                                 help="Another campaign to table beside this one "
                                                      "(bias and scatter per axis); repeatable."),
               as_json: bool = typer.Option(False, "--json", help='Print {"markdown", "html"}: the paths.')) -> None:
    """Write report.md and report.html from the database as it stands."""
    from bench.campaign.report import write_campaign_report  # deferred: --help and completion stay fast
    from bench.campaign.run import CampaignError, open_store  # deferred: --help and completion stay fast
    from drivers import BenchError  # deferred: --help and completion stay fast

    try:
        for d in (campaign_dir, *beside):
            open_store(d).close()
        paths = write_campaign_report(campaign_dir, beside, strict=True)
    except (CampaignError, BenchError) as e:  # a campaign or trial directory that fails its checks
        fail(str(e))
    if as_json:
        emit_json({k: str(v) for k, v in paths.items()})
    else:
        console.print(f"report: {paths['html']}", highlight=False)


@campaign_app.command("status")
def status(campaign_dir: Path = typer.Argument(...), as_json: bool = _JSON) -> None:
    """Counts of the campaign's trials (pending, running, done, error, passed)."""
    from bench.campaign.run import summarize  # deferred: --help and completion stay fast

    try:
        s = summarize(campaign_dir)
    except CampaignError as e:
        fail(str(e))
    if as_json:
        emit_json(s.as_json())
    else:
        console.print(f"planned {s.planned}, done {s.completed}, passed {s.passed}, errors {s.errors}, "
                      f"not run {s.pending}", highlight=False)


@campaign_app.command("falsify")
def falsify_cmd(spec: Path = typer.Argument(..., help="A campaign spec with axes (fault parameters, override "
                                                        "values), e.g. hil_configs/campaigns/falsify_bias.yaml."),
                budget: int = typer.Option(100, "--budget", min=1, help="Most trials to run."),
                seed: int = typer.Option(0, "--seed", min=0, help="The search's seed (the trials' own come "
                                                                  "from the spec's)."),
                optimizer: Optional[str] = typer.Option(None, "--optimizer", help="corners-cma (default: the box's "
                                                        "corners first, then CMA-ES), cma or random."),
                workers: Optional[int] = _WORKERS, scheduler: Optional[str] = _SCHEDULER,
                out: Optional[Path] = _search_dir("falsify"),
                as_json: bool = typer.Option(False, "--json", help='Print {"falsified", "trials", "robustness", '
                                             '"params", "config", ...}.')) -> None:
    """Search the spec's axes for a trial that violates a requirement; stop at the first, or the budget.

    Exit codes: 0 none found within the budget, 1 a requirement violated (its trial's config is
    written beside the search: `hilbench trial CONFIG` runs it alone), 2 refused, 130 Ctrl-C.
    """
    from bench.campaign.falsify import DEFAULT_OPTIMIZER, OPTIMIZERS, falsify  # deferred: --help stays fast
    from bench.campaign.lock import CampaignBusy  # deferred: --help and completion stay fast
    from bench.campaign.search_report import write_falsify_report  # deferred: --help stays fast

    optimizer = optimizer or DEFAULT_OPTIMIZER
    if optimizer not in OPTIMIZERS:
        fail(f"--optimizer {optimizer!r}: unknown; valid: {', '.join(OPTIMIZERS)}")
    try:
        res = falsify(spec, out, budget=budget, seed=seed, optimizer=optimizer, workers=workers,
                      scheduler=scheduler, notify=lambda m: err_console.print(m, highlight=False))
    except (CampaignSpecError, CampaignError, CampaignBusy, RuntimeError, ValueError) as e:
        fail(str(e))
    data = res.as_json()
    with_meta = {**data, "name": Path(spec).stem, "budget": budget, "search_seed": seed}
    report = write_falsify_report(res.campaign_dir, with_meta)
    if as_json:
        emit_json(data)
    else:
        verdict = "[red]FALSIFIED[/]" if res.falsified else "[green]not falsified[/]"
        lowest = "a trial error" if data["error"] else f"{data['requirement']} {_signed(data['robustness'])}"
        console.print(f"falsify {res.campaign_dir}: ", verdict, f" in {data['trials']} trial(s) "
                      f"({optimizer}); lowest: {lowest}", sep="", highlight=False)
        if data["params"]:
            console.print("at " + ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}"
                                            for k, v in data["params"].items()), highlight=False, soft_wrap=True)
        if data["error"]:  # it failed without running: refused (a target out of reach) or broken
            console.print(f"the trial errored: {data['error']}", highlight=False, soft_wrap=True)
        if res.falsified:
            console.print(f"re-run it alone: hilbench trial {data['config']}", highlight=False, soft_wrap=True)
        console.print(f"report: {report}", highlight=False)
    if res.interrupted:
        stopped(signal.SIGINT)
    raise typer.Exit(ExitCode.FAILED if res.falsified else ExitCode.PASSED)


def _signed(v: Optional[float]) -> str:
    return "none" if v is None else f"{v:+.3f}"


@campaign_app.command("boundary")
def boundary_cmd(spec: Path = typer.Argument(..., help="A campaign spec with axes (fault parameters, override "
                                                         "values), e.g. hil_configs/campaigns/boundary_bias.yaml."),
                 tolerance: float = typer.Option(0.01, "--tolerance", help="Stop when the bracket is this share "
                                                 "of the axis's range."),
                 max_trials: int = typer.Option(12, "--max-trials", min=2, help="Most trials per axis for its "
                                                "first seed."),
                 repeats: Optional[int] = typer.Option(None, "--repeats", min=1, help="Seeds a random trial's "
                                                       "boundary is bracketed with (default: the spec's "
                                                       "repeats, 5 when it has none); 1: one seed, no check."),
                 pair: Optional[tuple[str, str]] = typer.Option(None, "--pair", metavar="AXIS_A AXIS_B",
                                                                help="Also the boundary curve in the plane of "
                                                                "two axes (a label or a part of one, e.g. "
                                                                "theta5 theta6)."),
                 rays: int = typer.Option(7, "--rays", min=2, help="Rays of the --pair plane from its "
                                          "least-fault corner, the two axes included."),
                 grid: int = typer.Option(0, "--grid", min=0, help="Also run this many evenly spaced values "
                                          "per axis (and N × N in a --pair's plane), each by as many seeds, "
                                          "for the pass rate beside the boundary (0: none)."),
                 workers: Optional[int] = _WORKERS, scheduler: Optional[str] = _SCHEDULER,
                 out: Optional[Path] = _search_dir("boundary"),
                 as_json: bool = typer.Option(False, "--json", help='Print {"boundaries": [{"axis", '
                                              '"requirement", "value", "interval", "interval_kind", "trials", '
                                              '...}], "pairs": [{"axes", "points", "trials", "rays"}]}.')) -> None:
    """Along each numeric axis, the value where a requirement starts failing, and its interval
    (the bracket, or the range of the seeds' crossings when the trial is random); with --pair, the
    boundary curve in the plane of two axes."""
    from bench.campaign.boundary import find_boundaries  # deferred: --help stays fast
    from bench.campaign.lock import CampaignBusy  # deferred: --help and completion stay fast
    from bench.campaign.search_report import write_boundary_report  # deferred: --help stays fast

    if not 0 < tolerance < 1:
        fail(f"--tolerance must be between 0 and 1 (a share of the axis's range), got {tolerance}")
    try:
        found = find_boundaries(spec, out, tolerance=tolerance, max_trials=max_trials, workers=workers,
                                scheduler=scheduler, grid=grid, pair=pair if pair and pair[0] else None,
                                rays=rays, repeats=repeats,
                                notify=lambda m: err_console.print(m, highlight=False))
    except (CampaignSpecError, CampaignError, CampaignBusy, RuntimeError, ValueError) as e:
        fail(str(e))
    except KeyboardInterrupt:
        stopped(signal.SIGINT)
    report = write_boundary_report(found.campaign_dir, {"name": Path(spec).stem, "boundaries": found.boundaries,
                                                        "pairs": found.pairs}, found.grids, found.pair_grids)
    if as_json:
        emit_json({"boundaries": found.boundaries, "pairs": found.pairs, "campaign": str(found.campaign_dir)})
        return
    for b in found.boundaries:
        console.print(_boundary_line(b), highlight=False, soft_wrap=True)
    for p in found.pairs:
        points = ", ".join(f"({x:.4g}, {y:.4g})" for x, y in p["points"]) or "none"
        console.print(f"{p['axes'][0]} × {p['axes'][1]}: boundary at {points} ({p['trials']} trials)",
                      highlight=False, soft_wrap=True)
    console.print(f"report: {report}", highlight=False)


def _boundary_line(b: dict) -> str:
    if b["interval"] is None:
        return f"{b['axis']}: no requirement fails within its range ({b['trials']} trials)"
    lo, hi = b["interval"]
    where = "from beyond its range" if b["value"] is None else f"from {b['value']:.4g}"
    spread = (f"between {lo:.4g} and {hi:.4g}" if b["interval_kind"] == "bracket"
              else f"seeds' crossings from {lo:.4g} to {hi:.4g}")
    return (f"{b['axis']}: {b['requirement']} fails {where} ({spread}; {b['trials']} trials, "
            f"{b['method']})")
