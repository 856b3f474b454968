"""Reports of the campaigns that search: a falsification's robustness curve and falsifying trial,
and each axis's tolerance boundary beside the grid's pass rate — Markdown and one HTML page."""

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
    if result.get("error"):  # refused before it moved (a target out of reach) or broken: no margin
        lines[-2] = f"- {'violated' if result['falsified'] else 'lowest'}: the trial errored: {result['error']}"
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


def write_boundary_report(directory: Path | str, result: dict, grids: Sequence[dict] = (),
                          pair_grids: Sequence[dict] = ()) -> Path:
    """boundary.md and boundary.html of a boundary search: each axis's boundary and its interval, on
    the grid's pass rate where a grid was run beside it (``grids``: {axis, values, passed, n}), and
    each pair's boundary curve, on its plane's grid (``pair_grids``: {axes, values, passed, n})."""
    directory = Path(directory)
    figures = {}
    bounds = result.get("boundaries") or []
    if bounds:
        figures["boundary"] = _axes_figure(directory / "boundary.png", bounds, grids)
    for k, pair in enumerate(result.get("pairs") or []):
        grid = next((g for g in pair_grids if g["axes"] == pair["axes"]), None)
        figures[f"pair{k}"] = _pair_figure(directory / f"boundary_pair{k or ''}.png", pair, grid)
    lines = [f"# Tolerance boundaries of {result.get('name') or directory.name}", "",
             "| axis | requirement | boundary | interval | interval from | trials | how |",
             "|---|---|---:|---|---|---:|---|"]
    for b in bounds:
        iv = b.get("interval") or [None, None]
        lines.append(f"| {b['axis']} | {b['requirement'] or '—'} | {_fmt(b.get('value'))} | "
                     f"[{_fmt(iv[0])}, {_fmt(iv[1])}] | {_KINDS.get(b.get('interval_kind'), '—')} | "
                     f"{b['trials']} | {b.get('method', '')} |")
    lines += ["", "The boundary is where the lowest robustness crosses zero along the axis (the others at "
                  "their start). For a deterministic trial its interval is the final bracket; for a random "
                  "one it is the range of the crossings of several seeds (every trial of a seed with that "
                  "seed), and the boundary their median: where half of the trials fail.", ""]
    if "boundary" in figures:
        lines += [f"![boundaries]({figures['boundary']})", ""]
    for k, pair in enumerate(result.get("pairs") or []):
        a, b = pair["axes"]
        lines += [f"## The plane of {a} and {b}", "", f"{pair['trials']} trials; rays from the corner where "
                  "both are at their start, each bracketed as an axis is.", "",
                  f"| ray | {a} | {b} | interval along the ray | requirement | trials |",
                  "|---:|---:|---:|---|---|---:|"]
        for r in pair["rays"]:
            pt = r["point"] or [None, None]
            iv = ", ".join(f"({_fmt(x)}, {_fmt(y)})" for x, y in r["interval"]) if r["interval"] else "—"
            lines.append(f"| {r['angle_deg']:g}° | {_fmt(pt[0])} | {_fmt(pt[1])} | {iv} | "
                         f"{r['requirement'] or '—'} | {r['trials']} |")
        lines += ["", f"![boundary in the plane]({figures[f'pair{k}']})", ""]
    return _write(directory, "boundary", "\n".join(lines), figures, f"Boundaries {directory.name}")


_KINDS = {"bracket": "the bracket", "seeds": "the seeds' crossings"}


def _axes_figure(path: Path, bounds: Sequence[dict], grids: Sequence[dict]) -> str:
    """Each axis's boundary, its interval and its seeds' crossings, on the grid's pass rate."""
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
        if b.get("interval") is not None:
            lo, hi = b["interval"]
            ax.axvspan(lo, hi, color="#b00", alpha=0.15, label="interval")
        if b.get("value") is not None:
            ax.axvline(b["value"], color="#b00", label="boundary")
        seeds = [c for c in b.get("crossings") or [] if c is not None]
        if b.get("interval_kind") == "seeds" and seeds:
            ax.plot(seeds, [50.0] * len(seeds), "x", color="#600", label="seeds' crossings")
        ax.set_ylim(-5, 105)
        ax.set_xlabel(b["axis"])
        ax.set_ylabel("pass rate (%)")
        ax.set_title(f"{b['requirement']}: {b['trials']} trials", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path.name


def _pair_figure(path: Path, pair: dict, grid: dict | None) -> str:
    """The boundary curve in the plane of two axes, its intervals along the rays, on the plane's
    grid of pass rates where one was run."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 4.6))
    if grid:
        xs, ys, rate = [], [], []
        for i, x in enumerate(grid["values"][0]):
            for j, y in enumerate(grid["values"][1]):
                xs.append(x)
                ys.append(y)
                rate.append(100 * grid["passed"][i][j] / grid["n"][i][j] if grid["n"][i][j] else math.nan)
        dots = ax.scatter(xs, ys, c=rate, cmap="RdYlGn", vmin=0, vmax=100, s=36, edgecolors="#444",
                          linewidths=0.4, label="grid pass rate")
        fig.colorbar(dots, ax=ax, label="pass rate (%)")
    for r in pair["rays"]:
        if r["interval"]:
            (x0, y0), (x1, y1) = r["interval"]
            ax.plot([x0, x1], [y0, y1], color="#b00", alpha=0.35, lw=6, solid_capstyle="round")
    pts = pair["points"]
    if pts:
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color="#b00", label="boundary")
    ax.set_xlabel(pair["axes"][0])
    ax.set_ylabel(pair["axes"][1])
    ax.set_title(f"{pair['trials']} trials, {len(pair['rays'])} rays", fontsize=9, pad=24)
    ax.grid(alpha=0.3)
    # above the plane, not over it: the curve and the grid reach every corner
    ax.legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path.name
