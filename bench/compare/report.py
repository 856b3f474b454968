"""The sim-vs-real report: Fig. 12-style profiles, Table 3/4-style needle tables, tracking, verdict.

Writes ``profiles.png``, ``tracking.png``, ``needle.png``, ``report.md``,
``report.html`` (one self-contained page, figures embedded) and
``summary.json`` (everything in the tables, machine-readable).

Display units: joint angles in degrees (the train as its arc angle ε, with
its d2 equivalent stated), slides in mm, lags in ms, the needle in mm and
degrees.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from bench.compare.analysis import TABLE4_CURRENT_RESEARCH_MM, Comparison, Side
from bench.compare.figures import (
    display_scale,
    plot_needle_scatter,
    plot_profiles,
    plot_tracking,
    profiles_caption,
    relative_rms,
)
from bench.compare.prediction import Prediction
from bench.compare.prediction_report import plot_prediction, prediction_markdown
from bench.compare.signals import nanmean
from bench.core.log import TrialLog
from bench.core.outcome import SETTLED_WINDOW_S
from bench.kinematics.arc_train import TABLE3_MEASURED, TABLE3_TARGET, table3_deviations, train_pose
from bench.report.trial import markdown_to_html
from bench.scene.dynamics import gravity_torques

__all__ = ["gravity_loads", "render_markdown", "write_compare_report"]


def _num(v: float, nd: int = 3) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.{nd}f}"


# ---------------------------------------------------------------------------
# Gravity loads (what the paper calls the torque requirement)
# ---------------------------------------------------------------------------


def gravity_loads(comparison: Comparison) -> Optional[np.ndarray]:
    """Static gravity torque/force per joint at the commanded insertion pose (N·m or N),
    from PyBullet's inverse dynamics on the robot's URDF; None when it cannot be computed."""

    meta = comparison.subject.logs[0].metadata
    try:
        return np.abs(gravity_torques(str(meta["robot"]), np.asarray(meta["q_insert"], dtype=float),
                                      (meta.get("config") or {}).get("urdf_dir", "urdf")))
    except Exception:  # noqa: BLE001 - a column of the report, never worth losing the report for
        return None


def _spearman(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3:
        return math.nan
    rx = np.argsort(np.argsort(x[ok])).astype(float)
    ry = np.argsort(np.argsort(y[ok])).astype(float)
    return float(np.corrcoef(rx, ry)[0, 1])


# ---------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------


def _target_row(log: TrialLog) -> list[float]:
    t = log.metadata["target"]
    e = np.asarray(t["entry_m"], dtype=float) * 1e3
    return [float(e[0]), float(e[1]), float(e[2]), float(t["depth_m"]) * 1e3, math.degrees(t["angle_rad"])]


def _placed(o) -> list[str]:
    """A placement as Table 3 gives it: entry X, Y, Z, insertion and angle (— when none)."""
    return ["—"] * 5 if o is None else [f"{v:.2f}" for v in (*o.entry_mm, o.depth_mm, o.angle_deg)]


def _table3(side: Side) -> list[str]:
    inp = _target_row(side.logs[0])
    outcomes, _ = side.table3
    head = ("| Sr. No | input X (mm) | input Y (mm) | input Z (mm) | input insertion (mm) | input angle (°) "
            "| output X (mm) | output Y (mm) | output Z (mm) | output insertion (mm) | output angle (°) |")
    title = f"### {side.label}"
    if side.has_cameras:
        title += " — output measured by the cameras (as seed 000's Table 3), the encoders' beside"
        head += (" encoders' X (mm) | encoders' Y (mm) | encoders' Z (mm) | encoders' insertion (mm) "
                 "| encoders' angle (°) | encoders to cameras (mm) |")
    lines = [title, "", head, "|---|" + "---:|" * (10 + 6 * side.has_cameras)]
    for i, o in enumerate(outcomes):
        row = [str(i + 1), *(f"{v:.2f}" for v in inp), *_placed(o)]
        if side.has_cameras:
            cam = side.cameras[i] or {}
            gap = cam.get("encoder_gap_mm")
            why = cam.get("problem") or ("the trial had no cameras" if not cam else "")
            seen = "—" if gap is None else f"{gap:.2f}" + (" (flagged)" if cam.get("flag") else "")
            row += [*_placed(side.outcomes[i]), seen + (f" (no measurement: {why})" if why else "")]
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def _deviation_table(side: Side, cameras: bool = False) -> list[str]:
    outcomes, s = (side.seen, side.seen_stats) if cameras else (side.outcomes, side.stats)
    whose = (" — by the cameras" if cameras else " — by the encoders") if side.has_cameras else ""
    lines = [f"### {side.label}{whose}", "",
             "| repeat | ΔX (mm) | ΔY (mm) | ΔZ (mm) | Δinsertion (mm) | Δangle (°) | tip ΔX (mm) "
             "| tip ΔY (mm) | tip ΔZ (mm) | within limits |", "|---|" + "---:|" * 8 + "---|"]
    for i, (o, done, why) in enumerate(zip(outcomes, side.completed, side.reasons)):
        if o is None:
            if cameras and done:
                why = (side.cameras[i] or {}).get("problem") or "the trial had no cameras"
            lines.append(f"| {i + 1} | " + " | ".join(["—"] * 8) + f" | no placement ({why}) |")
            continue
        verdict = "yes" if o.passed and done else ("no" if done else f"no: stopped early ({why})")
        vals = (*o.entry_deviation_mm, o.depth_deviation_mm, o.angle_deviation_deg, *o.tip_deviation_mm)
        lines.append(f"| {i + 1} | " + " | ".join(f"{v:+.3f}" for v in vals) + f" | {verdict} |")
    for key, label in (("mean", "mean"), ("mean_abs", "mean abs"), ("max_abs", "max abs"),
                       ("std", "std")):
        vals = (*np.atleast_1d(s["entry_mm"][key]), s["depth_mm"][key], s["angle_deg"][key],
                *np.atleast_1d(s["tip_mm"][key]))
        lines.append(f"| **{label}** | " + " | ".join(_num(float(v)) for v in vals) + " | |")
    return lines + [""]


def _table4(comparison: Comparison) -> list[str]:
    t3 = table3_deviations()
    ref, sub = comparison.reference, comparison.subject
    by = lambda side: ", cameras" if side.has_cameras else ""  # noqa: E731 - whose tip each column is
    lines = ["| Deviation in | " + f"{ref.label} (mean abs{by(ref)}) | {sub.label} (mean abs{by(sub)}) | "
             f"{sub.label} (max abs{by(sub)}) | seed 000 Table 3 (mean abs, 5 repeats) | "
             "seed 000 Table 4: current research |", "|---|---:|---:|---:|---:|---:|"]
    rows = (("X axis (mm)", "entry_mm", 0, "x"), ("Y axis (mm)", "entry_mm", 1, "y"),
            ("Z axis (mm)", "entry_mm", 2, "z"), ("Depth of insertion (mm)", "depth_mm", None, "insertion"),
            ("Angle of insertion (°)", "angle_deg", None, "angle"))
    for label, key, k, t3k in rows:
        def pick(side: Side, what: str) -> float:
            v = np.atleast_1d(side.table3[1][key][what])
            return float(v[k] if k is not None else v[0])

        paper = TABLE4_CURRENT_RESEARCH_MM.get(t3k)
        lines.append(f"| {label} | {_num(pick(ref, 'mean_abs'), 2)} | {_num(pick(sub, 'mean_abs'), 2)} | "
                     f"{_num(pick(sub, 'max_abs'), 2)} | {np.abs(t3[t3k]).mean():.2f} | "
                     f"{'—' if paper is None else f'{paper:g}'} |")
    return lines + ["", "Table 3's repeats as published (input X 0, Y 88.2, Z 66 mm, insertion 30.1 mm at "
                    "47°): X " + "/".join(f"{v:.2f}" for v in TABLE3_MEASURED["x"]) + ", Y "
                    + "/".join(f"{v:.2f}" for v in TABLE3_MEASURED["y"]) + ", Z "
                    + "/".join(f"{v:.2f}" for v in TABLE3_MEASURED["z"]) + " mm, insertion "
                    + "/".join(f"{v:.2f}" for v in TABLE3_MEASURED["insertion"]) + " mm, angle "
                    + "/".join(f"{v:.2f}" for v in TABLE3_MEASURED["angle"])
                    + f"°. Table 4's column averages the paper's targets, Table 3 only Target 1 "
                      f"(target {TABLE3_TARGET['y']:g} mm in Y).", ""]


def _cameras_paragraph(side: Side) -> list[str]:
    """What the cameras said of a side's repeats: how many they placed within the limits, and each
    repeat's gap between the encoders' tip and theirs ([] when the trials had no cameras)."""
    if not side.has_cameras:
        return []
    gaps = []
    for i, c in enumerate(side.cameras):
        c = c or {}
        gap = c.get("encoder_gap_mm")
        gaps.append(f"{i + 1}: " + (f"{gap:.2f} mm" + (" flagged" if c.get("flag") else "") if gap is not None
                                    else f"none ({c.get('problem') or 'the trial had no cameras'})"))
    within = sum(1 for o in side.seen if o is not None and o.passed)
    by_encoders = sum(1 for o in side.outcomes if o is not None and o.passed)
    return [f"By the cameras, {within} of {len(side.logs)} {side.label} repeats within the limits; by the "
            f"encoders, {by_encoders}. The gap between the encoders' tip and the cameras' (flagged beyond "
            "the two tips' uncertainties together), per repeat: " + "; ".join(gaps) + ".", ""]


def _tracking_table(comparison: Comparison, side: Side, loads: Optional[np.ndarray]) -> list[str]:
    kinds = [r.kind for r in comparison.robot.chain.rows]
    head = ("| joint | unit | lag (ms) | RMS error | RMS / excursion (%) | max error | final error "
            "| placement error | settling (s) | band | hold effort (median abs) |")
    if loads is not None:
        head += " gravity load |"
    lines = [f"### {side.label} (mean over {len(side.logs)} repeat(s))", "", head,
             "|---|---|" + "---:|" * (9 + (loads is not None))]
    m = {a: side.mean_tracking(a) for a in ("lag_s", "rms", "max_abs", "final", "placement", "settling_s",
                                            "band", "excursion", "hold_effort")}
    for j, name in enumerate(comparison.joint_names):
        f, unit = display_scale(kinds[j])
        rel = 100 * m["rms"][j] / m["excursion"][j] if np.isfinite(m["lag_s"][j]) else math.nan
        eu = "N·m" if kinds[j] == "revolute" else "N"
        row = (f"| {name} | {unit} | {_num(m['lag_s'][j] * 1e3, 1)} | {_num(m['rms'][j] * f, 4)} | "
               f"{_num(rel, 2)} | {_num(m['max_abs'][j] * f, 4)} | {_num(m['final'][j] * f, 4)} | "
               f"{_num(m['placement'][j] * f, 4)} | {_num(m['settling_s'][j], 3)} | "
               f"±{_num(m['band'][j] * f, 4)} | {_num(m['hold_effort'][j], 3)} {eu} |")
        if loads is not None:
            row += f" {loads[j]:.3f} {eu} |"
        lines.append(row)
    return lines + [""]


def _load_paragraph(comparison: Comparison, loads: Optional[np.ndarray]) -> list[str]:
    if loads is None:
        return []
    sub = comparison.subject
    lag = sub.mean_tracking("lag_s")
    rel = relative_rms(sub)
    moving = np.isfinite(lag)
    names = [n for n, ok in zip(comparison.joint_names, moving) if ok]
    order = sorted(names, key=lambda n: -loads[comparison.joint_names.index(n)])
    rho_lag = _spearman(loads[moving], lag[moving])
    rho_rms = _spearman(loads[moving], rel[moving])
    return ["Torque requirement and tracking (seed 000: the joints that need high torque deviate from "
            "the 'S' profile): the joints that move, by static gravity load at the target, are "
            + ", ".join(f"{n} ({loads[comparison.joint_names.index(n)]:.2f})" for n in order)
            + f". On the {sub.label}, the rank correlation of gravity load with lag is "
            f"{_num(rho_lag, 2)} and with RMS error relative to the excursion {_num(rho_rms, 2)}.", ""]


def _profile_table(comparison: Comparison) -> list[str]:
    kinds = [r.kind for r in comparison.robot.chain.rows]
    segs = list(comparison.subject.logs[0].segment_names)
    rms, mx, cmd = (comparison.profile_mean(a) for a in ("rms", "max_abs", "cmd_rms"))
    by_seg = {s: nanmean(np.array([[p.rms_by_segment.get(s, np.nan) for p in pair]
                                    for pair in comparison.profile], dtype=float))
              if comparison.profile else np.full(len(kinds), np.nan) for s in segs}
    lines = [f"{comparison.subject.label} measured minus {comparison.reference.label} measured, both aligned "
             f"at the first commanded motion ({comparison.align}) and resampled on a common time base "
             f"(mean over {len(comparison.profile)} pair(s) of repeats). The last column is the same for "
             f"the commanded profiles: the plans start from the measured pose, which differs.", "",
             "| joint | unit | RMS | max | " + " | ".join(f"RMS in {s}" for s in segs)
             + " | RMS of the commanded difference |", "|---|---|" + "---:|" * (3 + len(segs))]
    for j, name in enumerate(comparison.joint_names):
        f, unit = display_scale(kinds[j])
        lines.append(f"| {name} | {unit} | {_num(rms[j] * f, 4)} | {_num(mx[j] * f, 4)} | "
                     + " | ".join(_num(by_seg[s][j] * f, 4) for s in segs) + f" | {_num(cmd[j] * f, 4)} |")
    return lines + [""]


def _contribution_table(comparison: Comparison) -> list[str]:
    sub = comparison.subject
    reps = [c for c in sub.contributions if c is not None]
    if not reps:
        return ["No repeat placed the needle: nothing to attribute.", ""]
    kinds = [r.kind for r in comparison.robot.chain.rows]
    ranking = sub.contribution_ranking()
    names = comparison.joint_names
    lines = ["Each joint's placement error (measured − commanded at the placement) through the FK "
             "Jacobian at the commanded pose, mean over the placed repeats; ranked by its share of "
             "the tip deviation.", "",
             "| rank | joint | placement error | tip ΔX (mm) | tip ΔY (mm) | tip ΔZ (mm) | tip norm (mm) "
             "| angle (°) | depth (mm) |", "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for rank, (name, _) in enumerate(ranking, 1):
        j = names.index(name)
        f, unit = display_scale(kinds[j])
        err = np.mean([rep[j].error for rep in reps]) * f
        tip = np.mean([rep[j].tip_mm for rep in reps], axis=0)
        norm = np.mean([rep[j].tip_norm_mm for rep in reps])
        ang = np.mean([rep[j].angle_deg for rep in reps])
        dep = np.mean([rep[j].depth_mm for rep in reps])
        lines.append(f"| {rank} | {name} | {err:+.4f} {unit} | {tip[0]:+.3f} | {tip[1]:+.3f} | "
                     f"{tip[2]:+.3f} | {norm:.3f} | {ang:+.4f} | {dep:+.4f} |")
    pred = np.mean([np.sum([c.tip_mm for c in rep], axis=0) for rep in reps], axis=0)
    got = np.atleast_1d(sub.stats["tip_mm"]["mean"])
    lines += ["", f"First-order sum of the contributions (mean over repeats): tip "
              f"({pred[0]:+.3f}, {pred[1]:+.3f}, {pred[2]:+.3f}) mm; achieved mean tip deviation "
              f"({got[0]:+.3f}, {got[1]:+.3f}, {got[2]:+.3f}) mm (the rest: the target's own IK residual "
              f"and second-order terms).", ""]
    return lines


def _train_note(comparison: Comparison) -> list[str]:
    if getattr(comparison.robot, "name", "") != "arc-train":
        return []

    eps = float(comparison.subject.logs[0].metadata["q_insert"][0])
    h = 1e-6
    rate = (train_pose(eps + h, comparison.robot.params).d2 - train_pose(eps - h, comparison.robot.params).d2) / (2 * h)
    return [f"The train's row is its arc angle ε in degrees; at the target 1° of ε is "
            f"{abs(rate) * math.pi / 180 * 1e3:.2f} mm of d2 (the profiles plot d2 as the paper does).", ""]


def render_markdown(comparison: Comparison, figures: dict[str, str], title: str,
                    notes: Sequence[str] = (), lost: Sequence[dict] = (),
                    loads: Optional[np.ndarray] = None) -> str:
    """The whole report as Markdown (the subset :func:`bench.report.trial.markdown_to_html` renders);
    ``loads``: the joints' static gravity loads (:func:`gravity_loads`), if known."""
    ref, sub = comparison.reference, comparison.subject
    log = sub.logs[0]
    meta = log.metadata
    cfg = meta.get("config") or {}
    plan = cfg.get("plan") or {}
    pos, ang = comparison.acceptance
    verdict = "PASSED" if comparison.passed else "FAILED"
    t = _target_row(log)
    lines = [f"# {title}: {verdict}", "",
             f"- robot: {meta.get('robot')}; target: X {t[0]:.1f}, Y {t[1]:.1f}, Z {t[2]:.1f} mm, "
             f"insertion {t[3]:.1f} mm at {t[4]:.1f}°",
             f"- plan: {plan.get('trajectory', '?')}, velocity scale {plan.get('velocity_scale', '?')}, "
             f"settle {plan.get('settle_s', '?')} s; control rate: {ref.label} "
             f"{1 / float(ref.logs[0].metadata.get('control_period', float('nan'))):g} Hz, {sub.label} "
             f"{1 / float(meta.get('control_period', float('nan'))):g} Hz",
             f"- repeats: {len(ref.logs)} on {ref.label} ({ref.backend}, {ref.rig}), {len(sub.logs)} on "
             f"{sub.label} ({sub.backend}, {sub.rig}: what each trial's record says ran it)",
             f"- acceptance: {pos:g} mm per axis and depth, {ang:g}° in angle"]
    lines += [f"- {n}" for n in notes]
    for a in lost:
        lines.append(f"- lost attempt of repeat {a['repeat']} (run again): {a['reason']} — `{a['run_dir']}`")
    lines.append("")
    judged, s = sub.judged
    worst_tip = np.atleast_1d(s["tip_mm"]["max_abs"])
    worst_entry = np.atleast_1d(s["entry_mm"]["max_abs"])
    ranking = sub.contribution_ranking()
    tip = "the cameras' tip" if sub.judged_by == "camera" else "the encoders' tip"
    lines += ["## Verdict", "",
              f"**{verdict}**: {sum(o is not None and o.passed for o in judged)} of {len(sub.logs)} "
              f"{sub.label} repeats within {pos:g} mm / {ang:g}° by {tip} (acceptance.by)"
              + ("" if all(sub.completed) else " (some repeats stopped early)")
              + f". Worst |deviation|: entry X {_num(worst_entry[0], 2)}, Y {_num(worst_entry[1], 2)}, "
              f"Z {_num(worst_entry[2], 2)} mm; tip X {_num(worst_tip[0], 2)}, Y {_num(worst_tip[1], 2)}, "
              f"Z {_num(worst_tip[2], 2)} mm; depth {_num(float(s['depth_mm']['max_abs']), 2)} mm; angle "
              f"{_num(float(s['angle_deg']['max_abs']), 3)}°.", ""]
    lines += _cameras_paragraph(sub)
    if ranking:
        lines += ["Joints that explain most of the tip deviation (placement error through the FK Jacobian): "
                  + ", ".join(f"{n} {v:.2f} mm" for n, v in ranking[:4]) + ".", ""]
    lines += ["## Needle placement per repeat (Table 3 layout)", ""]
    for side in (sub, ref):
        lines += _table3(side)
    lines += ["## Deviations over repeats", "",
              "Entry point (Table 3's X, Y, Z), insertion depth and angle, and the needle tip, achieved "
              "minus target; by the encoders, each repeat placed where its readings put it (the median "
              f"reading over the last {SETTLED_WINDOW_S:g} s of the insertion's settle); by the cameras, "
              "where the two cameras measured the needle as the insertion ended.", ""]
    for side in (sub, ref):
        if side.has_cameras:
            lines += _deviation_table(side, cameras=True)
        lines += _deviation_table(side)
    lines += ["## Average deviation (Table 4 layout)", ""] + _table4(comparison)
    lines += ["## Joint profiles (Fig. 12 layout)", "", profiles_caption(comparison), "",
              f"![joint profiles]({figures['profiles']})", ""]
    lines += ["## Tracking per joint", "",
              "Error = measured − commanded. Lag: delay of the measured velocity behind the commanded "
              "(cross-correlation peak, sub-sample); — for a joint whose command hardly moves. Settling: "
              "after the joint's last move that is followed by a hold, the time until |error| stays "
              "within the band (the servo tolerance ±0.29° through the joint's transmission: a 10 mm "
              "pinion for slides, the same pinion on the 200 mm arc for the train (±0.0145°); widened "
              "to 3σ of the sample noise) for the rest of the hold; — when it never does or the joint "
              "never moves. Placement error: at the placement window, where the needle is measured.", ""]
    lines += _train_note(comparison)
    for side in (sub, ref):
        lines += _tracking_table(comparison, side, loads)
    lines += _load_paragraph(comparison, loads)
    lines += [f"![tracking]({figures['tracking']})", ""]
    lines += [f"## {sub.label} vs {ref.label} profiles", ""] + _profile_table(comparison)
    lines += ["## What explains the deviation", ""] + _contribution_table(comparison)
    lines += [f"![needle deviation]({figures['needle']})", ""]
    lines += ["## Runs", ""]
    for side in (sub, ref):
        for i, (src, done, why) in enumerate(zip(side.sources, side.completed, side.reasons)):
            lines.append(f"- {side.label} {i + 1}: `{src}`" + ("" if done else f" — stopped early: {why}"))
    versions = meta.get("versions") or {}
    if versions:
        lines += ["", "## Versions", "", ", ".join(f"{k} {v}" for k, v in versions.items())]
    return "\n".join(lines) + "\n"


