"""Trial reports: Fig. 12-style joint profiles, a Table 3-style row, Markdown and self-contained HTML."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

import numpy as np

from bench.core.log import TrialLog
from bench.core.outcome import settled_position
from bench.core.result import PreparedTrial, TrialResult, write_result_json
from bench.kinematics.arc_train import train_pose
from bench.report.cameras import camera_markdown, draw_camera_views
from bench.report.panels import FIGURE_DPI, panel_figure, place_panels
from bench.report.twin import plot_twin, twin_markdown
from bench.scene.render import SIDE_VIEW, render_robot


def joint_display(robot, name: str, values: np.ndarray) -> tuple[np.ndarray, str, str]:
    """Values as the paper plots them: the train as d2 in mm, angles in degrees, slides in mm."""
    if name == "train" and getattr(robot, "name", "") == "arc-train":

        return np.asarray(train_pose(values, robot.params).d2) * 1e3, "d2 (mm)", "train d2"
    kind = {r.name: r.kind for r in robot.chain.rows}[name]
    if kind == "revolute":
        return np.degrees(values), "angle (°)", name
    return np.asarray(values) * 1e3, "position (mm)", name


#: Below this excursion (° or mm, as displayed) a joint did not move worth plotting.
STILL_EXCURSION = 0.01
#: A joint panel spans at least this (° or mm), so a joint that holds still is drawn as still.
STILL_PANEL_SPAN = 1.0


def largest_excursion(log: TrialLog, robot) -> float:
    """The largest commanded or measured excursion of any joint in the log (° or mm)."""
    if len(log) < 2:
        return 0.0
    worst = 0.0
    for name in log.joint_names:
        j = log.joint(name)
        for series in (log.q_cmd[:, j], log.q[:, j]):
            shown, _, _ = joint_display(robot, name, series)
            worst = max(worst, float(np.ptp(shown)))
    return worst


#: The two profiles of every joint panel: measured underneath, solid; commanded over it, dashed in
#: a contrasting colour, so it stays visible wherever the two agree (colour-blind safe pair).
MEASURED_STYLE = {"color": "#1f5fa8", "ls": "-", "lw": 1.6, "zorder": 2, "label": "measured"}
COMMANDED_STYLE = {"color": "#f28e1c", "ls": (0, (4, 2.5)), "lw": 1.8, "zorder": 3,
                   "label": "commanded (theoretical)"}
LEGEND_FONTSIZE = 11


def joint_figure(log: TrialLog, robot, title: str = ""):
    """The figure of :func:`plot_joint_profiles` (matplotlib), one panel a joint, one legend above."""
    names = log.joint_names
    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig, axes = panel_figure(rows, cols, 3.0 * rows + 0.6)
    t = log.time - (log.time[0] if len(log) else 0.0)
    for ax, name in zip(axes.flat, names):
        j = log.joint(name)
        cmd, unit, label = joint_display(robot, name, log.q_cmd[:, j])
        meas, _, _ = joint_display(robot, name, log.q[:, j])
        ax.plot(t, meas, **MEASURED_STYLE)
        ax.plot(t, cmd, **COMMANDED_STYLE)
        ax.set_title(label, y=1.0)  # at the frame's top: nothing above it to clear, so no search per draw
        ax.set_ylabel(unit)
        ax.ticklabel_format(axis="y", useOffset=False)  # values as read, not as offsets
        both = np.concatenate([cmd, meas])
        both = both[np.isfinite(both)]
        if both.size and np.ptp(both) < STILL_PANEL_SPAN:  # a joint that holds: encoder-tick dither
            mid = 0.5 * (both.max() + both.min())       # is a thin band, not a panel of colour
            ax.set_ylim(mid - STILL_PANEL_SPAN / 2, mid + STILL_PANEL_SPAN / 2)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    stops = [ev for ev in log.events if ev.kind in ("interlock", "abort")]
    for ev in stops[:1]:
        for ax in axes.flat[: len(names)]:
            ax.axvline(ev.time - (log.time[0] if len(log) else 0), color="k", ls=":", lw=1.0, zorder=4,
                       label=f"{ev.kind}: stopped here")
    height = fig.get_figheight()
    title_in = 0.4 if title else 0.0  # inches above the legend for the title
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=LEGEND_FONTSIZE,
               frameon=False, bbox_to_anchor=(0.5, 1.0 - title_in / height))
    heading = fig.suptitle(title, fontsize=13, y=1.0 - 0.08 / height, va="top") if title else None
    place_panels(fig, axes, len(names), top_in=title_in + 0.15, title=heading)
    return fig


def plot_joint_profiles(log: TrialLog, robot, path: Path, title: str = "") -> Path:
    """Commanded (theoretical) over measured profile of every joint, one panel each, as a PNG."""
    joint_figure(log, robot, title).savefig(path, dpi=FIGURE_DPI)
    return Path(path)


def _fmt(v: float, nd: int = 2) -> str:
    return f"{round(v, nd) + 0.0:.{nd}f}"  # no "-0.000"


def table3_markdown(target_mm: list[float], depth_mm: float, angle_deg: float, outcome) -> str:
    """Input and output target side by side, as seed 000 Table 3 (in mm)."""
    o = outcome
    head = ("| | entry point X (mm) | entry point Y (mm) | entry point Z (mm) | insertion (mm) | angle (°) |\n"
            "|---|---:|---:|---:|---:|---:|\n")
    rows = [
        ("input target", *target_mm, depth_mm, angle_deg),
        ("output (achieved)", *o.entry_mm, o.depth_mm, o.angle_deg),
        ("deviation", *o.entry_deviation_mm, o.depth_deviation_mm, o.angle_deviation_deg),
    ]
    body = "".join(f"| {r[0]} | " + " | ".join(_fmt(v, 3 if i < 5 else 3) for i, v in enumerate(r[1:]))
                   + " |\n" for r in rows)
    tip = (f"\nNeedle tip deviation (mm): X {_fmt(o.tip_deviation_mm[0], 3)}, "
           f"Y {_fmt(o.tip_deviation_mm[1], 3)}, Z {_fmt(o.tip_deviation_mm[2], 3)}.\n")
    return head + body + tip


def stop_markdown(result: "TrialResult", log: TrialLog) -> str:
    """What stopped a trial that did not complete: when, in which segment, why, how it was left."""
    t0 = log.time[0] if len(log) else 0.0
    stop = next((e for e in log.events if e.kind in ("interlock", "abort")), None)
    lines = []
    if stop is not None:
        seg = ""
        if len(log):
            k = min(int(np.searchsorted(log.time, stop.time)), len(log) - 1)
            names = log.segment_names
            if names and 0 <= int(log.segment[k]) < len(names):
                seg = f" during the {names[int(log.segment[k])]} segment"
        lines.append(f"- {stop.time - t0:.3f} s into the trial{seg}: **{stop.kind}**: {stop.message}")
    else:
        lines.append(f"- {result.reason or 'no reason recorded'}")
    for e in log.events:
        if e.kind == "safe-stop":
            lines.append(f"- then: {e.message}")
    return "\n".join(lines) + "\n"


def _events_markdown(log: TrialLog) -> str:
    lines = ["| time (s) | event | detail |", "|---:|---|---|"]
    t0 = log.time[0] if len(log) else 0.0
    for e in log.events:
        lines.append(f"| {e.time - t0:.3f} | {e.kind} | {e.message} |")
    return "\n".join(lines) + "\n"


def tracking_summary(log: TrialLog, robot) -> str:
    """Per joint: RMS and max |commanded − measured| and the final error, in display units."""
    lines = ["| joint | RMS error | max error | final error | unit |", "|---|---:|---:|---:|---|"]
    for name in log.joint_names:
        j = log.joint(name)
        cmd, unit, label = joint_display(robot, name, log.q_cmd[:, j])
        meas, _, _ = joint_display(robot, name, log.q[:, j])
        e = meas - cmd
        if e.size == 0:
            continue
        final = round(float(e[-1]), 4) + 0.0  # no "-0.0000"
        lines.append(f"| {label} | {np.sqrt(np.mean(e ** 2)):.4f} | {np.max(np.abs(e)):.4f} | "
                     f"{final:.4f} | {unit.split('(')[-1].rstrip(')')} |")
    return "\n".join(lines) + "\n"


def requirements_markdown(result: "TrialResult") -> str:
    """One row per requirement: its STL formula, its robustness (the signed margin, in the formula's
    units) and whether it holds; beside it, where the placement was judged on the backend's truth
    or the cameras', the same formula on the readings."""
    truth = result.basis in ("sim", "camera")
    fmt = lambda v: "—" if v is None else f"{v:+.3f}"  # noqa: E731
    head = "| requirement | formula | robustness | unit | holds |" + (" on the readings |" if truth else "")
    rows = [head, "|---|---|---:|---|---|" + ("---:|" if truth else "")]
    for r in result.requirements:
        formula = r["formula"].replace("|", "\\|")
        row = f"| {r['name']} | `{formula}` | {fmt(r['robustness'])} | {r.get('unit', '')} | {'yes' if r['holds'] else '**no**'} |"
        if truth:
            row += f" {fmt(r.get('measured_robustness'))} |"
        rows.append(row)
    where = {"sim": "the placement where the simulator's joints really were (its truth), the readings' "
                    "beside it",
             "camera": "the placement the cameras measured (acceptance.by: camera), the readings' beside it",
             }.get(result.basis, "the placement the readings give")
    return "\n".join(rows) + (f"\n\nRobustness is the signed margin by which the trial met each requirement "
                              f"(negative: by how much it missed), in mm or degrees as its formula; judged on "
                              f"{where}.\n")


