"""The test-stand report: per log the measured position, the model's prediction and the goal,
with each log's MAE, in one HTML page (matplotlib PNG embedded)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Sequence

import numpy as np

from bench.stand.predict import LogScore, Prediction

__all__ = ["plot_scores", "write_prediction_report"]


def _pyplot():
    import matplotlib  # heavy: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded only when a figure is drawn

    return plt


def plot_scores(scores: Sequence[LogScore], title: str, label: str = "predicted") -> bytes:
    """One panel per log (position in degrees against time): goal, measured, predicted; PNG bytes."""
    plt = _pyplot()
    cols = 3 if len(scores) > 4 else max(1, len(scores))
    rows = int(np.ceil(len(scores) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 2.8 * rows), squeeze=False)
    for ax, s in zip(axes.flat, scores):
        g = s.log
        ax.plot(g.time, np.degrees(g.goal), ":", color="tab:red", lw=1.0, label="goal")
        ax.plot(g.time, np.degrees(g.position), "-", color="0.5", lw=2.5, label="measured")
        ax.plot(g.time, np.degrees(s.simulated), "-", color="tab:green", lw=1.0, label=label)
        off = ~g.torque
        if off.any():
            ax.fill_between(g.time, 0, 1, where=off, color="0.9", transform=ax.get_xaxis_transform(),
                            label="torque off")
        ax.set_title(f"{g.name} {g.trajectory} kp {g.kp:g}: MAE {s.mae:.4f} rad", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("t (s)", fontsize=7)
        ax.set_ylabel("position (°)", fontsize=7)
    for ax in list(axes.flat)[len(scores):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def page(title: str, body: str) -> str:
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}</style></head>"
            f"<body><h1>{html.escape(title)}</h1>{body}</body></html>\n")


def score_table(scores: Sequence[LogScore]) -> str:
    """The per-log table (HTML): log, trajectory, P gain, samples, MAE and largest error (rad)."""
    rows = "".join(f"<tr><td>{html.escape(s.log.name)}</td><td>{html.escape(s.log.trajectory)}</td>"
                   f"<td>{s.log.kp:g}</td><td>{len(s.log)}</td><td>{s.mae:.4f}</td>"
                   f"<td>{s.max_error:.4f}</td></tr>"
                   for s in scores)
    return ("<table><tr><th>log</th><th>trajectory</th><th>kp</th><th>samples</th><th>MAE (rad)</th>"
            f"<th>max error (rad)</th></tr>{rows}</table>")


def png_tag(png: bytes) -> str:
    return f"<img alt='measured and predicted' src='data:image/png;base64,{base64.b64encode(png).decode()}'>"


def write_prediction_report(pred: Prediction, path: Path) -> Path:
    """The HTML report of a prediction: the table, the mean and the plots."""
    title = f"Test-stand prediction: {pred.model.name}"
    supply = "the measured supply" if pred.model.measured_supply else "the nominal supply"
    body = (f"<p>Each log rolled out open loop from its first measured position and velocity, driven by its "
            f"goals, torque enable and {supply}; MAE over every 5 ms sample, as BAM scores its models. "
            f"Mean MAE over {len(pred.scores)} log(s): <b>{pred.mean_mae:.4f} rad</b>.</p>"
            + score_table(pred.scores) + png_tag(plot_scores(pred.scores, title)))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page(title, body), encoding="utf-8")
    return path
