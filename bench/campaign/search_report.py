"""Reports of the campaigns that search: a falsification's robustness curve and falsifying trial,
and each fault axis's tolerance boundary beside the grid's pass rate — Markdown and one HTML page."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

from bench.campaign.rates import wilson
from bench.report.trial import markdown_to_html

__all__ = ["write_boundary_report", "write_falsify_report"]


def _plt():
    import matplotlib  # heavy: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded only when a figure is drawn

    return plt


def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    return f"{v:+.3f}" if isinstance(v, float) else str(v)


def _write(directory: Path, stem: str, md: str, figures: dict[str, str], title: str) -> Path:
    """``<stem>.md`` and ``<stem>.html`` beside the search's trials (``campaign report`` keeps
    report.md and report.html for the campaign's own report of the same trials)."""
    (directory / f"{stem}.md").write_text(md)
    (directory / f"{stem}.html").write_text(markdown_to_html(md, {v: directory / v for v in figures.values()}, title))
    return directory / f"{stem}.html"


def write_falsify_report(directory: Path | str, result: dict) -> Path:
    """falsify.md and falsify.html of a search: the lowest score trial by trial, and the trial it found."""
    directory = Path(directory)
    curve = [c for c in result.get("curve") or []]
    figures = {}
    if curve:
        plt = _plt()
        fig, ax = plt.subplots(figsize=(6.5, 3.6))
        xs = [i + 1 for i, c in enumerate(curve) if c is not None]
        ys = [c for c in curve if c is not None]
        ax.step(xs, ys, where="post", label="lowest so far")
        ax.axhline(0.0, color="#b00", lw=1, ls="--", label="violation")
        ax.set_xlabel("trial")
        ax.set_ylabel("lowest robustness / scale")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(directory / "robustness.png", dpi=100)
        plt.close(fig)
        figures["curve"] = "robustness.png"
    verdict = "FALSIFIED" if result["falsified"] else "not falsified"
    lines = [f"# Falsification of {result.get('name') or directory.name}: {verdict}", "",
             f"- optimiser: {result['optimizer']}, search seed {result.get('search_seed', '?')}, "
             f"budget {result.get('budget', '?')} trials",
             f"- trials to {'the violation' if result['falsified'] else 'the end'}: {result['trials']} "
             f"({result['ran']} run: a batch runs whole)",
             f"- {'violated' if result['falsified'] else 'closest to failing'}: requirement "
             f"`{result.get('requirement')}`, robustness {_fmt(result.get('robustness'))} "
             f"(its units; score {_fmt(result.get('score'))} of its scale)", ""]
    if result.get("params"):
        lines += ["## The trial", "", "| axis | value |", "|---|---:|"]
        lines += [f"| {k} | {v:.6g} |" if isinstance(v, float) else f"| {k} | {v} |"
                  for k, v in result["params"].items()]
        lines += ["", f"Trial {result.get('trial')}, seed {result.get('seed')}; re-run it alone: "
                      f"`hilbench trial {result.get('config')}`", ""]
    if figures:
        lines += ["## Robustness, trial by trial", "", f"![robustness]({figures['curve']})", "",
                  "*The lowest score found so far (a requirement's robustness over its scale; below 0 a "
                  "requirement is violated).*", ""]
    return _write(directory, "falsify", "\n".join(lines), figures, f"Falsification {directory.name}")


def write_boundary_report(directory: Path | str, result: dict, grids: Sequence[dict] = ()) -> Path:
    """boundary.md and boundary.html of a boundary search: each axis's boundary and its interval, on
    the grid's pass rate where a grid was run beside it (``grids``: {axis, values, passed, n})."""
    directory = Path(directory)
    figures = {}
    bounds = result.get("boundaries") or []
    if bounds:
        plt = _plt()
        fig, axs = plt.subplots(1, len(bounds), figsize=(5.2 * len(bounds), 3.6), squeeze=False)
        for ax, b in zip(axs[0], bounds):
            grid = next((g for g in grids if g["axis"] == b["axis"]), None)
            if grid:
                rate = [p / n * 100 if n else math.nan for p, n in zip(grid["passed"], grid["n"])]
                ci = [wilson(p, n) for p, n in zip(grid["passed"], grid["n"])]
                ax.errorbar(grid["values"], rate, yerr=[[r - lo * 100 for r, (lo, _) in zip(rate, ci)],
                                                        [hi * 100 - r for r, (_, hi) in zip(rate, ci)]],
                            fmt="o-", capsize=3, label="grid pass rate")
            if b.get("value") is not None:
                ax.axvline(b["value"], color="#b00", label="boundary")
                lo, hi = b["interval"]
                ax.axvspan(lo, hi, color="#b00", alpha=0.15, label="interval")
            ax.set_ylim(-5, 105)
            ax.set_xlabel(b["axis"])
            ax.set_ylabel("pass rate (%)")
            ax.set_title(f"{b['requirement']}: {b['trials']} trials", fontsize=9)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(directory / "boundary.png", dpi=100)
        plt.close(fig)
        figures["boundary"] = "boundary.png"
    lines = [f"# Tolerance boundaries of {result.get('name') or directory.name}", "",
             "| axis | requirement | boundary | interval | trials | how |", "|---|---|---:|---|---:|---|"]
    for b in bounds:
        iv = b.get("interval") or [None, None]
        lines.append(f"| {b['axis']} | {b['requirement'] or '—'} | {_fmt(b.get('value'))} | "
                     f"[{_fmt(iv[0])}, {_fmt(iv[1])}] | {b['trials']} | {b.get('method', '')} |")
    lines += ["", "The boundary is where the lowest robustness crosses zero along the axis (the others at "
                  "their start); its interval brackets the crossing, widened by the spread of repeated "
                  "trials at the boundary where the spec repeats them.", ""]
    if figures:
        lines += [f"![boundaries]({figures['boundary']})", ""]
    return _write(directory, "boundary", "\n".join(lines), figures, f"Boundaries {directory.name}")
