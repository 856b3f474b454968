"""Campaign reports: pass rates along each axis, deviation distributions beside
seed 000's Table 3, the worst trials — Markdown and one self-contained HTML page."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bench.campaign.cameras import basis_line, cameras_markdown
from bench.campaign.checked import read_campaign, trial_run_dir
from bench.campaign.rates import detection_rates, detection_table, monitored, wilson
from bench.kinematics.arc_train import table3_deviations
from bench.report.trial import markdown_to_html
from bench.trial.record import load_record, rebuild_report

__all__ = ["deviation_table", "write_campaign_report"]

# (column, label, unit, paper key): the paper's X, Y, Z are the first target point (entry).
AXES = [("entry_dx_mm", "entry X", "mm", "x"), ("entry_dy_mm", "entry Y", "mm", "y"),
        ("entry_dz_mm", "entry Z", "mm", "z"), ("tip_dx_mm", "tip X", "mm", None),
        ("tip_dy_mm", "tip Y", "mm", None), ("tip_dz_mm", "tip Z", "mm", None),
        ("depth_dev_mm", "insertion depth", "mm", "insertion"), ("angle_dev_deg", "angle", "°", "angle")]


def _stats(v: np.ndarray) -> tuple[float, float, float]:
    v = v[np.isfinite(v)]
    if not v.size:
        return (math.nan, math.nan, math.nan)
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0, float(np.abs(v).max())


def deviation_table(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Mean, std and max |deviation| per axis for the campaign's done trials and for Table 3."""
    paper = table3_deviations()
    out = []
    for col, label, unit, key in AXES:
        v = np.array([r[col] for r in rows if r[col] is not None], dtype=float)
        m, s, mx = _stats(v)
        pm, ps, pmx = _stats(paper[key]) if key else (math.nan,) * 3
        out.append({"axis": label, "unit": unit, "n": int(v.size), "mean": m, "std": s, "max_abs": mx,
                    "paper_mean": pm, "paper_std": ps, "paper_max_abs": pmx})
    return out


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _severity(r: dict, pos: float, ang: float) -> float:
    if r["status"] != "done" or not r["completed"] or r["angle_dev_deg"] is None:
        return math.inf
    lin = [abs(r[c]) for c, *_ in AXES if c != "angle_dev_deg" and r[c] is not None]
    return max(max(lin) / pos, abs(r["angle_dev_deg"]) / ang)


# ---------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------


def _plt():
    import matplotlib  # heavy: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded only when a figure is drawn

    return plt


