"""The twin's page of a trial report: each watched joint's residual and its detector against the
threshold, the alarms where they fell, and a table of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.core.log import TrialLog
from bench.monitor.detector import Cusum, CusumParams
from bench.report.panels import FIGURE_DPI, panel_figure, place_panels

__all__ = ["plot_twin", "twin_markdown"]

RESIDUAL_STYLE = {"color": "#9a9a9a", "lw": 0.9, "label": "position residual / σ"}
CURRENT_STYLE = {"color": "#e0a458", "lw": 0.8, "label": "current residual / σ"}
SCORE_STYLE = {"color": "#1f5fa8", "lw": 1.7, "label": "CUSUM (larger side and signal)"}
THRESHOLD_STYLE = {"color": "#c0392b", "ls": (0, (5, 3)), "lw": 1.4, "label": "alarm threshold"}


def plot_twin(log: TrialLog, summary: dict, path: Path) -> Path:
    """One panel a watched joint: its residual over σ and the detector's sum against the threshold."""
    params = CusumParams(summary["cusum"]["drift_sigma"], summary["cusum"]["threshold_sigma"])
    watched = [log.joint(n) for n in summary["joints"]]
    z, zc, both = log.twin_z, log.twin_current_z, log.twin_columns
    n = z.shape[1]
    # as the monitor ran them; per joint the larger signal's
    scores = Cusum(both.shape[1], params).sums(both).reshape(len(z), -1, n).max(axis=1)
    t = log.time - log.time[0]
    cols = 3
    rows = int(np.ceil(len(watched) / cols))
    fig, axes = panel_figure(rows, cols, 2.6 * rows + 0.7)
    alarms = summary.get("alarms") or []
    for ax, j in zip(axes.flat, watched):
        name = log.joint_names[j]
        predicted = np.isfinite(z[:, j])  # the readings the twin predicted
        ax.plot(t[predicted], z[predicted, j], **RESIDUAL_STYLE)
        if zc is not None:
            ax.plot(t[predicted], zc[predicted, j], **CURRENT_STYLE)
        ax.plot(t, scores[:, j], **SCORE_STYLE)
        ax.axhline(params.threshold, **THRESHOLD_STYLE)
        for a in alarms:
            if a["joint"] == name:
                ax.axvline(a["t_s"], color="#c0392b", lw=1.2, label="alarm")
        # the scale of the threshold: a sum that runs on past an alarm leaves the panel at the top
        peak = float(np.nanmax(np.abs(both[:, j::n]), initial=0.0))
        top = params.threshold * 2.5
        ax.set_ylim(-min(max(4.0, 1.1 * peak), top), top)
        if float(np.nanmax(scores[:, j], initial=0.0)) > top:
            ax.text(0.99, 0.96, f"CUSUM peaks at {np.nanmax(scores[:, j]):.0f} σ", transform=ax.transAxes,
                    ha="right", va="top", fontsize=9, color=SCORE_STYLE["color"])
        ax.set_title(name, y=1.0)  # at the frame's top: nothing above it to clear, so no search per draw
        ax.set_ylabel("σ")
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(watched):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    handles, labels = {}, []
    for ax in axes.flat[: len(watched)]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    labels = list(handles)
    fig.legend([handles[k] for k in labels], labels, loc="upper center", ncol=len(labels), fontsize=11,
               frameon=False, bbox_to_anchor=(0.5, 1.0))
    place_panels(fig, axes, len(watched), top_in=0.45)
    fig.savefig(path, dpi=FIGURE_DPI)
    return Path(path)


def twin_markdown(summary: dict, figure: str | None) -> str:
    """The report's section on the twin: what ran, what it said, the figure."""
    c = summary["cusum"]
    alarms = summary.get("alarms") or []
    lines = [f"The servo model (`{Path(summary['model']).name}`) ran beside the trial, corrected "
             f"towards each reading; per joint, a CUSUM on each residual over σ "
             f"({' and '.join(summary.get('signals', ['position']))}; drift allowance "
             f"{c['drift_sigma']:g} σ, threshold {c['threshold_sigma']:g} σ) raises an alarm when the "
             f"joint stops behaving like its model. Action: {summary['action']}. Watched: "
             f"{', '.join(summary['joints'])}.", ""]
    if alarms:
        lines += ["| joint | time (s) | signal | CUSUM (σ) |", "|---|---|---|---|"]
        lines += [f"| {a['joint']} | {a['t_s']:.3f} | {a['signal']} | {a['score']:.1f} |" for a in alarms]
        lines.append("")
    else:
        lines += ["No alarm: every watched joint behaved like its model.", ""]
    if figure:
        lines += [f"![the twin's residuals]({figure})", ""]
    return "\n".join(lines)
