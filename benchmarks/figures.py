"""The bench's measured figures in one place: rows the benchmarks write, rendered as a table.

``docs/figures.json`` holds one row per figure: what was measured, the value, the script
that measured it and when, on what. A benchmark run with ``--write-table`` replaces its own
rows (:func:`record`) and renders ``docs/figures.md`` again; nobody edits the page by hand
(``python benchmarks/figures.py --check`` and the test suite compare it with the rows). The
README's table of the twin's figures is rendered from the same rows.
Prose in the docs links here instead of quoting a number.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "figures.json"
PAGE = ROOT / "docs" / "figures.md"
README = ROOT / "README.md"
#: The README's table of the twin's figures lies between these lines: the rows whose key starts
#: with ``monitor.``, rendered as the page renders them, so the front page states them as measured.
README_BLOCK = ("<!-- The twin's figures: generated from docs/figures.json by benchmarks/figures.py. -->",
                "<!-- End of the twin's figures. -->")
FIELDS = ("key", "what", "value", "by", "measured")

HEADER = """# Measured figures

<!-- Generated from figures.json by benchmarks/figures.py: run a benchmark with --write-table
     to measure again; do not edit this page by hand. -->

Every figure the docs cite, as the benchmark that measured it last wrote it: what was
measured, the value, the script (run it with `--write-table` to measure again and
replace its rows) and when, on what machine and code.

| figure | value | measured by | when, on what |
| --- | --- | --- | --- |
"""


def load() -> list[dict]:
    """The rows, in their order; each one has every field."""
    rows = json.loads(DATA.read_text())
    for row in rows:
        missing = [f for f in FIELDS if not row.get(f)]
        if missing:
            raise ValueError(f"{DATA.name}: row {row.get('key')!r} has no {', '.join(missing)}")
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _lines(rows: list[dict]) -> list[str]:
    return [f"| {_cell(r['what'])} | {_cell(r['value'])} | `{r['by']}` | {_cell(r['measured'])} |"
            for r in rows]


def render(rows: list[dict]) -> str:
    """The page: the header, then one table row per figure."""
    return HEADER + "\n".join(_lines(rows)) + "\n"


def render_readme(rows: list[dict], text: str) -> str:
    """``text`` (the README) with the table between :data:`README_BLOCK`'s lines made from ``rows``."""
    start, end = README_BLOCK
    head, found, rest = text.partition(start + "\n")
    _, closed, tail = rest.partition(end)
    if not (found and closed):
        raise ValueError(f"{README.name} has no block of the twin's figures ({start} ... {end})")
    table = ["| figure | value | measured by | when, on what |", "| --- | --- | --- | --- |",
             *_lines([r for r in rows if r["key"].startswith("monitor.")])]
    return head + start + "\n" + "\n".join(table) + "\n" + end + tail


def provenance(note: str = "") -> str:
    """When, on what code and machine: the date, the commit, the cores and the load."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "no checkout"
    load = os.getloadavg()[1]
    text = f"{dt.date.today().isoformat()}, commit {commit}, {os.cpu_count()} cores at load {load:.1f}"
    return f"{text}; {note}" if note else text


def record(by: str, figures: dict[str, tuple[str, str]], note: str = "") -> None:
    """Replace the rows of ``figures`` (key: (what, value)) measured by the script ``by``, keep
    every other row where it was, and render the page again."""
    rows = load() if DATA.exists() else []
    when = provenance(note)
    keys = [r["key"] for r in rows]
    for key, (what, value) in figures.items():
        row = {"key": key, "what": what, "value": value, "by": by, "measured": when}
        if key in keys:
            rows[keys.index(key)] = row
        else:
            rows.append(row)
            keys.append(key)
    DATA.write_text(json.dumps(rows, indent=2, ensure_ascii=False) + "\n")
    PAGE.write_text(render(rows))
    if README.exists():
        README.write_text(render_readme(rows, README.read_text()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="fail if docs/figures.md is not the rows' rendering")
    args = ap.parse_args()
    rows = load()
    text, readme = render(rows), render_readme(rows, README.read_text())
    if args.check:
        for path, want in ((PAGE, text), (README, readme)):
            if path.read_text() != want:
                sys.exit(f"{path.relative_to(ROOT)} is not generated from {DATA.name}; "
                         f"run python benchmarks/figures.py")
        return
    PAGE.write_text(text)
    README.write_text(readme)


if __name__ == "__main__":
    main()
