"""The comparison's figures: Fig. 12-style joint profiles of every repeat, tracking error bars, the
needle tips of both sides around the target."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bench.compare.analysis import Comparison, Side
from bench.compare.signals import first_motion_time
from bench.core.log import TrialLog
from bench.kinematics.arc_train import table3_deviations
from bench.report.trial import joint_display

__all__ = ["REPEAT_COLOURS", "display_scale", "plot_needle_scatter", "plot_profiles", "plot_tracking", "relative_rms",
           "profiles_caption"]

#: Fig. 12's colours for experiments 1–5 (the theoretical profile is red dotted); more repeats cycle on.
REPEAT_COLOURS = ("blue", "green", "#e6b800", "black", "magenta", "tab:cyan", "tab:brown", "tab:olive")


def relative_rms(side: Side) -> np.ndarray:
    """Mean RMS error over the commanded excursion, per joint; NaN for joints that hardly move."""
    lag = side.mean_tracking("lag_s")
    exc = side.mean_tracking("excursion")
    return np.where(np.isfinite(lag) & (exc > 0), side.mean_tracking("rms") / np.where(exc > 0, exc, 1.0),
                    np.nan)


def _colour(i: int) -> str:
    return REPEAT_COLOURS[i % len(REPEAT_COLOURS)]


def display_scale(kind: str) -> tuple[float, str]:
    """(factor from SI, unit) for a joint kind."""
    return (180.0 / math.pi, "°") if kind == "revolute" else (1e3, "mm")


def pyplot():
    import matplotlib  # heavy: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded only when a figure is drawn

    return plt


def aligned_time(log: TrialLog) -> np.ndarray:
    t = np.asarray(log.time, dtype=float)
    try:
        return t - first_motion_time(t, np.asarray(log.q_cmd))
    except ValueError:
        return t - t[0]


def plot_profiles(comparison: Comparison, path: Path) -> Path:
    """Fig. 12 for both sides: per joint, the theoretical profile (red dotted) and every repeat."""

    plt = pyplot()
    robot = comparison.robot
    names = comparison.joint_names
    sides = (comparison.reference, comparison.subject)
    fig, axes = plt.subplots(len(names), 2, figsize=(12, 2.1 * len(names)), sharex=True, squeeze=False)
    for col, side in enumerate(sides):
        for row, name in enumerate(names):
            ax = axes[row, col]
            j = names.index(name)
            for i, log in enumerate(side.logs):
                t = aligned_time(log)
                meas, unit, label = joint_display(robot, name, np.asarray(log.q)[:, j])
                ax.plot(t, meas, "-", color=_colour(i), lw=1.0, label=f"repeat {i + 1}")
            if side.logs:
                log = side.logs[0]
                cmd, unit, label = joint_display(robot, name, np.asarray(log.q_cmd)[:, j])
                ax.plot(aligned_time(log), cmd, "r:", lw=1.8, label="theoretical")
                ax.set_ylabel(unit, fontsize=8)
            ax.set_title(f"{label} — {side.label}", fontsize=9)
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time from the first commanded motion (s)")
    axes[0, 1].legend(loc="best", fontsize=7, ncol=2)
    fig.suptitle("Theoretical and measured joint profiles (Fig. 12 layout)")
    fig.subplots_adjust(left=0.07, right=0.98, top=0.96, bottom=0.04, hspace=0.45, wspace=0.16)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


_COLOUR_NAMES = {"#e6b800": "yellow", "tab:cyan": "cyan", "tab:brown": "brown", "tab:olive": "olive"}


def profiles_caption(comparison: Comparison) -> str:
    """What the profile figure draws, counted from the runs it was given (never a fixed five)."""
    n = max(len(comparison.reference.logs), len(comparison.subject.logs))
    names = [_COLOUR_NAMES.get(_colour(i), _colour(i)) for i in range(n)]
    left, right = comparison.reference.label, comparison.subject.label
    if n == 1:
        runs = f"the measured profile in {names[0]}"
    else:
        listed = ", ".join(names[:-1]) + f" and {names[-1]}"
        runs = f"repeats 1–{n} in {listed} (the paper's colours)"
    return (f"Left: {left}; right: {right}. Red dotted: the theoretical (commanded) profile of the "
            f"first repeat; {runs}.")


def plot_tracking(comparison: Comparison, path: Path) -> Path:
    """Per joint: lag, RMS error relative to the commanded excursion, and tip contribution."""
    plt = pyplot()
    names = comparison.joint_names
    x = np.arange(len(names))
    sides = (comparison.reference, comparison.subject)
    colours = ("tab:gray", "tab:blue")
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    w = 0.38
    for k, (side, colour) in enumerate(zip(sides, colours)):
        lag = side.mean_tracking("lag_s") * 1e3
        rel = 100 * relative_rms(side)
        off = (k - 0.5) * w
        axes[0].bar(x + off, np.nan_to_num(lag), w, color=colour, label=side.label)
        axes[1].bar(x + off, np.nan_to_num(rel), w, color=colour, label=side.label)
        ranking = dict(side.contribution_ranking())
        axes[2].bar(x + off, [ranking.get(n, 0.0) for n in names], w, color=colour, label=side.label)
    axes[0].set_ylabel("lag (ms)")
    axes[0].set_title("lag of the measured motion behind the commanded (velocity cross-correlation)")
    axes[1].set_ylabel("RMS error (% of excursion)")
    axes[1].set_title("RMS tracking error relative to the commanded excursion")
    axes[2].set_ylabel("|tip contribution| (mm)")
    axes[2].set_title("placement error of each joint through the FK Jacobian (mean over repeats)")
    for ax in axes:
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
    axes[2].set_xticks(x, names)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_needle_scatter(comparison: Comparison, path: Path) -> Path:
    """Entry-point (Table 3's X, Y, Z) and tip deviations, the acceptance box and Table 3's points."""
    plt = pyplot()
    limit = comparison.acceptance[0]
    t3 = table3_deviations()
    t3_xyz = np.stack([t3["x"], t3["y"], t3["z"]], axis=1)
    pairs = ((0, 1, "X", "Y"), (0, 2, "X", "Z"), (1, 2, "Y", "Z"))
    fig, axes = plt.subplots(1, 3, figsize=(14, 5.6))
    span = limit * 1.25
    for ax, (a, b, la, lb) in zip(axes, pairs):
        ax.add_patch(plt.Rectangle((-limit, -limit), 2 * limit, 2 * limit, fill=False, ls="--",
                                   color="red", lw=1.2, label=f"acceptance ±{limit:g} mm"))
        ax.plot(t3_xyz[:, a], t3_xyz[:, b], "*", color="black", ms=10, label="seed 000 Table 3")
        for o_i, o in enumerate(comparison.reference.outcomes):
            if o is not None:
                ax.plot(o.entry_deviation_mm[a], o.entry_deviation_mm[b], "s", mfc="none", color="gray",
                        ms=9, label=f"{comparison.reference.label} entry" if o_i == 0 else None)
        for i, o in enumerate(comparison.subject.outcomes):
            if o is None:
                continue
            ax.plot(o.entry_deviation_mm[a], o.entry_deviation_mm[b], "o", color=_colour(i), ms=7,
                    label=f"{comparison.subject.label} {i + 1} entry")
            ax.plot(o.tip_deviation_mm[a], o.tip_deviation_mm[b], "^", mfc="none", color=_colour(i),
                    ms=7, label=f"{comparison.subject.label} {i + 1} tip")
        pts = [abs(v) for o in comparison.subject.placed + comparison.reference.placed
               for v in (o.entry_deviation_mm[a], o.entry_deviation_mm[b], o.tip_deviation_mm[a],
                         o.tip_deviation_mm[b])]
        m = max([span] + [v * 1.1 for v in pts] + [float(np.abs(t3_xyz).max()) * 1.1])
        ax.set_xlim(-m, m)
        ax.set_ylim(-m, m)
        ax.set_aspect("equal")
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_xlabel(f"{la} deviation (mm)")
        ax.set_ylabel(f"{lb} deviation (mm)")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(6, len(labels)), fontsize=7)
    fig.suptitle("Needle deviation from Target 1: entry point (filled) and tip (hollow)")
    fig.tight_layout(rect=(0, 0.2, 1, 0.95))
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)
