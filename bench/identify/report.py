"""The identification report: per joint, the logged position and current beside the datasheet
model's and the identified model's, the residuals, the error before and after, and each fitted
value with its standard error and whether the logs could tell it."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from bench.config.servo_model import ServoModelFile
from bench.identify.fit import FitResult
from bench.identify.logs import LoggedRun, RigSetup
from bench.identify.simulate import FILE_KEYS
from bench.report.trial import markdown_to_html

__all__ = ["write_report"]

UNITS = {"kt_scale": "", "armature_kgm2": "kg·m²", "viscous_nms": "N·m·s/rad", "coulomb_nm": "N·m",
         "stribeck_nm": "N·m", "stribeck_velocity_rads": "rad/s"}


def _pyplot():
    import matplotlib  # heavy: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded only when a figure is drawn

    return plt


def _display(setup: RigSetup, k: int) -> tuple[float, str]:
    """Scale and unit to show joint k's position in: degrees or millimetres."""
    return (np.degrees(1.0), "°") if setup.kinds[k] == "revolute" else (1e3, "mm")


def _mae_text(setup: RigSetup, k: int, value: float) -> str:
    scale, unit = _display(setup, k)
    return f"{value * scale:.3f} {unit}"


def plot_joint(setup: RigSetup, runs: Sequence[LoggedRun], fit: FitResult, name: str, path: Path) -> Path:
    """Position, its residual and current of one joint over every log, end to end."""
    plt = _pyplot()
    k = setup.joint_names.index(name)
    f = list(fit.joints).index(name)
    scale, unit = _display(setup, k)
    fig, (ax_q, ax_r, ax_i) = plt.subplots(3, 1, figsize=(11, 6.2), sharex=True,
                                           gridspec_kw={"height_ratios": [2, 1, 1.4]})
    t0 = 0.0
    for i, run in enumerate(runs):
        t = run.time + t0
        qb, ib = fit.simulated_before[i][0][:, f], fit.simulated_before[i][1][:, f]
        qa, ia = fit.simulated_after[i][0][:, f], fit.simulated_after[i][1][:, f]
        first = i == 0
        ax_q.plot(t, run.goal[:, k] * scale, ":", color="tab:red", lw=1.2, label="goal" if first else None)
        ax_q.plot(t, run.q[:, k] * scale, "-", color="0.55", lw=3.0, label="logged" if first else None)
        ax_q.plot(t, qb * scale, "--", color="tab:blue", lw=1.0, label="datasheet model" if first else None)
        ax_q.plot(t, qa * scale, "-", color="tab:green", lw=1.0, label="identified model" if first else None)
        ax_r.plot(t, (qb - run.q[:, k]) * scale, "--", color="tab:blue", lw=0.9)
        ax_r.plot(t, (qa - run.q[:, k]) * scale, "-", color="tab:green", lw=0.9)
        ax_i.plot(t, run.current[:, k], "-", color="0.55", lw=2.4)
        ax_i.plot(t, ib, "--", color="tab:blue", lw=0.9)
        ax_i.plot(t, ia, "-", color="tab:green", lw=0.9)
        if i:
            for ax in (ax_q, ax_r, ax_i):
                ax.axvline(t0, color="k", lw=0.6, alpha=0.5)
        t0 = t[-1] + 0.5
    ax_q.set_ylabel(f"position ({unit})")
    ax_r.set_ylabel(f"model − log ({unit})")
    ax_r.axhline(0.0, color="k", lw=0.5)
    ax_i.set_ylabel("current (A)")
    ax_i.set_xlabel("time (s), logs end to end")
    for ax in (ax_q, ax_r, ax_i):
        ax.grid(alpha=0.3)
    ax_q.legend(loc="upper right", fontsize=8, ncol=4)
    fig.suptitle(f"{name}: logged vs modelled")
    fig.subplots_adjust(left=0.08, right=0.98, top=0.93, bottom=0.08, hspace=0.15)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _fmt(value: float) -> str:
    return "—" if not np.isfinite(value) else f"{value:.3g}"


