"""The trial report's joint plots: the commanded profile drawn over the measured one, dashed, in a
contrasting colour, so it shows wherever the two agree; one legend, large enough to read."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import to_rgb

from bench.core.log import TrialLog
from bench.kinematics.registry import get_robot
from bench.report.trial import LEGEND_FONTSIZE, joint_figure


def _agreeing_log(robot) -> TrialLog:
    """A log whose measured profile equals the commanded one: the worst case for seeing both."""
    n = len(robot.joint_names)
    log = TrialLog(list(robot.joint_names), ["move"], metadata={})
    for k in range(50):
        q = np.asarray(robot.chain.home, dtype=float) + 0.01 * k
        log.append(0.01 * k, 0, q, np.zeros(n), q, np.zeros(n), np.zeros(n))
    return log


def test_commanded_is_drawn_over_measured_dashed_in_a_contrasting_colour():
    import matplotlib.pyplot as plt  # heavy: matplotlib, only to draw the figure

    robot = get_robot("arc-train")
    fig = joint_figure(_agreeing_log(robot), robot, "t")
    try:
        for ax in fig.axes[: len(robot.joint_names)]:
            by_label = {line.get_label(): line for line in ax.get_lines()}
            cmd, meas = by_label["commanded (theoretical)"], by_label["measured"]
            assert cmd.get_zorder() > meas.get_zorder()  # on top
            assert cmd.get_linestyle() in ("--", "-.", ":") and meas.get_linestyle() == "-"
            assert np.abs(np.subtract(to_rgb(cmd.get_color()), to_rgb(meas.get_color()))).sum() > 0.8
        (legend,) = fig.legends  # one, for the whole figure
        assert [t.get_text() for t in legend.get_texts()] == ["measured", "commanded (theoretical)"]
        assert all(t.get_fontsize() >= LEGEND_FONTSIZE >= 10 for t in legend.get_texts())
    finally:
        plt.close(fig)