def plot_distributions(rows: Sequence[dict], path: Path, limits: tuple[float, float]) -> Path:
    """Histograms of the deviations per axis, Table 3's five repeats overlaid."""
    plt = _plt()
    paper = table3_deviations()
    fig, axes = plt.subplots(2, 4, figsize=(16, 7))
    for ax, (col, label, unit, key) in zip(axes.flat, AXES):
        v = np.array([r[col] for r in rows if r[col] is not None], dtype=float)
        lim = limits[1] if unit == "°" else limits[0]
        if v.size:
            lo = min(v.min(), *(paper[key] if key else []), -0.05 * lim)
            hi = max(v.max(), *(paper[key] if key else []), 0.05 * lim)
            ax.hist(v, bins=min(40, max(8, int(np.sqrt(v.size)) * 2)), range=(lo, hi),
                    color="tab:blue", alpha=0.75, label=f"campaign (n={v.size})")
        if key:
            for i, p in enumerate(paper[key]):
                ax.axvline(p, color="tab:red", lw=1.2, ls="--",
                           label="seed 000 Table 3 (5 repeats)" if i == 0 else None)
            ax.plot(paper[key], np.zeros_like(paper[key]), "v", color="tab:red", ms=9, clip_on=False)
        for i, s in enumerate((-lim, lim)):
            ax.axvline(s, color="k", lw=1.2, label=f"acceptance limit ±{lim:g} {unit}" if i == 0 else None)
        ax.set_title(f"{label} deviation")
        ax.set_xlabel(unit)
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("Deviation from the target: campaign trials (bars), seed 000 Table 3's repeats "
                 "(red dashed), acceptance limits (black)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _groups(rows: Sequence[dict], axis: dict) -> list[tuple[str, float, list[dict]]]:
    """(label, x, rows) per grid value, or per quantile bin of a random axis."""
    label = axis["label"]
    have = [r for r in rows if label in r["params"]]
    values = [r["params"][label] for r in have]
    if axis["kind"] in ("grid", "choice") or len(set(map(str, values))) <= 8:
        keys: list = []
        for v in values:
            if v not in keys:
                keys.append(v)
        numeric = all(isinstance(k, (int, float)) for k in keys)
        if numeric:
            keys.sort()
        return [(_fmt(k) if isinstance(k, float) else str(k), float(k) if numeric else float(i),
                 [r for r in have if r["params"][label] == k]) for i, k in enumerate(keys)]
    v = np.asarray(values, dtype=float)
    edges = np.unique(np.quantile(v, np.linspace(0, 1, 9)))
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = [r for r, x in zip(have, v) if a <= x and (x < b or b == edges[-1])]
        out.append((f"{a:.3g}–{b:.3g}", 0.5 * (a + b), sel))
    return out


def plot_pass_rates(rows: Sequence[dict], axes_meta: Sequence[dict], path: Path) -> Path | None:
    """Pass rate (Wilson 95 % interval) against each varying parameter."""
    if not axes_meta:
        return None
    plt = _plt()
    n = len(axes_meta)
    fig, axs = plt.subplots(1, n, figsize=(5.5 * n, 4), squeeze=False)
    for ax, axis in zip(axs[0], axes_meta):
        groups = _groups(rows, axis)
        x = np.array([g[1] for g in groups])
        k = np.array([sum(bool(r["passed"]) for r in g[2]) for g in groups])
        m = np.array([len(g[2]) for g in groups])
        rate = np.where(m > 0, k / np.maximum(m, 1), np.nan)
        ci = np.array([wilson(int(a), int(b)) for a, b in zip(k, m)])
        ax.errorbar(x, rate * 100, yerr=[(rate - ci[:, 0]) * 100, (ci[:, 1] - rate) * 100],
                    fmt="o-", capsize=4)
        ax.set_ylim(-5, 105)
        ax.set_xlabel(axis["label"])
        ax.set_ylabel("pass rate (%)")
        ax.grid(alpha=0.3)
        if axis["kind"] not in ("grid", "choice"):
            ax.set_title("binned by quantile")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_detection(axes: Sequence[tuple[dict, list[tuple[str, float, list[dict]]]]], path: Path) -> Path:
    """Per varying parameter: the twin's detection rate beside the pass rate, with their intervals
    (the twin must flag a fault before it costs the placement: its curve rises first)."""
    plt = _plt()
    fig, axs = plt.subplots(1, len(axes), figsize=(5.8 * len(axes), 4.2), squeeze=False)
    for ax, (axis, groups) in zip(axs[0], axes):
        x = np.array([g[1] for g in groups])
        for key, label, style in (("detected", "detected by the twin", "s-"), ("passed", "placement passed", "o--")):
            k = np.array([detection_rates(g[2])[key] for g in groups])
            m = np.array([detection_rates(g[2])["n"] for g in groups])
            rate = np.where(m > 0, k / np.maximum(m, 1), np.nan)
            ci = np.array([wilson(int(a), int(b)) for a, b in zip(k, m)])
            ax.errorbar(x, rate * 100, yerr=[(rate - ci[:, 0]) * 100, (ci[:, 1] - rate) * 100],
                        fmt=style, capsize=4, label=label)
        positive = x[x > 0]
        if positive.size and positive.max() > 10 * positive.min():  # magnitudes over decades: each seen
            ax.set_xscale("symlog", linthresh=float(positive.min()))
        ax.set_ylim(-5, 105)
        ax.set_xlabel(axis["label"])
        ax.set_ylabel("share of trials (%)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=9, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_heatmap(rows: Sequence[dict], a: dict, b: dict, path: Path) -> Path:
    """Pass rate over two grid axes (other axes pooled)."""
    plt = _plt()
    va = sorted({r["params"][a["label"]] for r in rows})
    vb = sorted({r["params"][b["label"]] for r in rows})
    grid = np.full((len(vb), len(va)), np.nan)
    counts = np.zeros_like(grid, dtype=int)
    for i, y in enumerate(vb):
        for j, x in enumerate(va):
            sel = [r for r in rows if r["params"][a["label"]] == x and r["params"][b["label"]] == y]
            counts[i, j] = len(sel)
            if sel:
                grid[i, j] = 100.0 * sum(bool(r["passed"]) for r in sel) / len(sel)
    fig, ax = plt.subplots(figsize=(1.3 * len(va) + 3, 1.0 * len(vb) + 2))
    im = ax.imshow(grid, origin="lower", cmap="RdYlGn", vmin=0, vmax=100, aspect="auto")
    for i in range(len(vb)):
        for j in range(len(va)):
            if counts[i, j]:
                ax.text(j, i, f"{grid[i, j]:.0f}%\nn={counts[i, j]}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(va)), [_fmt(v) if isinstance(v, float) else str(v) for v in va])
    ax.set_yticks(range(len(vb)), [_fmt(v) if isinstance(v, float) else str(v) for v in vb])
    ax.set_xlabel(a["label"])
    ax.set_ylabel(b["label"])
    fig.colorbar(im, ax=ax, label="pass rate (%)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------
# The report
# ---------------------------------------------------------------------------


def _pass_rate_table(rows: Sequence[dict], axis: dict) -> list[str]:
    lines = [f"| {axis['label']} | trials | passed | pass rate | 95 % interval |", "|---|---:|---:|---:|---:|"]
    for label, _, sel in _groups(rows, axis):
        k = sum(bool(r["passed"]) for r in sel)
        lo, hi = wilson(k, len(sel))
        lines.append(f"| {label} | {len(sel)} | {k} | {100 * k / max(1, len(sel)):.1f} % | "
                     f"{100 * lo:.0f}–{100 * hi:.0f} % |")
    return lines


def worst_trials(rows: Sequence[dict], pos: float, ang: float, n: int = 10) -> list[dict]:
    """The ``n`` trials furthest from passing: errors and unfinished first, then by deviation."""
    ranked = sorted(rows, key=lambda r: (-_severity(r, pos, ang), r["id"]))
    return [r for r in ranked if r["status"] in ("done", "error")][:n]


def write_worst_reports(campaign_dir: Path, rows: Sequence[dict], pos: float, ang: float,
                        strict: bool = False) -> int:
    """Each worst trial's own HTML report, from its record (campaign trials are run without one);
    returns how many were written. A trial whose record cannot be read keeps its log link, or,
    ``strict``, refuses the report (:class:`RunDirError` naming the run and what is wrong)."""

    worst = [(r, trial_run_dir(campaign_dir, r)) for r in worst_trials(rows, pos, ang) if r["log_path"]]
    if strict:  # every run checked before anything is written
        for _, run_dir in worst:
            load_record(run_dir)
    written = 0
    for _, run_dir in worst:
        if (run_dir / "report.html").is_file():
            continue
        try:
            rebuild_report(run_dir)
            written += 1
        except Exception:  # noqa: BLE001 - a missing link never costs the campaign its report
            continue
    return written


def _beside_markdown(done: Sequence[dict], counts: dict, others: Sequence[tuple[str, list[dict], dict]]) -> list[str]:
    """This campaign's placement scatter and bias beside other campaigns' (e.g. the same faults on
    PyBullet's ideal motors and on the identified servo model) and beside Table 3."""
    names = ["this campaign"] + [name for name, _, _ in others]
    sets = [(done, counts)] + [(rows, c) for _, rows, c in others]
    lines = ["## Beside other campaigns", "",
             "Bias (mean) ± scatter (standard deviation) of each deviation, campaign by campaign, and "
             "the paper's five repeats at Target 1 (Table 3). A sim that knows the rig's servos shows "
             "the rig's bias (gravity sag, friction) and scatter; PyBullet's ideal motors show only the "
             "faults'.", "",
             "| | " + " | ".join(names) + " | Table 3 |", "|---|" + "---:|" * (len(names) + 1)]
    rates = []
    for rows, c in sets:
        n = sum(1 for r in rows)
        rates.append(f"{c['passed']}/{n} ({_fmt(100.0 * c['passed'] / n, 1) if n else '—'} %)")
    lines.append("| passed | " + " | ".join(rates) + " | 5/5 |")
    tables = [deviation_table(rows) for rows, _ in sets]
    for k, (_, label, unit, _key) in enumerate(AXES):
        cells = [f"{_fmt(t[k]['mean'], 2)} ± {_fmt(t[k]['std'], 2)}" for t in tables]
        paper = tables[0][k]
        ref = f"{_fmt(paper['paper_mean'], 2)} ± {_fmt(paper['paper_std'], 2)}" if math.isfinite(
            paper["paper_mean"]) else "—"
        lines.append(f"| {label} ({unit}) | " + " | ".join(cells) + f" | {ref} |")
    return lines + [""]


def _load(campaign_dir: Path) -> tuple[dict, list[dict], dict]:
    return read_campaign(campaign_dir)


def render_markdown(meta: dict, rows: list[dict], counts: dict, figures: dict[str, str],
                    campaign_dir: Path, beside: Sequence[tuple[str, list[dict], dict]] = ()) -> str:
    done = [r for r in rows if r["status"] == "done"]
    acc = meta.get("acceptance", {})
    pos, ang = float(acc.get("position_mm", 5.0)), float(acc.get("angle_deg", 1.0))
    n_done = len(done)
    rate = 100.0 * counts["passed"] / n_done if n_done else math.nan
    truth = sorted({r["truth"] for r in done if r["truth"]})
    sessions = meta.get("sessions", [])
    lines = [f"# Campaign {meta.get('name', campaign_dir.name)}", ""]
    if meta.get("description"):
        lines += [meta["description"].strip(), ""]
    lines += [f"- spec: `{meta.get('spec_file')}`; base trial: `{meta.get('base_config')}`",
              f"- planned {counts['planned']}, done {counts['done']}, passed {counts['passed']} "
              f"({_fmt(rate, 1)} % of done), errors {counts['error']}, "
              f"not yet run {counts['pending'] + counts['running']}",
              f"- acceptance: {pos:g} mm per axis (entry, tip) and depth, {ang:g}° in angle",
              f"- campaign seed {meta.get('seed')}; every trial's seed and faults are in `campaign.db` "
              "(`hilbench campaign rerun DIR ID` runs one again)"]
    if sessions:
        wall = sum(s.get("wall_s", 0.0) for s in sessions)
        lines.append(f"- wall time {wall:.1f} s over {len(sessions)} session(s); last on "
                     f"{sessions[-1].get('pool', '?')}")
    rigs = sorted({str((r.get("metrics") or {}).get("rig")) for r in done
                   if (r.get("metrics") or {}).get("rig")})
    if rigs:
        lines.append(f"- rig: {', '.join(rigs)} (sim, emulated or real: what each trial's record says ran it)")
    if truth:
        lines.append(basis_line(truth))
    lines += ["", "## Deviation against seed 000 Table 3", "",
              "Campaign trials that finished vs the paper's five repeats at Target 1 (Table 3: "
              "the first target point X, Y, Z, the insertion and the angle; the paper has no tip "
              "position).", "",
              "| axis | n | mean | std | max abs | Table 3 mean | Table 3 std | Table 3 max abs |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for t in deviation_table(done):
        u = f" ({t['unit']})"
        lines.append(f"| {t['axis']}{u} | {t['n']} | {_fmt(t['mean'])} | {_fmt(t['std'])} | "
                     f"{_fmt(t['max_abs'])} | {_fmt(t['paper_mean'])} | {_fmt(t['paper_std'])} | "
                     f"{_fmt(t['paper_max_abs'])} |")
    lines += ["", f"![deviation distributions]({figures['hist']})", ""]
    if beside:
        lines += _beside_markdown(done, counts, beside)
    axes_meta = meta.get("axes", [])
    lines += cameras_markdown(done, axes_meta, _groups)
    if axes_meta:
        lines += ["## Pass rate along each axis", ""]
        if "rates" in figures:
            lines += [f"![pass rates]({figures['rates']})", ""]
        for axis in axes_meta:
            lines += _pass_rate_table(done, axis) + [""]
        for key, fig in figures.items():
            if key.startswith("heat"):
                lines += [f"![pass-rate heatmap]({fig})", ""]
        if monitored(done):
            lines += ["## Detection by the twin", "",
                      "Each trial ran the servo model beside it (`monitor:`). Detected: an alarm at or after "
                      "the fault began; at a magnitude that injects nothing, every alarm is a false one.", ""]
            if "detection" in figures:
                lines += [f"![detection and pass rates]({figures['detection']})", ""]
            for axis in axes_meta:
                lines += detection_table(_groups(done, axis), axis["label"]) + [""]
    worst = worst_trials(rows, pos, ang)
    if worst:
        lines += ["## Worst trials", "", "Largest deviation relative to its limit first; errors and "
                  "trials that did not finish at the top. The lowest margin is the requirement with the "
                  "lowest robustness (mm or °; negative: missed by that much). Each one's own report (its joint profiles "
                  "and events) is linked; `hilbench campaign rerun DIR ID` runs it again.", "",
                  "| id | parameters | tip dev X, Y, Z (mm) | depth (mm) | angle (°) | lowest margin | passed | "
                  "reason | report |", "|---:|---|---|---:|---:|---|---|---|---|"]
        for r in worst:
            params = ", ".join(f"{k} = {_fmt(v) if isinstance(v, float) else v}" for k, v in r["params"].items())
            tip = ", ".join(_fmt(r[c], 2) for c in ("tip_dx_mm", "tip_dy_mm", "tip_dz_mm"))
            why = r["error"] if r["status"] == "error" else (r["reason"] or "")
            report = Path(r["log_path"]).with_name("report.html") if r["log_path"] else None
            if report is not None and (campaign_dir / report).is_file():
                log = f"[{r['name']}]({report.as_posix()})"
            elif r["log_path"]:
                log = f"[{r['name']} (log)]({r['log_path']})"
            else:
                log = "—"
            margin = (f"{r['worst']} {r['robustness']:+.3f}" if isinstance(r.get("worst"), str)
                      and isinstance(r.get("robustness"), (int, float)) else "—")
            lines.append(f"| {r['id']} | {params or '—'} | {tip} | {_fmt(r['depth_dev_mm'], 2)} | "
                         f"{_fmt(r['angle_dev_deg'], 3)} | {margin} | {'yes' if r['passed'] else 'no'} | "
                         f"{why.replace('|', '/') or '—'} | {log} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def write_campaign_report(campaign_dir: Path | str, beside: Sequence[Path] = (),
                          strict: bool = False) -> dict[str, Path]:
    """``report.md``, ``report.html`` (figures embedded) and ``figures/`` in the campaign directory;
    ``beside``: other campaigns' directories whose deviations are tabled beside this one's.

    Every directory is checked first (:mod:`bench.campaign.checked`); ``strict`` (``campaign
    report``) also refuses a worst trial whose run directory fails its checks, before writing."""

    campaign_dir = Path(campaign_dir)
    meta, rows, counts = _load(campaign_dir)
    others = []
    for other in map(Path, beside):
        o_meta, o_rows, o_counts = _load(other)
        o_done = [r for r in o_rows if r["status"] == "done"]
        others.append((o_meta.get("name", other.name), o_done, o_counts))
    acc = meta.get("acceptance", {})
    limits = (float(acc.get("position_mm", 5.0)), float(acc.get("angle_deg", 1.0)))
    write_worst_reports(campaign_dir, rows, *limits, strict=strict)
    fig_dir = campaign_dir / "figures"
    fig_dir.mkdir(exist_ok=True)
    done = [r for r in rows if r["status"] == "done"]
    figures = {"hist": "figures/deviations.png"}
    plot_distributions(done, campaign_dir / figures["hist"], limits)
    axes_meta = meta.get("axes", [])
    if axes_meta and done:
        plot_pass_rates(done, axes_meta, fig_dir / "pass_rates.png")
        figures["rates"] = "figures/pass_rates.png"
        if monitored(done):
            plot_detection([(a, _groups(done, a)) for a in axes_meta], fig_dir / "detection.png")
            figures["detection"] = "figures/detection.png"
        grid = [a for a in axes_meta if a["kind"] == "grid"]
        if len(grid) >= 2:
            plot_heatmap(done, grid[0], grid[1], fig_dir / "heatmap.png")
            figures["heat0"] = "figures/heatmap.png"
    md = render_markdown(meta, rows, counts, figures, campaign_dir, others)
    (campaign_dir / "report.md").write_text(md)
    html = markdown_to_html(md, {v: campaign_dir / v for v in figures.values()},
                            f"Campaign {meta.get('name', '')}")
    html = re.sub(r"\[([^\]\n]+)\]\(([^)\s]+)\)", r"<a href='\2'>\1</a>", html)
    (campaign_dir / "report.html").write_text(html)
    table = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in t.items()}
             for t in deviation_table(done)]
    (campaign_dir / "summary.json").write_text(json.dumps(
        {"counts": counts, "deviations": table}, indent=2) + "\n")
    return {"markdown": campaign_dir / "report.md", "html": campaign_dir / "report.html"}