def report_markdown(setup: RigSetup, runs: Sequence[LoggedRun], fit: FitResult,
                    model: ServoModelFile, figures: dict[str, str]) -> str:
    lines = ["# Servo identification", "",
             f"Robot **{setup.robot}**, {len(runs)} log(s), {sum(r.duration for r in runs):.1f} s in all. "
             "Each joint's servo is simulated along its logged motion (firmware, motor and gearbox of the "
             "shared servo model, the rest of the robot as measured) and its physics fitted to the logged "
             "position and current, from the datasheet's values: CMA-ES, then Levenberg-Marquardt. "
             "Each log is simulated in windows of 5 s, each started from the logged state.", "",
             "## Logs", ""]
    lines += [f"- `{r.run_dir}`: {r.duration:.1f} s, SHA-256 {r.sha256[:12]}…" for r in runs]
    lines += ["", "## Error before (datasheet) and after (identified)", "",
              "| joint | position MAE before | after | current MAE before (A) | after (A) |",
              "| --- | ---: | ---: | ---: | ---: |"]
    for name, jf in fit.joints.items():
        k = setup.joint_names.index(name)
        lines.append(f"| {name} | {_mae_text(setup, k, jf.mae_before)} | {_mae_text(setup, k, jf.mae_after)} | "
                     f"{jf.current_mae_before:.3f} | {jf.current_mae_after:.3f} |")
    if fit.skipped:
        lines += ["", "Not fitted: " + "; ".join(f"{n}: {why}" for n, why in fit.skipped.items()) + ". "
                  "Each takes the median of the fitted joints with its servo model (the same motor and "
                  "gearbox), or the datasheet's values when none was fitted; the model file's notes say which."]
    lines += ["", "## Identified physics", "",
              "| joint | " + " | ".join(f"{k} ({UNITS[k]})" if UNITS[k] else k for k in FILE_KEYS) + " |",
              "| --- | " + " | ".join("---:" for _ in FILE_KEYS) + " |"]
    weak = {n.split(":", 1)[0]: n.split(": too little to fit on: ", 1)[1] for n in model.notes
            if ": too little to fit on: " in n}
    for name, jf in fit.joints.items():
        cells = []
        for key in FILE_KEYS:
            if name in weak:  # the file holds its peers' physics
                cells.append(f"({_fmt(jf.values[key])}) → {_fmt(getattr(model.joints[name], key))} *")
                continue
            if key in jf.at_bound:  # the file holds its peers' value, not this one
                cells.append(f"edge ({_fmt(jf.values[key])}) → {_fmt(getattr(model.joints[name], key))} *")
                continue
            cell = f"{_fmt(jf.values[key])} ± {_fmt(jf.stderr[key])}"
            cells.append(cell if jf.observable[key] else f"{cell} *")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if weak:
        lines += ["", "**(fitted) → written**: too little to fit on, so the model file holds the median "
                  "of the joint's told peers: " + "; ".join(f"{n}: {why}" for n, why in weak.items()) + "."]
    edges = [n for n in model.notes if "edge of the fit's range" in n]
    if edges:
        lines += ["", "**edge (fitted) → written**: the fit drove the value (or the friction peak it goes "
                  "with) to the edge of its range, so the logs cannot tell it and the model file holds the "
                  "value after the arrow: "
                  + "; ".join(edges) + "."]
    lines += ["", "± is one standard error: how far the value can move, the others free to make up for it, "
              "before the fit's cost rises by 5 %. * marks a value **not observable**: one the logs cannot "
              "tell on its own (the list below says why). Friction against speed is told by constant-speed "
              "motion: the Stribeck velocity by speeds on both sides of it, Coulomb and viscous friction "
              "by two past its fade a factor 2 apart (at one, only their sum); a value told by the "
              "fit's cost alone must have a standard error within 5 % of it. What the logs do tell of a value not observable "
              "is its combination with the others (e.g. the friction at the speeds the joint moved at). "
              "The Stribeck peak is the friction at rest; Coulomb is the level it falls to with speed "
              "(or, on some worn gearboxes, rises to).", ""]
    why = [(name, key, jf.reasons[key]) for name, jf in fit.joints.items() for key in FILE_KEYS
           if not jf.observable[key] and key in jf.reasons and name not in weak]
    if why:
        lines += ["## Not observable, and why", "", "| joint | value | why |", "| --- | --- | --- |"]
        lines += [f"| {name} | {key} | {reason} |" for name, key, reason in why]
        lines.append("")
    left = [(name, a, b) for name, jf in fit.joints.items() for _, a, b in jf.left_out]
    if left:
        lines += ["Left out of the fit: " + "; ".join(f"{n} {a:.1f}–{b:.1f} s" for n, a, b in left)
                  + " (windows the joint's simulation alone could not follow, over 5 times its typical "
                  "error all along: a fast motion swinging the arm, whose coupling the log tells too "
                  "roughly).", ""]
    for name in fit.joints:
        lines += [f"## {name}", "", f"![{name}]({figures[name]})", ""]
    return "\n".join(lines)


def write_report(setup: RigSetup, runs: Sequence[LoggedRun], fit: FitResult, model: ServoModelFile,
                 path: Path) -> Path:
    """The report as one self-contained HTML page (figures inline) and its Markdown beside it."""
    path = Path(path)
    fig_dir = path.with_name(path.stem + "_figures")
    fig_dir.mkdir(parents=True, exist_ok=True)
    figures = {name: f"{fig_dir.name}/{name}.png" for name in fit.joints}
    for name in fit.joints:
        plot_joint(setup, runs, fit, name, fig_dir / f"{name}.png")
    md = report_markdown(setup, runs, fit, model, figures)
    path.with_suffix(".md").write_text(md, encoding="utf-8")
    images = {rel: path.parent / rel for rel in figures.values()}
    path.write_text(markdown_to_html(md, images, f"Servo identification, {setup.robot}"), encoding="utf-8")
    return path
