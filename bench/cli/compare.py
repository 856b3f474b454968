"""``hilbench compare``: sim vs real tracking, from a config (runs both) or from two saved runs.

Kept in its own module; ``bench/cli/app.py`` registers :func:`compare`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from bench.cli.common import (CLOCK_HELP, checked_clock, console, emit_json, err_console, fail, load_config,
                               say, stopped, styled)
from bench.cli.live import LIVE_HELP, LIVE_WAIT_HELP, LIVE_WAIT_S, live_view
from bench.core.interrupts import SignalGuard, TrialInterrupted
from drivers.errors import (
    ActuatorError,
    BenchError,
    CompareError,
    ConfigError,
    ExitCode,
    PlanMismatchError,
    TrialError,
    safe_stop_unconfirmed,
)

__all__ = ["compare"]


def _is_config(path: Path) -> bool:
    return path.suffix.lower() in (".yaml", ".yml")


def _log_path(path: Path) -> Path:
    """A run directory or a trial.npz → the log file; errors name the path."""
    if path.is_dir():
        p = path / "trial.npz"
        if not p.is_file():
            fail(f"{path}: not a trial run directory (no trial.npz in it)")
        return p
    if path.is_file() and path.suffix == ".npz":
        return path
    if not path.exists():
        fail(f"{path}: no such file or directory")
    fail(f"{path}: expected a trial config (.yaml), a trial run directory or a trial.npz")


def compare(first: Path = typer.Argument(..., help="A trial config (.yaml) with backend.kind: dynamixel, "
                                                 "or a trial run directory / trial.npz."),
            second: Optional[Path] = typer.Argument(None, help="With a run as FIRST: the second run "
                                                               "directory or trial.npz."),
            repeats: int = typer.Option(5, "--repeats", help="Repeats on each backend (config form)."),
            emulate: bool = typer.Option(False, "--emulate", help="Run the real backend against the "
                                                                  "emulated servo bus and sensor."),
            clock: Optional[str] = typer.Option(None, "--clock", metavar="realtime|virtual", help=CLOCK_HELP),
            retries: Optional[int] = typer.Option(None, "--retries", help="Rig repeats that lose the bus or "
                                                  "the sensor are run again this often (default 3 "
                                                  "emulated, 0 real)."),
            align: str = typer.Option("motion", "--align", help="Align logs at the first commanded motion "
                                                                "('motion') or by cross-correlation ('xcorr')."),
            out: Path = typer.Option(Path("runs"), "--out", help="Directory for the comparison directory."),
            sim_model: Optional[str] = typer.Option(
                None, "--sim-model", metavar="MODEL",
                help="Also run the sim through the servo model ('datasheet': the servo table's models and "
                     "gains; or a servo model file) and report how well it predicts the rig."),
            live: bool = typer.Option(False, "--live", help=LIVE_HELP),
            live_wait: float = typer.Option(LIVE_WAIT_S, "--live-wait", min=0, help=LIVE_WAIT_HELP),
            as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON line.")) -> None:
    """Compare sim and real tracking: run a config's plan on both backends N times, or compare two runs."""
    if align not in ("motion", "xcorr"):
        fail(f"--align must be 'motion' or 'xcorr', got {align!r}")
    clock = checked_clock(emulate, clock)
    if _is_config(first):
        if second is not None:
            fail(f"{second}: a second argument only goes with a run as the first (got a config, {first})")
        if sim_model is not None and sim_model != "datasheet":
            from bench.config.models import (  # deferred: --help and completion stay fast
                load_servo_model_file,
            )

            if not Path(sim_model).is_file():
                fail(f"--sim-model {sim_model!r}: neither 'datasheet' nor a servo model file (not found)")
            try:
                load_servo_model_file(sim_model)
            except ConfigError as e:
                fail(f"--sim-model: {e}")
            sim_model = str(Path(sim_model).resolve())
        result, out_dir, predicted, stop, live_url = _from_config(first, repeats, emulate, retries, align,
                                                                   out, sim_model, as_json, live, live_wait,
                                                                   clock)
    else:
        if second is None:
            fail(f"{first}: give two runs to compare (RUN_A RUN_B), or a trial config (.yaml)")
        if emulate or repeats != 5 or retries is not None or sim_model is not None or live or clock:
            fail("--repeats, --emulate, --clock, --retries, --sim-model and --live go with a config, not with two "
                 "saved runs")
        result, out_dir = _from_runs(first, second, align, out)
        predicted, stop, live_url = None, "", None
    summary = result.summary()
    summary["report"] = str(out_dir / "report.html")
    skipped = (getattr(result, "rig_stats", None) or {}).get("physics_skipped_s", 0.0)
    if skipped:  # as trial says it: the rehearsal's rig did not keep real time
        say("warning: the emulated rig's physics fell behind real time and skipped {} s; the machine "
            "was too busy for a faithful rehearsal", f"{skipped:.2f}")
    unconfirmed = safe_stop_unconfirmed(stop)
    if stop:
        summary["safe_stop"] = stop
    if unconfirmed:  # what the technician must see first, whatever the verdict
        summary["reason"] = "; ".join(x for x in (stop, summary.get("reason")) if x)
    if predicted is not None:
        summary["prediction"] = predicted.as_dict()
    if live_url:
        summary["live_url"] = live_url
    if as_json:
        emit_json(summary)
    else:
        verdict = "[green]PASSED[/]" if result.passed else "[red]FAILED[/]"
        sub = result.subject
        console.print(styled("{}: " + verdict + " over {} repeat(s) ({} mm / {}°)", sub.label,
                             len(sub.logs), f"{result.acceptance[0]:g}", f"{result.acceptance[1]:g}"))
        for line in _deviation_lines(summary):
            console.print(line, highlight=False)
        console.print(f"worst joint: {summary['worst_joint']}")
        if predicted is not None:
            pr = summary["prediction"]
            gap = (f"tracking gap {pr['tracking_gap_ratio']} of the ideal sim's"
                   if pr["tracking_gap_ratio"] is not None else
                   "no tracking gap: no repeat completed by the rig and both sims")
            console.print(f"prediction: tip {pr['tip_error_mm']['mean']} mm mean, "
                          f"{pr['tip_error_mm']['max']} mm max; {gap}")
        console.print(f"report: {out_dir / 'report.html'}")
    if unconfirmed:
        say("[bold red]check the rig:[/] {}", summary["reason"])
        raise typer.Exit(ExitCode.STOP_UNCONFIRMED)
    if not result.passed:
        say("[bold red]compare failed:[/] {}", summary["reason"])
    raise typer.Exit(ExitCode.PASSED if result.passed else ExitCode.FAILED)