def _json_default(o: object) -> object:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"cannot store {type(o).__name__} in summary.json")


def write_compare_report(comparison: Comparison, out_dir: Path, title: str = "Sim vs real",
                         notes: Sequence[str] = (), lost: Sequence[dict] = (),
                         ideal: Optional[Comparison] = None,
                         prediction: Optional[Prediction] = None) -> dict[str, Path]:
    """profiles.png, tracking.png, needle.png, report.md, report.html and summary.json in ``out_dir``;
    with a servo model (``ideal`` and ``prediction``), prediction.png and its section too."""

    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    figures = {"profiles": "profiles.png", "tracking": "tracking.png", "needle": "needle.png"}
    plot_profiles(comparison, d / figures["profiles"])
    plot_tracking(comparison, d / figures["tracking"])
    plot_needle_scatter(comparison, d / figures["needle"])
    loads = gravity_loads(comparison)
    md = render_markdown(comparison, figures, title, notes, lost, loads)
    if ideal is not None and prediction is not None:
        figures["prediction"] = "prediction.png"
        plot_prediction(comparison, ideal, d / figures["prediction"])
        head, sep, rest = md.partition("## Joint profiles (Fig. 12 layout)")
        md = head + "\n".join(prediction_markdown(prediction, figures["prediction"])) + "\n" + sep + rest
    (d / "report.md").write_text(md)
    (d / "report.html").write_text(markdown_to_html(md, {v: d / v for v in figures.values()}, title))
    record = comparison.as_dict()
    record["gravity_load"] = None if loads is None else [float(v) for v in loads]
    record["notes"] = list(notes)
    record["lost_attempts"] = list(lost)
    if prediction is not None:
        record["prediction"] = prediction.as_dict()
    (d / "summary.json").write_text(json.dumps(record, indent=2, default=_json_default) + "\n")
    paths = {k: d / v for k, v in figures.items()}
    paths.update({"markdown": d / "report.md", "html": d / "report.html", "summary": d / "summary.json"})
    return paths