def render_markdown(result: "TrialResult", log: TrialLog, prep: "PreparedTrial",
                    figures: dict[str, str]) -> str:
    cfg = prep.config
    t = cfg.target
    o = result.outcome
    meta = log.metadata
    verdict = ("PASSED" if result.passed else "FAILED")
    late = result.timing.verdict_note()  # a loop that did not keep time says so beside the verdict
    lines = [f"# Trial {cfg.name}: {verdict}" + (f"; {late}" if late else ""), "",
             f"- robot: {cfg.robot}, backend: {cfg.backend.kind} ({meta.get('rig') or 'rig not recorded'}), "
             f"trajectory: {cfg.plan.trajectory}, "
             f"control rate: {cfg.control_hz:g} Hz, seed: {cfg.seed}",
             f"- started: {meta.get('start_time', '?')}; log: `{result.log_path.name}`",
             f"- acceptance: {cfg.acceptance.position_mm:g} mm per axis and depth, "
             f"{cfg.acceptance.angle_deg:g}° in angle"]
    if meta.get("note"):
        lines.append(f"- note: {meta['note']}")
    if not result.completed:
        lines.append(f"- **stopped early: {result.reason or 'unknown reason'}**")
    lines.append("")
    lines.append("## Needle placement (Table 3 layout)")
    lines.append("")
    if result.excitation:
        lines[-2:] = ["## Excitation", "",
                      "An excitation run for identifying the servos: around the target's entry pose each "
                      "joint in turn took a chirp, a multi-sine and a slow up-and-down or constant-speed "
                      "sweeps, slow reversals and holds; no needle was "
                      "placed. It passes by completing with every interlock on; the log feeds "
                      "identification.", ""]
    elif o is not None:
        lines.append(table3_markdown([t.x_mm, t.y_mm, t.z_mm], t.depth_mm, t.angle_deg, o))
    else:
        lines.append("The trial stopped before the insertion finished: no placement to report.\n")
    if result.requirements:
        lines += ["## Requirements", "", requirements_markdown(result), ""]
    if not result.completed:
        at = next(i for i, line in enumerate(lines) if line in ("## Needle placement (Table 3 layout)",
                                                               "## Excitation"))
        lines[at:at] = ["## What stopped it", "", stop_markdown(result, log)]
    lines += ["## Joint profiles (Fig. 12 layout)", ""]
    if "joints" in figures:
        lines += [f"![joint profiles]({figures['joints']})", ""]
    else:
        span = (log.time[-1] - log.time[0]) if len(log) else 0.0
        lines += [f"No joint moved more than {STILL_EXCURSION:g}° or {STILL_EXCURSION:g} mm in the "
                  f"{span:.3f} s the trial ran ({len(log)} samples): nothing to plot. The tracking "
                  f"and events tables below hold what was measured.", ""]
    if "robot" in figures:
        where = ("where the trial stopped" if not result.completed else
                 "at the end of the run" if result.excitation else "at the end of the insertion")
        lines += [f"![robot {where}]({figures['robot']})", ""]
        if not result.excitation:
            lines += [f"*The robot {where}, seen {SIDE_VIEW} (the phantom and the gantry left "
                      f"out; the bed in grey). Red: the planned insertion, from the target's entry "
                      f"point (red ball) to its tip; orange: the planned approach, the 30 mm the "
                      f"needle travels above the entry point; green: the entry point and tip where "
                      f"the robot placed the needle (measured joints).*", ""]
        else:
            lines += [f"*The robot {where}, in the CT room.*", ""]
    if result.camera is not None:
        lines += ["## The needle seen by the cameras", "",
                  camera_markdown(result.camera, o, result.judged_by, figures.get("cameras"))]
    if result.monitor is not None:
        lines += ["## The twin", "", twin_markdown(result.monitor, figures.get("twin"))]
    lines += ["## Tracking", "", tracking_summary(log, prep.robot), "## Loop timing", "",
              result.timing.markdown(), "## Events", "",
              _events_markdown(log), "## Versions", "",
              ", ".join(f"{k} {v}" for k, v in meta.get("versions", {}).items()), ""]
    return "\n".join(lines)


