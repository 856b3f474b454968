"""The accuracy study of one robot at one pose, as one JSON summary and a report.

:func:`run_study` gathers :mod:`bench.accuracy.analysis`'s three views (Monte-Carlo
budget, Jacobian budget, eqs 12–14 sweep) so the CLI, the report and the
tests all read the same numbers; :func:`summary` is the one-line JSON the
CLI prints (mm, degrees; joint values SI); :func:`write_report` writes the
figures, Markdown and self-contained HTML. For the arc-and-train robot the
paper's Table 3 (five measured repeats of Target 1) is set beside the budget.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from bench.accuracy import analysis as acc
from bench.config.models import AcceptanceConfig
from bench.kinematics.arc_train import ArcTrainRobot
from bench.kinematics.para_brachy import ParaBrachyRobot
from bench.kinematics.registry import get_robot
from bench.report.trial import markdown_to_html

__all__ = ["Study", "run_study", "summary", "table3_rows", "write_report", "plot_tip_errors",
           "plot_shares", "plot_sweep"]

_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Study:
    """Everything one accuracy run computed."""

    robot_name: str
    robot: object
    q: np.ndarray
    pose_note: str
    tol_deg: float
    jacobian: acc.JacobianBudget
    monte_carlo: acc.MonteCarloBudget
    sweep: acc.Sweep

    @property
    def has_table3(self) -> bool:
        return isinstance(self.robot, ArcTrainRobot)


def _pose_note(robot, q0: np.ndarray, custom: bool) -> str:
    """Where the default pose came from, in words."""
    home = np.array([r.home for r in robot.chain.rows], dtype=float)
    if isinstance(robot, ParaBrachyRobot):
        base = "the workspace centre (tip 250, −60, 0 mm; ψ −60°, θ 25°) by IGM"
    elif np.array_equal(q0, home):
        base = "the robot's home"
    else:
        base = "Target 1 of seed 000 (Y 88.2 mm, Z 66 mm, 30.1 mm deep at 47°) by IK"
    return base + (", with some joints moved" if custom else "")


def run_study(robot, q=None, tol_deg: float = acc.SERVO_TOL_DEG, samples: int = 20000, seed: int = 0,
              distribution: acc.Distribution = "uniform", tolerances: acc.Tolerances = None) -> Study:
    """Run the Monte-Carlo, Jacobian and sweep studies of ``robot`` (a name or a model) at ``q``.

    ``q`` defaults to :func:`bench.accuracy.analysis.default_pose`. Raises KeyError
    (unknown robot) or ValueError (bad tolerance or sample count; an
    unreachable configuration) with the bad value named.
    """
    model = get_robot(robot) if isinstance(robot, str) else robot
    q0 = acc.default_pose(model)
    q = q0 if q is None else np.asarray(q, dtype=float)
    tol = acc.resolve_tolerances(model, tolerances, tol_deg)
    mc = acc.monte_carlo_budget(model, q, tol, n=samples, seed=seed, distribution=distribution)
    jb = acc.jacobian_budget(model, q, tol, distribution=distribution)
    joint, values = acc.default_sweep(model, q)
    sw = acc.perturbation_sweep(model, q, joint, values)
    custom = not np.array_equal(q, q0)
    return Study(acc.robot_label(model), model, q, _pose_note(model, q0, custom), float(tol_deg), jb, mc, sw)


def _r(x: float, nd: int = 4) -> float:
    return round(float(x), nd) + 0.0


def summary(study: Study) -> dict:
    """The JSON summary: budget per axis, worst case, shares and Table 3 beside them."""
    mc, jb = study.monte_carlo, study.jacobian
    tip = mc.tip_stats()
    keys = ("std", "p95", "max")

    def pick(s: acc.ErrorStats, extra: tuple[str, ...] = ()) -> dict[str, float]:
        d = s.as_dict()
        return {k: d[k] for k in ("mean", *keys, *extra)}

    out: dict = {
        "robot": study.robot_name,
        "pose": {n: _r(v, 9) for n, v in zip(jb.joint_names, study.q)},
        "pose_note": study.pose_note,
        "tol_deg": study.tol_deg,
        "tolerances": {n: float(f"{t:.6g}") for n, t in zip(jb.joint_names, jb.tolerances)},
        "distribution": mc.distribution,
        "samples": mc.n,
        "seed": mc.seed,
        "tip_mm": {**{a: pick(tip[a]) for a in _AXES}, "norm": pick(tip["norm"], ("rms",))},
        "entry_mm": {a: pick(s) for a, s in mc.entry_stats().items()},
        "depth_mm": pick(acc.ErrorStats.of(mc.depth_err_mm)),
        "angle_deg": pick(acc.ErrorStats.of(mc.angle_err_deg)),
        "axis_deg": pick(acc.ErrorStats.of(mc.axis_err_deg), ("rms",)),
        "worst_case_mm": {**{a: _r(v) for a, v in zip(_AXES, jb.worst_tip_mm)}, "norm": _r(jb.worst_tip_norm_mm)},
        "worst_case_angle_deg": _r(jb.worst_angle_deg),
        "worst_case_axis_deg": _r(jb.worst_axis_deg),
        "rss_mm": {a: _r(v) for a, v in zip(_AXES, jb.rss_tip_mm)},
        "shares": {
            "method": "variance with one joint perturbed / sum over joints (Monte Carlo)",
            "tip": {n: _r(s) for n, s in zip(mc.joint_names, mc.share_tip)},
            "axis": {n: _r(s) for n, s in zip(mc.joint_names, mc.share_axis)},
        },
        "sweep": {"joint": study.sweep.joint,
                  "ratio_min": {n: float(f"{v:.4g}") for n, v in zip(jb.joint_names, study.sweep.ratio.min(0))},
                  "ratio_max": {n: float(f"{v:.4g}") for n, v in zip(jb.joint_names, study.sweep.ratio.max(0))}},
        "table3": None,
    }
    if study.has_table3:
        t3 = acc.table3_summary()
        out["table3"] = {k: {m: t3[k][m] for m in ("mean", "std", "mean_abs", "max_abs")} for k in t3}
    return out


# ---------------------------------------------------------------------------
# Table 3 beside the budget
# ---------------------------------------------------------------------------


def table3_rows(study: Study) -> list[dict[str, object]]:
    """One row per Table 3 quantity: budget (tip and entry) and the five measured deviations."""
    mc, jb = study.monte_carlo, study.jacobian
    t3 = acc.table3_summary() if study.has_table3 else {}
    tip, entry = mc.tip_stats(), mc.entry_stats()
    rows = []
    for i, a in enumerate(_AXES):
        rows.append({"quantity": f"{a.upper()} (mm)", "tip": tip[a], "entry": entry[a],
                     "worst": float(jb.worst_tip_mm[i]), "table3": t3.get(a)})
    rows.append({"quantity": "insertion (mm)", "tip": acc.ErrorStats.of(mc.depth_err_mm), "entry": None,
                 "worst": jb.worst_depth_mm, "table3": t3.get("insertion")})
    rows.append({"quantity": "angle (°)", "tip": acc.ErrorStats.of(mc.angle_err_deg), "entry": None,
                 "worst": jb.worst_angle_deg, "table3": t3.get("angle")})
    return rows


def _verdict(study: Study) -> list[str]:
    """What the numbers say about Table 3, written from the numbers themselves."""
    mc = study.monte_carlo
    t3 = acc.table3_summary()
    tip = mc.tip_stats()
    lines = []
    p95 = max(tip[a].p95 for a in _AXES)
    mx = max(tip[a].max for a in _AXES)
    lines.append(f"- Magnitude: ±{study.tol_deg:g}° on every servo spreads the tip by σ = "
                 + ", ".join(f"{tip[a].std:.2f}" for a in _AXES) + " mm (X, Y, Z); 95 % of placements "
                 f"stay within {p95:.2f} mm on every axis and the largest of {mc.n} draws is {mx:.2f} mm. "
                 "That covers the paper's \"0.1 to 3.8 mm in each of X, Y, Z\" (section 6); Table 3's own "
                 f"largest deviation is {max(t3[a]['max_abs'] for a in _AXES):.2f} mm.")
    for i, a in enumerate(_AXES):
        m, s = t3[a]["mean"], t3[a]["std"]
        sem = s / np.sqrt(5)
        lines.append(f"- {a.upper()}: measured mean {m:+.2f} mm ({abs(m) / sem:.1f} standard errors from 0), "
                     f"scatter σ {s:.2f} mm; budget σ {tip[a].std:.2f} mm.")
    dep, ang = acc.ErrorStats.of(mc.depth_err_mm), acc.ErrorStats.of(mc.angle_err_deg)
    lines.append(f"- Insertion: measured σ {t3['insertion']['std']:.2f} mm against a budget σ of {dep.std:.3f} mm "
                 f"(d10's servo alone); angle: measured σ {t3['angle']['std']:.2f}°, mean "
                 f"{t3['angle']['mean']:+.2f}°, against a budget σ of {ang.std:.2f}°.")
    lines.append("- The deadband is zero-mean, so it cannot make a consistent offset; an offset many standard "
                 "errors from zero, or a scatter well above the budget, points to something else "
                 "(calibration, compliance, the 3D-printed racks, the camera measurement).")
    return lines


# ---------------------------------------------------------------------------
# Figures (matplotlib's object API: no display, no pyplot state)
# ---------------------------------------------------------------------------


def _figure(size: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy: loaded only when a figure is drawn
    from matplotlib.figure import Figure  # heavy: loaded only when a figure is drawn

    fig = Figure(figsize=size, constrained_layout=True)
    FigureCanvasAgg(fig)
    return fig


def plot_tip_errors(study: Study, path: Path) -> Path:
    """Histograms of the Monte-Carlo tip, depth and angle errors; Table 3's five deviations on top."""
    mc = study.monte_carlo
    t3 = acc.table3_summary() if study.has_table3 else None
    norm3 = None
    if t3 is not None:
        norm3 = np.linalg.norm(np.array([t3[a]["deviations"] for a in _AXES]), axis=0)
    panels = [(mc.tip_err_mm[:, i], f"tip {a.upper()} error (mm)", t3[a]["deviations"] if t3 else None)
              for i, a in enumerate(_AXES)]
    panels += [(np.linalg.norm(mc.tip_err_mm, axis=1), "tip 3-D error (mm)", norm3),
               (mc.depth_err_mm, "insertion depth error (mm)", t3["insertion"]["deviations"] if t3 else None),
               (mc.angle_err_deg, "insertion angle error (°)", t3["angle"]["deviations"] if t3 else None)]
    fig = _figure((13.0, 7.0))
    axes = fig.subplots(2, 3)
    for ax, (data, label, measured) in zip(axes.flat, panels):
        lo, hi = float(np.min(data)), float(np.max(data))
        if measured is not None:
            lo, hi = min(lo, min(measured)), max(hi, max(measured))
        pad = 0.05 * (hi - lo) if hi > lo else 1.0
        ax.hist(data, bins=80, range=(lo - pad, hi + pad), color="#4C72B0", alpha=0.8,
                label=f"budget ({mc.n} draws)")
        if measured is not None:
            for k, v in enumerate(measured):
                ax.axvline(v, color="#DD8452", lw=2.0, label="Table 3 (measured)" if k == 0 else None)
        ax.set_xlabel(label)
        ax.set_ylabel("draws")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=8, loc="upper left")
    fig.suptitle(f"{study.robot_name}: needle error from ±{study.tol_deg:g}° servos ({mc.distribution})")
    fig.savefig(path, dpi=100)
    return Path(path)