def _xyz(values) -> str:
    return "  ".join(f"{axis} {'n/a' if v is None else format(round(v, 3) + 0.0, '+.3f')}"
                     for axis, v in zip("XYZ", values))


def _deviation_lines(summary: dict) -> list[str]:
    """The console's needle lines: X/Y/Z with their unit, the mean signed and the largest |…|."""
    tip, depth, angle = (summary[k] for k in ("tip_deviation_mm", "depth_deviation_mm", "angle_deviation_deg"))
    if tip["mean"] is None or tip["mean"][0] is None:
        return ["needle: no repeat placed it"]
    num = lambda v: "n/a" if v is None else f"{round(v, 3) + 0.0:.3f}"  # noqa: E731 - no "-0.000"
    return [f"tip deviation, mean (mm): {_xyz(tip['mean'])}",
            f"tip deviation, max |…| (mm): {_xyz(tip['max']).replace('+', '')}",
            f"depth (mm): mean {num(depth['mean'])}, max |…| {num(depth['max'])}; "
            f"angle (°): mean {num(angle['mean'])}, max |…| {num(angle['max'])}"]


def _from_config(path: Path, repeats: int, emulate: bool, retries: Optional[int], align: str, out: Path,
                 sim_model: Optional[str] = None, as_json: bool = False, live: bool = False,
                 live_wait: float = 0.0, clock: Optional[str] = None):

    from bench.compare.session import run_comparison  # deferred: --help and completion stay fast

    cfg = load_config(path)
    with Progress(TextColumn("{task.description}", style="bold", markup=False), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task(f"compare {cfg.name}", total=1.0)

        def progress(what: str, fraction: float) -> None:
            bar.update(task, description=what, completed=min(1.0, fraction))

        def waiting(what: str) -> None:
            bar.update(task, description=what)

        with SignalGuard() as guard, live_view(live, path, out, guard, live_wait, waiting) as server:
            try:
                res = run_comparison(cfg, out, repeats=repeats, emulate=emulate, retries=retries,
                                     align=align, progress=progress, interrupts=guard, sim_model=sim_model,
                                     clock=clock)
            except (CompareError, ConfigError, TrialError, PlanMismatchError, ActuatorError) as e:
                bar.stop()
                _refused_or_unconfirmed(e, as_json)
            except TrialInterrupted as e:
                bar.stop()
                stop = getattr(e, "safe_stop", None) or f"the rig got its safe stop ({cfg.backend.safe_stop})"
                unconfirmed = safe_stop_unconfirmed(stop)
                code = ExitCode.STOP_UNCONFIRMED if unconfirmed else e.exit_code
                said = str(e)  # "interrupted by SIGINT", and who asked when it was not a signal from outside
                reason = said + (f"; {stop}" if unconfirmed else "")
                if as_json:
                    emit_json({"passed": False, "completed": False, "reason": reason, "runs": str(out),
                               "safe_stop": stop, "exit_code": int(code)}
                              | ({"live_url": server.url} if server else {}))
                line = f"compare stopped; {stop}; the runs so far are under {out}"
                if unconfirmed:
                    fail(f"{said}: {line}", code)
                say("[bold red]{}:[/] {}", said, line)
                stopped(e.signum)
    return res.comparison, res.out_dir, res.prediction, res.safe_stop, server.url if server else None


def _refused_or_unconfirmed(e: BenchError, as_json: bool) -> None:
    """A comparison that could not go on: refused (exit 2) if nothing moved, else its one line;
    a safe stop that was not confirmed is said first, with exit 3."""
    stop = getattr(e, "safe_stop", None)
    if not safe_stop_unconfirmed(stop):
        fail(str(e))
    reason = f"{stop}; {e}"
    if as_json:
        emit_json({"passed": False, "completed": False, "reason": reason, "safe_stop": stop,
                   "exit_code": int(ExitCode.STOP_UNCONFIRMED)})
    fail(reason, ExitCode.STOP_UNCONFIRMED)


def _from_runs(a: Path, b: Path, align: str, out: Path):

    from bench.compare.alignment import load_saved_trial  # deferred: --help and completion stay fast
    from bench.compare.analysis import compare_logs  # deferred: --help and completion stay fast
    from bench.compare.report import write_compare_report  # deferred: --help and completion stay fast
    from bench.core.rundir import RunDirError  # deferred: --help and completion stay fast

    pa, pb = _log_path(a), _log_path(b)
    try:
        la, lb = load_saved_trial(a), load_saved_trial(b)
    except RunDirError as e:
        fail(str(e))
    # the run on hardware (or its emulator) is the one judged; with two alike, the second
    if la.metadata.get("backend") == "dynamixel" and lb.metadata.get("backend") != "dynamixel":
        (la, pa, a), (lb, pb, b) = (lb, pb, b), (la, pa, a)
    labels = (_label(la, "A"), _label(lb, "B"))
    if labels[0] == labels[1]:
        labels = (f"{labels[0]} A", f"{labels[1]} B")
    try:
        result = compare_logs([la], [lb], labels=labels, sources=([str(a)], [str(b)]),
                              align=align)  # type: ignore[arg-type]
    except (PlanMismatchError, ValueError, KeyError) as e:
        fail(str(e).replace("\n", " "))
    from bench.core.record import new_run_dir  # deferred: --help and completion stay fast

    name = (la.metadata.get("config") or {}).get("name", "runs")
    try:
        out_dir = new_run_dir(Path(out), f"compare-{name}")
    except BenchError as e:
        fail(str(e))
    write_compare_report(result, out_dir, title=f"{labels[1]} vs {labels[0]}: {name}",
                         notes=[f"{labels[0]}: {a}", f"{labels[1]}: {b}"])
    return result, out_dir


def _label(log, fallback: str) -> str:
    backend = str(log.metadata.get("backend"))
    rig = log.metadata.get("rig")  # what the record says ran it
    if rig in ("emulated", "real"):
        return f"{rig} rig"
    if backend == "dynamixel":  # a log recorded before records said which rig
        port = str(((log.metadata.get("config") or {}).get("backend") or {}).get("port", ""))
        return "emulated rig" if port.startswith("/dev/pts/") else "real rig"
    return {"pybullet": "sim"}.get(backend, fallback)
