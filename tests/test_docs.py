"""The README is a front page and the reference is a site: the README short, its two set-up
commands as CI runs them, every link it has pointing at a page that exists; the measured
figures one generated table the benchmarks write; the site built strictly when MkDocs is here."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = (REPO / "README.md").read_text()
MAIN_JOB = ("python3 -m venv .venv && .venv/bin/pip install -e . && "
            ".venv/bin/hilbench trial hil_configs/sim_target1.yaml")
TESTS = ("python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && "
         ".venv/bin/pytest -q -n 3 --dist loadfile")


def _figures():
    spec = importlib.util.spec_from_file_location("figures", REPO / "benchmarks" / "figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _slug(title: str) -> str:
    return re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", title).strip().lower())


def test_the_readme_is_a_front_page_with_the_two_set_up_commands():
    lines = README.splitlines()
    assert len(lines) <= 250, len(lines)
    assert f"```bash\n{MAIN_JOB}\n```" in README and f"```bash\n{TESTS}\n```" in README
    for section in ("## Set-up", "## A first session at the rig", "## Commands", "## Where to read more"):
        assert section in README, section
    assert "| `hilbench init DIR` |" in README


def test_every_readme_link_reaches_a_page_and_its_anchor():
    links = re.findall(r"\]\(((?!https?:)[^)]+)\)", README)
    assert links
    for link in links:
        path, _, anchor = link.partition("#")
        target = REPO / path
        assert target.exists(), link
        if anchor:
            headings = [_slug(h) for h in re.findall(r"^#+ (.+)$", target.read_text(), re.M)]
            assert anchor in headings, link


def test_the_figures_page_is_the_rendering_of_the_rows_the_benchmarks_write():
    figures = _figures()
    rows = figures.load()
    assert rows and (REPO / "docs" / "figures.md").read_text() == figures.render(rows)
    readme = (REPO / "README.md").read_text()  # the front page's table of the twin's figures, too
    assert readme == figures.render_readme(rows, readme)
    assert "| Twin on clean Target 1 trials of servo-model sims" in readme
    for row in rows:  # each one written by a script that can write it again
        script = REPO / row["by"]
        assert script.is_file() and "--write-table" in script.read_text(), row["by"]
        assert "record(" in script.read_text(), row["by"]


def test_record_replaces_a_scripts_rows_and_keeps_the_rest(tmp_path, monkeypatch):
    figures = _figures()
    monkeypatch.setattr(figures, "DATA", tmp_path / "figures.json")
    monkeypatch.setattr(figures, "PAGE", tmp_path / "figures.md")
    readme = tmp_path / "README.md"
    readme.write_text(f"# A\n\n{figures.README_BLOCK[0]}\n{figures.README_BLOCK[1]}\n\n## B\n")
    monkeypatch.setattr(figures, "README", readme)
    figures.record("benchmarks/a.py", {"a.one": ("first", "1 s"), "a.two": ("second", "2 s")})
    figures.record("benchmarks/b.py", {"b.one": ("other", "3 s")})
    figures.record("benchmarks/a.py", {"a.one": ("first", "1.5 s")})
    rows = json.loads((tmp_path / "figures.json").read_text())
    assert [(r["key"], r["value"]) for r in rows] == [("a.one", "1.5 s"), ("a.two", "2 s"), ("b.one", "3 s")]
    assert all(r["measured"] for r in rows)
    assert (tmp_path / "figures.md").read_text() == figures.render(rows)
    assert "| first | 1.5 s | `benchmarks/a.py` |" in (tmp_path / "figures.md").read_text()
    figures.record("benchmarks/m.py", {"monitor.x": ("the twin's", "4 s")})  # the README's: monitor rows
    text = readme.read_text()
    assert text.startswith("# A\n\n") and text.endswith(f"{figures.README_BLOCK[1]}\n\n## B\n")
    assert "| the twin's | 4 s | `benchmarks/m.py` |" in text and "first" not in text


def test_the_layout_page_states_the_layers_once_as_the_contract_does():
    layout = (REPO / "docs" / "layout.md").read_text()
    assert layout.count("- Layers, top to bottom") == 1
    assert "## The servo core" in layout
    contract = re.search(r'name = "Layers: ([^"]+)"', (REPO / "pyproject.toml").read_text()).group(1)
    order = [p.strip() for p in contract.replace("features", "").split(">")]
    assert [p.split()[0] for p in order if p][:1] == ["cli"]
    for package in ("stand", "trial", "report", "core", "rig", "config", "scene", "kinematics", "paths"):
        assert f"`{package}`" in layout


def test_the_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra is not installed (CI builds the site itself)")
    pytest.importorskip("material", reason="the docs extra is not installed")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, timeout=120,
                          env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "site" / "figures" / "index.html").is_file()
