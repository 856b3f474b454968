"""The report of a test-stand identification: per log the measured position against the
datasheet model's and the identified model's open-loop rollouts, the MAE before and after, and
the values fitted."""

from __future__ import annotations

import html
from pathlib import Path

from bench.config.servo_model import STAND_JOINT, ServoModelFile
from bench.stand.predict import Prediction
from bench.stand.report import page, plot_scores, png_tag

__all__ = ["write_stand_report"]


def _values_table(model: ServoModelFile, fitted: dict[str, float]) -> str:
    """Each fitted value, its standard error (the others held: a lower bound) and whether the logs told it."""
    errors = model.uncertainty.get(STAND_JOINT, {})
    hidden = set(model.unobservable.get(STAND_JOINT, []))
    physics = model.joints[STAND_JOINT]
    rows = []
    for k, v in fitted.items():
        key, unit = k, 1.0
        if k == "kt_nma":  # the file holds Kt as a factor on the datasheet's
            key, unit = "kt_scale", v / physics.kt_scale if physics.kt_scale else 1.0
        e = errors.get(key)
        err = "—" if e is None else f"{e * unit:.3g}"
        rows.append(f"<tr><td>{html.escape(k)}</td><td>{v:.6g}</td><td>{err}</td>"
                    f"<td>{'not observable' if key in hidden else 'observable'}</td></tr>")
    return ("<table><tr><th>fitted</th><th>value</th><th>standard error</th><th></th></tr>"
            + "".join(rows) + "</table><p>Standard error: the step, the others held, at which the mean MAE "
            "rises 5 % (a lower bound on the error with the others free); a value whose error is over 5 % of "
            "it the logs could not tell.</p>")


def write_stand_report(before: Prediction, after: Prediction, model: ServoModelFile, path: Path,
                       fitted: dict[str, float] | None = None) -> Path:
    """The HTML page beside the model file."""
    rows = "".join(f"<tr><td>{html.escape(b.log.name)}</td><td>{html.escape(b.log.trajectory)}</td>"
                   f"<td>{b.log.kp:g}</td><td>{b.mae:.4f}</td><td>{a.mae:.4f}</td></tr>"
                   for b, a in zip(before.scores, after.scores))
    physics = model.joints[STAND_JOINT].model_dump(exclude_none=True)
    if model.stand is not None:
        physics["gravity_offset_rad"] = model.stand.gravity_offset_rad
    values = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.6g}</td></tr>" for k, v in physics.items())
    body = (f"<p>Open-loop rollouts of every log (BAM's score: MAE over every 5 ms sample), the measured "
            f"supply driving the motor. Mean MAE: datasheet {before.mean_mae:.4f} rad, identified "
            f"<b>{after.mean_mae:.4f} rad</b>.</p>"
            "<table><tr><th>log</th><th>trajectory</th><th>kp</th><th>datasheet MAE (rad)</th>"
            f"<th>identified MAE (rad)</th></tr>{rows}</table>"
            f"<h2>Identified ({html.escape(model.servo or '')})</h2><table>{values}</table>"
            + (_values_table(model, fitted) if fitted else "")
            + "".join(f"<p>{html.escape(n)}</p>" for n in model.notes)
            + "<h2>Identified model</h2>"
            + png_tag(plot_scores(after.scores, "identified model", "identified"))
            + "<h2>Datasheet model</h2>"
            + png_tag(plot_scores(before.scores, "datasheet model", "datasheet")))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page("Test-stand identification", body), encoding="utf-8")
    return path
