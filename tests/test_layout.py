"""The code's layout rules (README, "Layout"): import contracts, small modules, imports at the top,
no import cycle (type-only imports included) and no dead name.

``lint-imports`` checks the layers (the bench's and those inside ``drivers/``), the
independence of the features and the absence of run-time cycles (pyproject.toml); the
rest is read from the source here.
"""

from __future__ import annotations

import ast
import shutil
from collections import defaultdict
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "drivers", "trajectories")
#: Code outside the packages that may be the only user of a name.
USERS = ("tests", "benchmarks")
MAX_LINES = 500
#: Dependencies a function may import where it needs them: heavy to import, or optional extras.
DEFERRABLE = {"matplotlib", "scipy", "trimesh", "dask", "distributed", "pybullet", "dynamixel_sdk",
              "pexpect", "PIL", "cma", "cv2", "rtamt"}


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def _function_imports(path: Path):
    tree = ast.parse(path.read_text())
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom):
                    yield node, ("." if node.level else "") + (node.module or "")
                elif isinstance(node, ast.Import):
                    for alias in node.names:
                        yield node, alias.name


def test_import_contracts_hold():
    res = _lint_imports(ROOT)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    assert "0 broken" in res.stdout


def _lint_imports(cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lint-imports")
    cmd = [str(exe)] if exe.exists() else [shutil.which("lint-imports") or "lint-imports"]
    return subprocess.run(cmd + ["--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_the_drivers_layers_refuse_an_import_of_the_emulator(tmp_path):
    """The contract inside ``drivers/`` is not a formality: a backend reaching for the emulator
    (its rig is reached only through bench.rig) breaks it."""
    for name in (*PACKAGES, "pyproject.toml"):
        src = ROOT / name
        (shutil.copytree(src, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
         if src.is_dir() else shutil.copy(src, tmp_path / name))
    with (tmp_path / "drivers" / "pybullet" / "stepped.py").open("a") as f:
        f.write("\nimport drivers.emulator  # noqa\n")
    res = _lint_imports(tmp_path)
    assert res.returncode != 0
    assert "drivers.pybullet is not allowed to import drivers.emulator" in res.stdout, res.stdout[-3000:]


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _all_imports(root: Path, packages=PACKAGES) -> dict[tuple[str, str], int]:
    """Every project import (importer, imported) -> line, wherever it is written: at the top,
    in a function or under ``if TYPE_CHECKING:``."""
    files = {_module_name(p, root): p for pkg in packages for p in (root / pkg).rglob("*.py")}
    edges: dict[tuple[str, str], int] = {}

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    for module, path in files.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            for target in targets:
                found = known(target) if target.split(".")[0] in packages else None
                if found and found != module:
                    edges.setdefault((module, found), node.lineno)
    return edges


def _import_cycles(edges) -> list[str]:
    """Cycles among the children of any package (the modules of one package, the subpackages
    of one package, the top-level packages), as ``a -> b -> a``."""
    graphs: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for a, b in edges:
        pa, pb = a.split("."), b.split(".")
        n = 0
        while n < min(len(pa), len(pb)) and pa[n] == pb[n]:
            n += 1
        if n in (len(pa), len(pb)):
            continue  # a package and its own module: not siblings
        graphs[".".join(pa[:n])][".".join(pa[: n + 1])].add(".".join(pb[: n + 1]))
    cycles = []
    for graph in graphs.values():
        state: dict[str, int] = {}

        def visit(node: str, stack: list[str]) -> None:
            state[node] = 1
            for nxt in sorted(graph.get(node, ())):
                if state.get(nxt) == 1:
                    cycles.append(" -> ".join(stack[stack.index(nxt):] + [node, nxt]))
                elif nxt not in state:
                    visit(nxt, stack + [node])
            state[node] = 2

        for node in sorted(graph):
            if node not in state:
                visit(node, [])
    return cycles


def test_no_import_cycle_at_any_level_type_only_imports_included():
    """lint-imports leaves out ``if TYPE_CHECKING:`` imports (they never run); a cycle made of
    them still ties two modules together, so it is refused here."""
    cycles = _import_cycles(_all_imports(ROOT))
    assert not cycles, "break these cycles:\n" + "\n".join(cycles)


def test_a_type_only_cycle_is_caught(tmp_path):
    pkg = tmp_path / "bench" / "config"
    pkg.mkdir(parents=True)
    (tmp_path / "bench" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "models.py").write_text("from bench.config.calibration import check\n")
    (pkg / "calibration.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .models import Config\n")
    assert _import_cycles(_all_imports(tmp_path, ("bench",))) == [
        "bench.config.calibration -> bench.config.models -> bench.config.calibration"]


def _dead_names(root: Path, packages=PACKAGES, users=USERS) -> list[str]:
    """Module-level functions, classes and constants of the packages that no code (the packages,
    the tests, the benchmarks) names outside their own definition. A decorated function is
    registered by its decorator (a CLI command, a validator), so it counts as used."""
    sources = [p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))]
    readers = sources + [p for d in users for p in sorted((root / d).rglob("*.py"))]
    defined: list[tuple[Path, int, str]] = []
    seen: dict[str, set[tuple[Path, int]]] = defaultdict(set)
    for path in readers:
        tree = ast.parse(path.read_text())
        if path in sources:
            for node in tree.body:
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    if not node.decorator_list:
                        defined.append((path, node.lineno, node.name))
                elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                    for t in (node.targets if isinstance(node, ast.Assign) else [node.target]):
                        if isinstance(t, ast.Name):
                            defined.append((path, node.lineno, t.id))
        for node in ast.walk(tree):
            if isinstance(node, ast.Name):
                seen[node.id].add((path, node.lineno))
            elif isinstance(node, ast.Attribute):
                seen[node.attr].add((path, node.lineno))
            elif isinstance(node, ast.alias):
                seen[node.name.rpartition(".")[2]].add((path, node.lineno))
    return [f"{path.relative_to(root)}:{line} {name}" for path, line, name in defined
            if not name.startswith("__") and not seen[name] - {(path, line)}]


def test_no_dead_name():
    dead = _dead_names(ROOT)
    assert not dead, "nothing uses these; delete them:\n" + "\n".join(dead)


def test_a_dead_name_is_caught(tmp_path):
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "geo.py").write_text(
        "LIVE = 1\nDEAD = 2\n\ndef rot_x(a):\n    return a\n\ndef used():\n    return LIVE\n")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_geo.py").write_text("from bench.geo import used\n")
    assert _dead_names(tmp_path, ("bench",), ("tests",)) == ["bench/geo.py:2 DEAD", "bench/geo.py:4 rot_x"]


def test_no_source_file_is_over_500_lines():
    long = {str(p.relative_to(ROOT)): n for p in _sources()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"split these at a natural seam: {long}"


def test_imports_inside_functions_are_deferred_dependencies_with_a_reason():
    """Project modules are imported at the top (a cycle is fixed, not hidden); a function may
    import a heavy or optional dependency, saying why on the same line. The CLI alone defers
    its library imports, so ``hilbench --help`` and completion stay fast."""
    bad = []
    for path in _sources():
        rel = path.relative_to(ROOT)
        lines = path.read_text().splitlines()
        in_cli = rel.parts[:2] == ("bench", "cli")
        for node, module in _function_imports(path):
            root = module.lstrip(".").split(".")[0]
            commented = any("#" in line for line in lines[node.lineno - 1:node.end_lineno])
            allowed = root in DEFERRABLE or (in_cli and root in PACKAGES)
            if not (allowed and commented):
                bad.append(f"{rel}:{node.lineno} {module}" + ("" if allowed else " (import it at the top)"))
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_says_why_it_exists(package):
    missing = [str(p.relative_to(ROOT)) for p in (ROOT / package).rglob("__init__.py")
               if ast.get_docstring(ast.parse(p.read_text())) is None]
    assert not missing, missing
