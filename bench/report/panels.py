"""The grid of panels the report's figures share (the joint profiles' and the twin's): one panel a
joint sharing the time axis, written as a PNG by Agg alone, its margins laid out as tight_layout
would leave them without drawing every panel to measure it (a trial report's largest cost)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axis import Axis
    from matplotlib.figure import Figure
    from matplotlib.text import Text

__all__ = ["FIGURE_DPI", "panel_figure", "place_panels"]

#: The report's figures are 12 inches wide and written at this resolution (1320 pixels).
FIGURE_DPI = 110
#: The room tight_layout leaves around and between panels, in font sizes (its ``pad``).
_PAD_FONTS = 1.08


def panel_figure(rows: int, cols: int, height: float) -> tuple[Figure, np.ndarray]:
    """A 12-inch-wide figure of ``rows`` x ``cols`` panels sharing the time axis, drawn by Agg
    alone: a report only writes a PNG, so pyplot's backend machinery and figure registry (and
    closing the figure in it) would be work for nothing."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy: only when a figure is drawn
    from matplotlib.figure import Figure  # heavy: only when a figure is drawn

    fig = Figure(figsize=(12, height), dpi=FIGURE_DPI)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, sharex=True, squeeze=False)


def _probe(fig: Figure, size, **kw) -> Text:
    """A text of the panels' font in ``size``, set at the origin and never drawn: what a label
    takes is measured on it, as a draw measures it (and its measures are cached for the draw)."""
    from matplotlib.text import Text  # heavy: only when a figure is drawn

    return Text(0, 0, "0", fontsize=size, figure=fig, **kw)


def _widest(probe: Text, renderer, labels: list[str]) -> float:
    """The width (pixels) of the widest of ``labels`` in the font of ``probe``."""
    widest = 0.0
    for s in labels:
        probe.set_text(s)
        widest = max(widest, probe.get_window_extent(renderer).width)
    return widest


def _drawn_ticks(axis: Axis) -> tuple[np.ndarray, list[str]]:
    """The major ticks an axis will draw (those in its view) and their labels, as a draw makes them."""
    locs = np.asarray(axis.get_majorticklocs(), dtype=float)
    labels = axis.major.formatter.format_ticks(locs)  # formatted among all of them, as drawn
    lo, hi = sorted(axis.get_view_interval())
    slack = 1e-10 * (hi - lo)
    keep = (locs >= lo - slack) & (locs <= hi + slack)
    return locs[keep], [s for s, k in zip(labels, keep) if k]


def place_panels(fig: Figure, axes: np.ndarray, used: int, top_in: float,
                 title: Optional[Text] = None) -> None:
    """Margins and gaps as tight_layout leaves them (a pad of 1.08 font sizes around what each of
    the first ``used`` panels' title, tick labels and axis labels take, and around the figure's
    ``title``) below a band of ``top_in`` inches for the legend, without drawing every panel to
    measure it: fonts and tick sizes are known, so only what the data set is measured, the y tick
    labels (their width, and how far the lowest hangs below its panel) and the time labels'
    overhang at the right end; the ticks are those of the panels' final height, as drawn."""
    import matplotlib as mpl  # heavy: only when a figure is drawn

    rc, r, pt = mpl.rcParams, fig.canvas.get_renderer(), 1 / 72
    inches = lambda px: px / fig.dpi  # noqa: E731
    width, height = fig.get_size_inches()
    rows, cols = axes.shape
    pad = _PAD_FONTS * rc["font.size"] * pt
    shown = list(axes.flat[:used])
    x_tick = _probe(fig, rc["xtick.labelsize"])
    y_tick = _probe(fig, rc["ytick.labelsize"], va="center_baseline")  # set as the y ticks' labels
    title_up = max(inches(ax.title.get_window_extent(r).y1 - ax.bbox.y1) for ax in shown)
    heading = 0.0 if title is None else inches(title.get_window_extent(r).height) + pad
    top = top_in + pad + title_up + heading
    bottom = pad + (rc["xtick.major.size"] + rc["xtick.major.pad"] + rc["axes.labelpad"]) * pt + inches(
        x_tick.get_window_extent(r).height + axes[-1, 0].xaxis.label.get_window_extent(r).height)

    def rows_apart(below: float) -> float:
        """Rows ``below`` inches plus a pad and a title apart; the panels' height."""
        gap = below + pad + title_up
        panel = (height - top - bottom - (rows - 1) * gap) / rows
        fig.subplots_adjust(top=1 - top / height, bottom=bottom / height, hspace=gap / panel)
        return panel

    tick = rc["xtick.major.size"] * pt  # the time ticks under every panel
    hang, below = -inches(y_tick.get_window_extent(r).y0), tick  # a y label centred on the bottom edge
    panel_h = rows_apart(tick)
    for ax in shown[: (rows - 1) * cols]:
        locs, _ = _drawn_ticks(ax.yaxis)
        lo, hi = sorted(ax.get_ylim())
        if locs.size:
            below = max(below, hang - (locs.min() - lo) / (hi - lo) * panel_h)
    if below > tick:
        rows_apart(below)
    beside = [0.0] * cols  # per column, what the y ticks and labels take left of the frame
    for k, ax in enumerate(shown):
        _, labels = _drawn_ticks(ax.yaxis)
        label = ax.yaxis.label.get_window_extent(r).width if ax.get_ylabel() else 0.0
        beside[k % cols] = max(beside[k % cols], inches(label + _widest(y_tick, r, labels))
                               + (rc["ytick.major.size"] + rc["ytick.major.pad"] + rc["axes.labelpad"]) * pt)
    left, gap_w = pad + beside[0], pad + max(beside[1:], default=0.0)

    def columns_apart(over: float) -> float:
        """Columns a gap apart, ``over`` inches more for time labels past the right edge; their width."""
        right, gap = pad + over, gap_w + over
        panel = (width - left - right - (cols - 1) * gap) / cols
        fig.subplots_adjust(left=left / width, right=1 - right / width, wspace=gap / panel)
        return panel

    panel_w = columns_apart(0.0)
    locs, labels = _drawn_ticks(shown[0].xaxis)  # time: shared, one axis says it for all
    lo, hi = sorted(shown[0].get_xlim())
    over = max([0.0] + [inches(_widest(x_tick, r, [s])) / 2 - (hi - x) / (hi - lo) * panel_w
                        for x, s in zip(locs, labels)])  # a label centred on the right edge
    if over > 0.0:
        columns_apart(over)