def plot_shares(study: Study, path: Path) -> Path:
    """Each joint's share of the tip and axis variance: Monte Carlo beside the Jacobian."""
    mc, jb = study.monte_carlo, study.jacobian
    names = list(mc.joint_names)
    x = np.arange(len(names))
    fig = _figure((max(6.0, 0.9 * len(names) + 2.0), 4.2))
    ax = fig.subplots()
    w = 0.27
    ax.bar(x - w, mc.share_tip, w, label="tip variance (Monte Carlo)", color="#4C72B0")
    ax.bar(x, jb.share_tip, w, label="tip variance (Jacobian)", color="#8FAADC")
    ax.bar(x + w, mc.share_axis, w, label="axis variance (Monte Carlo)", color="#C44E52")
    ax.set_xticks(x, names)
    ax.set_ylabel("share")
    ax.set_ylim(0, 1)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{study.robot_name}: which joint's tolerance the needle error comes from")
    fig.savefig(path, dpi=100)
    return Path(path)


def plot_sweep(sweep: acc.Sweep, path: Path) -> Path:
    """Seed 003 eqs 12–14 along the sweep: tip motion per ε, and θ and ψ change, for every joint."""
    fig = _figure((15.5, 4.3))
    axes = fig.subplots(1, 3)
    xs = sweep.values_display
    j = sweep.joint_names.index(sweep.joint)
    xunit = "mm" if sweep.kinds[j] == "prismatic" else "°"
    for k, name in enumerate(sweep.joint_names):
        unit = "mm/mm" if sweep.kinds[k] == "prismatic" else "mm/°"
        axes[0].plot(xs, np.maximum(sweep.ratio[:, k], 1e-12), label=f"{name} ({unit})")
        axes[1].plot(xs, sweep.theta_change_deg[:, k], label=name)
        axes[2].plot(xs, sweep.psi_change_deg[:, k], label=name)
    from matplotlib.ticker import FormatStrFormatter  # heavy: loaded only when a figure is drawn

    positive = sweep.ratio[sweep.ratio > 0]
    if positive.size and positive.max() > 100 * positive.min():  # e.g. the paper's q2 at 5e-5 beside q3 at 20
        axes[0].set_yscale("log")
        axes[0].yaxis.set_major_formatter(FormatStrFormatter("%g"))
    else:
        axes[0].set_ylim(bottom=0)
    axes[0].set_ylabel("tip motion per ε (eq 12)")
    axes[1].set_ylabel("θ change per ε (°, eq 14)")
    axes[2].set_ylabel("ψ change per ε (°, eq 13)")
    for ax in axes:
        ax.set_xlabel(f"{sweep.joint} ({xunit})")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=8)
    fig.suptitle(f"{sweep.robot}: each joint stepped by ε = 0.05 mm or 0.05° along a sweep of {sweep.joint}")
    fig.savefig(path, dpi=100)
    return Path(path)


