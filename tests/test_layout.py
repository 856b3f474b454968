"""The code's layout rules (README, "Layout"): import contracts, small modules, imports at the top.

``lint-imports`` checks the layers, the independence of the features and the
absence of cycles (pyproject.toml); the rest is read from the source here.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "drivers", "trajectories")
MAX_LINES = 500
#: Dependencies a function may import where it needs them: heavy to import, or optional extras.
DEFERRABLE = {"matplotlib", "scipy", "trimesh", "dask", "distributed", "pybullet", "dynamixel_sdk",
              "pexpect", "PIL", "cma"}


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
    exe = Path(sys.executable).with_name("lint-imports")
    cmd = [str(exe)] if exe.exists() else [shutil.which("lint-imports") or "lint-imports"]
    res = subprocess.run(cmd + ["--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    assert "0 broken" in res.stdout


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
