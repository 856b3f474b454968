"""The bench's measured figures in one place: rows the benchmarks write, rendered as a table.

``docs/figures.json`` holds one row per figure: what was measured, the value, the script
that measured it and when, on what. A benchmark run with ``--write-table`` replaces its own
rows (:func:`record`) and renders ``docs/figures.md`` again; nobody edits the page by hand
(``python benchmarks/figures.py --check`` and the test suite compare it with the rows).
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


def render(rows: list[dict]) -> str:
    """The page: the header, then one table row per figure."""
    lines = [f"| {_cell(r['what'])} | {_cell(r['value'])} | `{r['by']}` | {_cell(r['measured'])} |" for r in rows]
    return HEADER + "\n".join(lines) + "\n"


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="fail if docs/figures.md is not the rows' rendering")
    args = ap.parse_args()
    text = render(load())
    if args.check:
        if PAGE.read_text() != text:
            sys.exit(f"{PAGE.relative_to(ROOT)} is not generated from {DATA.name}; "
                     f"run python benchmarks/figures.py")
        return
    PAGE.write_text(text)


if __name__ == "__main__":
    main()