def markdown_to_html(md: str, images: dict[str, Path], title: str) -> str:
    """A small Markdown subset (headings, lists, tables, images) as one self-contained page."""
    out = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;}"
           "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:4px 8px;"
           "text-align:right}td:first-child,th:first-child{text-align:left}img{max-width:100%}"
           ".fail{color:#b00}.pass{color:#080}</style></head><body>"]
    in_table = in_list = False
    table: list[list[str]] = []
    for line in md.splitlines():
        if line.startswith("|"):
            cells = re.split(r"(?<!\\)\|", line.strip()[1:-1] if line.strip().endswith("|")
                             else line.strip()[1:])
            table.append([c.strip().replace("\\|", "|") for c in cells])
            in_table = True
            continue
        if in_table:
            out.append(_html_table(table))
            table, in_table = [], False
        if line.startswith("- "):
            if not in_list:
                out.append("<ul>")
                in_list = True
            out.append(f"<li>{_inline(line[2:])}</li>")
            continue
        if in_list:
            out.append("</ul>")
            in_list = False
        if line.startswith("!["):
            alt, src = line[2:].split("](", 1)
            src = src.rstrip(")")
            data = base64.b64encode(Path(images[src]).read_bytes()).decode()
            out.append(f"<p><img alt='{html.escape(alt)}' src='data:image/png;base64,{data}'></p>")
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            text = _inline(line[level:].strip()).replace(" %", "\u00a0%")  # "100.0 %" on one line
            text = text.replace("PASSED", "<span class='pass'>PASSED</span>").replace(
                "FAILED", "<span class='fail'>FAILED</span>")
            out.append(f"<h{level}>{text}</h{level}>")
        elif line.strip():
            out.append(f"<p>{_inline(line)}</p>")
    if in_table:
        out.append(_html_table(table))
    if in_list:
        out.append("</ul>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _html_table(rows: list[list[str]]) -> str:
    """A Markdown table as HTML, each column aligned as its separator row says (``---:`` right)."""
    align: list[str] = []
    if len(rows) > 1 and all(set(c) <= set("-:") and c for c in rows[1]):
        align = ["right" if c.endswith(":") and not c.startswith(":") else
                 "center" if c.startswith(":") and c.endswith(":") else "left" for c in rows[1]]
        rows = [rows[0], *rows[2:]]

    def cell(tag: str, i: int, text: str) -> str:
        style = f" style='text-align:{align[i]}'" if i < len(align) else ""
        return f"<{tag}{style}>{_inline(text)}</{tag}>"

    out = ["<table>"]
    for r, row in enumerate(rows):
        tag = "th" if r == 0 else "td"
        out.append("<tr>" + "".join(cell(tag, i, c) for i, c in enumerate(row)) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _inline(text: str) -> str:

    t = html.escape(text)
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    t = re.sub(r"(?<![\w*])\*(?![\s*])(.+?)(?<![\s*])\*(?![\w*])", r"<em>\1</em>", t)  # not "2 * 3 * 4"
    t = re.sub(r"`(.+?)`", r"<code>\1</code>", t)
    return t


def write_trial_report(result: "TrialResult", log: TrialLog, prep: "PreparedTrial",
                       picture: bool = True) -> dict[str, Path]:
    """joints.png, robot.png, report.md, report.html and result.json in the run directory."""
    d = result.run_dir
    figures = {}
    if largest_excursion(log, prep.robot) >= STILL_EXCURSION:
        figures["joints"] = "joints.png"
        plot_joint_profiles(log, prep.robot, d / "joints.png",
                            title=f"{prep.config.name}: commanded vs measured")
    else:
        (d / "joints.png").unlink(missing_ok=True)  # a rebuilt report drops a stale figure
    if result.monitor is not None and log.twin_z is not None and len(log) > 1:
        figures["twin"] = "twin.png"
        plot_twin(log, result.monitor, d / "twin.png")
    else:
        (d / "twin.png").unlink(missing_ok=True)
    if picture and len(log):
        try:

            insert = log.segment_names.index("insert") if "insert" in log.segment_names else -1
            idx = np.flatnonzero(log.segment == insert)
            q = log.q[idx[-1]] if idx.size else log.q[-1]
            render_robot(prep.config.robot, q, d / "robot.png",
                         target=None if result.excitation else prep.target)
            figures["robot"] = "robot.png"
        except Exception:  # a picture is a nicety; never lose a report for it
            pass
    drawn = None
    if result.camera is not None and prep.config.cameras is not None:
        try:
            q = settled_position(log, "insert")
            drawn = draw_camera_views(d, prep.config.cameras, log.metadata.get("camera"),
                                      prep.robot.needle(q).tip, d / "cameras.png")
        except (KeyError, ValueError, OSError):  # a picture is a nicety; never lose a report for it
            drawn = None
    if drawn is not None:
        figures["cameras"] = "cameras.png"
    else:
        (d / "cameras.png").unlink(missing_ok=True)
    md = render_markdown(result, log, prep, figures)
    (d / "report.md").write_text(md)
    images = {v: d / v for v in figures.values()}
    (d / "report.html").write_text(markdown_to_html(md, images, f"Trial {prep.config.name}"))
    write_result_json(result)
    return {k: d / v for k, v in figures.items()}