# ---------------------------------------------------------------------------
# Markdown and HTML
# ---------------------------------------------------------------------------


def _f(v: Optional[float], nd: int = 3) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def acceptance_limits() -> tuple[float, float]:
    """Seed 000's acceptance limits (mm per axis and depth, degrees), as trials judge them."""

    a = AcceptanceConfig()
    return a.position_mm, a.angle_deg


def over_limit(study: Study) -> list[str]:
    """Each budget figure (tip max, worst case) beyond the acceptance limit, in words."""
    pos, ang = acceptance_limits()
    out = []
    for row in table3_rows(study):
        angle = row["quantity"].startswith("angle")
        limit, unit = (ang, "°") if angle else (pos, " mm")
        for label, v in (("the largest Monte Carlo |error|", row["tip"].max),
                         ("the worst case", row["worst"])):
            if v is not None and abs(v) > limit:
                out.append(f"{row['quantity'].split(' (')[0]}: {label} {abs(v):.3f}{unit} is over the "
                           f"{limit:g}{unit} acceptance limit")
    return out


def _flag(v: Optional[float], limit: float, nd: int = 3) -> str:
    """A figure, bold and marked when it is over its acceptance limit."""
    return f"**{_f(v, nd)} ⚠**" if v is not None and abs(v) > limit else _f(v, nd)


