"""Who may build an emulator: bench.rig (the robot's emulated rig) and one module of the test stand
(bench.stand.emulated, its servo and pendulum); every other room reaches an emulated rig through
them. Read from the source here, and held by ``lint-imports`` (pyproject.toml), whose contract
must name every room there is."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The modules that may import drivers.emulator, and the packages all of whose modules may.
ALLOWED_MODULES = {"bench.stand.emulated"}
ALLOWED_PACKAGES = ("bench.rig",)
CONTRACT = "The emulated rig is reached through bench.rig alone"


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports_emulator(path: Path) -> list[int]:
    """Lines of ``path`` importing drivers.emulator (or a module of it), however written."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
        if any(n == "drivers.emulator" or n.startswith("drivers.emulator.") for n in names):
            lines.append(node.lineno)
    return lines


def _allowed(module: str) -> bool:
    return module in ALLOWED_MODULES or any(module == p or module.startswith(p + ".")
                                            for p in ALLOWED_PACKAGES)


def test_only_the_rig_and_the_emulated_stand_import_the_emulator():
    found = {(_module(p), line) for pkg in ("bench", "trajectories") for p in (ROOT / pkg).rglob("*.py")
             for line in _imports_emulator(p)}
    importers = {m for m, _ in found}
    assert {"bench.rig.emulated", "bench.stand.emulated"} <= importers  # the scan sees what is there
    refused = sorted(f"{m}:{line}" for m, line in found if not _allowed(m))
    assert not refused, f"only bench.rig and bench.stand.emulated may import drivers.emulator: {refused}"


def test_the_contract_names_every_room_but_the_rig():
    """A room added later is under the rule from its first commit, not once someone remembers it."""
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    contract = next(c for c in contracts if c["name"] == CONTRACT)
    rooms = {f"bench.{p.name}" if p.is_dir() else f"bench.{p.stem}" for p in (ROOT / "bench").iterdir()
             if (p.is_dir() and (p / "__init__.py").exists()) or (p.suffix == ".py" and p.stem != "__init__")}
    assert set(contract["source_modules"]) == (rooms - set(ALLOWED_PACKAGES)) | {"trajectories"}
    assert contract["ignore_imports"] == [f"{m} -> drivers.emulator" for m in sorted(ALLOWED_MODULES)]


def test_lint_imports_refuses_the_stand_reaching_the_emulator_elsewhere(tmp_path):
    """The allowance is one module wide: the stand's session importing the emulator breaks the contract."""
    for name in ("bench", "drivers", "trajectories", "pyproject.toml"):
        src = ROOT / name
        (shutil.copytree(src, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
         if src.is_dir() else shutil.copy(src, tmp_path / name))
    with (tmp_path / "bench" / "stand" / "session.py").open("a") as f:
        f.write("\nimport drivers.emulator  # noqa\n")
    exe = Path(sys.executable).with_name("lint-imports")
    cmd = [str(exe)] if exe.exists() else [shutil.which("lint-imports") or "lint-imports"]
    res = subprocess.run(cmd + ["--no-cache"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode != 0
    assert "bench.stand is not allowed to import drivers.emulator" in res.stdout, res.stdout[-3000:]
    assert "bench.stand.session -> drivers.emulator" in res.stdout
