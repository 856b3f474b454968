"""The prediction part of a comparison report: a Fig. 12-style figure with the commanded profile,
the rig, the ideal sim and the model-driven sim in one panel per joint, and its table."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.compare.analysis import Comparison
from bench.compare.figures import aligned_time, pyplot
from bench.compare.prediction import SENSED_SETTLE_S, SETTLE_FRACTION, STILL_EXCURSION, Prediction
from bench.core.outcome import SETTLED_WINDOW_S
from bench.report.trial import joint_display

__all__ = ["PLACEMENT_NOTE", "plot_prediction", "prediction_markdown"]

#: Why this section places the needle over another window than the repeat tables do.
PLACEMENT_NOTE = (
    f"*Where the needle is placed.* The repeat tables above (Table 3 layout, deviations over "
    f"repeats) place it as each trial did for its verdict: the median reading over the last "
    f"{SETTLED_WINDOW_S:g} s of the insertion's settle. This section places each side by its mean "
    f"reading over the last {SETTLE_FRACTION:.0%} of that settle, and the train, read by its "
    f"ultrasonic sensor, over all its stillness from {SENSED_SETTLE_S:g} s after its goal last "
    f"changed: the sensor reads whole millimetres with about a millimetre of noise on the rig "
    f"(0.7 mm of tip a step), so a {SETTLED_WINDOW_S:g} s median lands on whichever millimetre the "
    f"noise gave, and only the mean over seconds says where the host loop put the train. The two "
    f"placements therefore differ by up to a few millimetres of tip on the rig; the table gives "
    f"the tip error by both.")


def plot_prediction(model: Comparison, ideal: Comparison, path: Path) -> Path:
    """Per joint, repeat 1: commanded (red dotted), rig (wide grey), ideal sim (blue dashed), model sim (green)."""
    plt = pyplot()
    robot, names = model.robot, model.joint_names
    cols = 3
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.3 * rows), sharex=True, squeeze=False)
    rig, sim, ideal_sim = model.subject.logs[0], model.reference.logs[0], ideal.reference.logs[0]
    for k, name in enumerate(names):
        ax = axes[k // cols, k % cols]
        j = names.index(name)
        # the rig wide and pale underneath, so a model sim that lies on it leaves it visible
        for log, style, colour, width, label in ((rig, "-", "0.55", 3.2, model.subject.label),
                                                 (ideal_sim, "--", "tab:blue", 1.1, "ideal sim"),
                                                 (sim, "-", "tab:green", 1.0, model.reference.label)):
            y, unit, title = joint_display(robot, name, np.asarray(log.q)[:, j])
            ax.plot(aligned_time(log), y, style, color=colour, lw=width, label=label)
        cmd, unit, title = joint_display(robot, name, np.asarray(rig.q_cmd)[:, j])
        ax.plot(aligned_time(rig), cmd, "r:", lw=1.6, label="commanded")
        ax.set_title(title, fontsize=9)
        ax.set_ylabel(unit, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for k in range(len(names), rows * cols):
        axes[k // cols, k % cols].set_axis_off()
    for ax in axes[-1]:
        ax.set_xlabel("time from the first commanded motion (s)", fontsize=8)
    axes[0, 0].legend(loc="best", fontsize=7)
    fig.suptitle("Commanded, rig, ideal sim and model sim, repeat 1 (Fig. 12 layout)")
    fig.subplots_adjust(left=0.07, right=0.98, top=0.93, bottom=0.07, hspace=0.5, wspace=0.3)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def prediction_markdown(pred: Prediction, figure: str) -> list[str]:
    """The section's lines: what the figures mean, the table, the figure."""
    d = pred.as_dict()
    tips = d["tip_error_mm"]["per_repeat"]
    ratio = ("— (no repeat completed by the rig and both sims)" if d["tracking_gap_ratio"] is None
             else d["tracking_gap_ratio"])
    still = ", ".join(f"{v:g} {'°' if k == 'revolute' else 'm'}" for k, v in
                      (("revolute", round(np.degrees(STILL_EXCURSION["revolute"]), 3)),
                       ("prismatic", STILL_EXCURSION["prismatic"])))
    return ["## Prediction of the rig", "",
            "How well the sim with the servo model foresees the rig. *Tip error*: the distance "
            "between the needle tips the model sim and the rig placed, per repeat (mm). *Tracking "
            "gap*: the RMS over joints and time of (sim − rig) measured positions, each joint's "
            "relative to its commanded excursion (joints moving less than " + still + " left out); "
            "the ratio is the model's gap over the ideal sim's (1: no better; 0.2: 80 % smaller).", "",
            PLACEMENT_NOTE, "",
            "| figure | value |", "| --- | --- |",
            f"| tip error per repeat (mm) | {', '.join(f'{v:.3f}' for v in tips) or '—'} |",
            f"| tip error mean / max (mm) | {d['tip_error_mm']['mean']} / {d['tip_error_mm']['max']} |",
            f"| the same, placed as the repeat tables place it (mm) | "
            f"{', '.join(f'{v:.3f}' for v in d['trial_tip_error_mm']) or '—'} |",
            f"| tracking gap, model sim | {d['tracking_gap']['model']} |",
            f"| tracking gap, ideal sim | {d['tracking_gap']['ideal']} |",
            f"| tracking gap ratio (model / ideal) | {ratio} |", "",
            f"![Commanded, rig, ideal sim and model sim]({figure})", ""]