def render_markdown(study: Study, figures: dict[str, str]) -> str:
    mc, jb, sw = study.monte_carlo, study.jacobian, study.sweep
    ratios = acc.servo_transmissions(study.robot)
    L = [f"# Accuracy budget: {study.robot_name}", "",
         f"- pose: {study.pose_note}",
         f"- servo tolerance ±{study.tol_deg:g}°, joint errors {mc.distribution} "
         f"({mc.n} draws, seed {mc.seed}); lengths in mm, angles in degrees", ""]
    L += ["## Joints and tolerances", "",
          "| joint | type | value | transmission (per servo rad) | tolerance ± | σ |", "|---|---|---:|---:|---:|---:|"]
    for n, k, v, r, t, s in zip(jb.joint_names, jb.kinds, study.q, ratios, jb.tolerances, jb.sigma):
        if k == "prismatic":
            L.append(f"| {n} | {k} | {v * 1e3:.3f} mm | {r * 1e3:.4g} mm | {t * 1e3:.4f} mm | {s * 1e3:.4f} mm |")
        else:
            L.append(f"| {n} | {k} | {np.degrees(v):.3f}° | {r:.4g} | {np.degrees(t):.4f}° | {np.degrees(s):.4f}° |")
    t3_cols = study.has_table3
    L += ["", "## Budget against the measured deviations" if t3_cols else "## Budget", ""]
    if t3_cols:
        L.append("Table 3 of seed 000: five repeats of Target 1, measured minus asked; its X, Y, Z are "
                 "the target point the needle enters at, so the budget gives both the tip and the entry point.")
        L.append("")
    head = "| quantity | tip σ | tip p95 of \\|error\\| | tip max \\|error\\| | worst case | entry σ |"
    rule = "|---|---:|---:|---:|---:|---:|"
    if t3_cols:
        head += " Table 3 mean | Table 3 σ | Table 3 mean abs | Table 3 max abs |"
        rule += "---:|---:|---:|---:|"
    L += [head, rule]
    pos, ang = acceptance_limits()
    for row in table3_rows(study):
        s, e, t = row["tip"], row["entry"], row["table3"]
        limit = ang if row["quantity"].startswith("angle") else pos
        line = (f"| {row['quantity']} | {_f(s.std)} | {_f(s.p95)} | {_flag(s.max, limit)} | "
                f"{_flag(row['worst'], limit)} | {_f(e.std if e else None)} |")
        if t3_cols:
            line += (f" {_f(t['mean'] if t else None, 2)} | {_f(t['std'] if t else None, 2)} | "
                     f"{_f(t['mean_abs'] if t else None, 2)} | {_f(t['max_abs'] if t else None, 2)} |")
        L.append(line)
    L += ["", f"σ is of the signed error; p95 and max are of its magnitude |error|, over {mc.n} "
          f"draws; the worst case puts every servo at the end of its tolerance that hurts most "
          f"(Jacobian). Marked ⚠: over the acceptance limit ({pos:g} mm per axis and depth, {ang:g}°)."]
    for words in over_limit(study):
        L.append(f"- **{words}**")
    ax = acc.ErrorStats.of(mc.axis_err_deg)
    L += ["", f"Needle axis error (angle between the axes): RMS {ax.rms:.3f}°, p95 {ax.p95:.3f}°, "
          f"max {ax.max:.3f}°; worst case (Jacobian) {jb.worst_axis_deg:.3f}°. "
          f"First order (Jacobian RSS) σ: " + ", ".join(f"{v:.3f}" for v in jb.rss_tip_mm) + " mm.", ""]
    if study.has_table3:
        L += ["## What the numbers say", "", *_verdict(study), ""]
    L += [f"![needle error histograms]({figures['tips']})", "", "## Which joints matter", "",
          "| joint | tip share (Monte Carlo) | tip share (Jacobian) | axis share (Monte Carlo) | "
          "worst-case tip contribution (mm) |", "|---|---:|---:|---:|---:|"]
    for i, n in enumerate(jb.joint_names):
        L.append(f"| {n} | {mc.share_tip[i]:.4f} | {jb.share_tip[i]:.4f} | {mc.share_axis[i]:.4f} | "
                 f"{np.linalg.norm(jb.contrib_tip_mm[i]):.4f} |")
    L += ["", f"Single-joint variances add up to {mc.additivity_tip:.4f} of the total tip variance "
          "(1 means the joints act independently and linearly).", "",
          f"![joint shares]({figures['shares']})", "",
          "## Seed 003 eqs 12–14 along a sweep", "",
          f"{sw.joint} swept over {sw.values_display[0]:.3f} … {sw.values_display[-1]:.3f} "
          f"{'mm' if sw.kinds[sw.joint_names.index(sw.joint)] == 'prismatic' else '°'} "
          f"({len(sw.values)} points); at each point every joint is stepped by ε and the tip motion "
          "(eq 12) and the change of ψ (eq 13) and θ (eq 14) are recorded.", "",
          "| joint | ε | tip motion / ε min | max | max abs θ change (°) | max abs ψ change (°) |",
          "|---|---:|---:|---:|---:|---:|"]
    for k, n in enumerate(sw.joint_names):
        e = f"{sw.eps_display[k]:.3g} {'mm' if sw.kinds[k] == 'prismatic' else '°'}"
        L.append(f"| {n} | {e} | {sw.ratio[:, k].min():.4g} | {sw.ratio[:, k].max():.4g} | "
                 f"{np.abs(sw.theta_change_deg[:, k]).max():.3g} | {np.abs(sw.psi_change_deg[:, k]).max():.3g} |")
    L += ["", f"![eqs 12-14 sweep]({figures['sweep']})", ""]
    return "\n".join(L)


def write_report(study: Study, out: Path) -> dict[str, Path]:
    """tip_errors.png, shares.png, sweep.png, report.md, report.html, budget.json, samples.npz in ``out``."""

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures = {"tips": "tip_errors.png", "shares": "shares.png", "sweep": "sweep.png"}
    plot_tip_errors(study, out / figures["tips"])
    plot_shares(study, out / figures["shares"])
    plot_sweep(study.sweep, out / figures["sweep"])
    md = render_markdown(study, figures)
    (out / "report.md").write_text(md)
    images = {v: out / v for v in figures.values()}
    (out / "report.html").write_text(markdown_to_html(md, images, f"Accuracy budget: {study.robot_name}"))
    (out / "budget.json").write_text(json.dumps(summary(study), indent=2) + "\n")
    mc = study.monte_carlo
    np.savez_compressed(out / "samples.npz", joint_names=np.array(mc.joint_names), q=mc.q,
                        tolerances=mc.tolerances, joint_err=mc.joint_err, tip_err_mm=mc.tip_err_mm,
                        entry_err_mm=mc.entry_err_mm, depth_err_mm=mc.depth_err_mm,
                        angle_err_deg=mc.angle_err_deg, axis_err_deg=mc.axis_err_deg)
    paths = {k: out / v for k, v in figures.items()}
    paths.update(markdown=out / "report.md", html=out / "report.html", json=out / "budget.json",
                 samples=out / "samples.npz")
    return paths
