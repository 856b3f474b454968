"""One light errors module and one exit-code table, used everywhere.

``drivers/errors.py`` holds every error the project raises on purpose, under
``BenchError``, and the exit codes; it imports the standard library alone, so the
command line catches by class without loading the library, and its entry point
loads nothing heavy before its stop-signal handlers are in.
"""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

import drivers.errors as errors
from drivers.errors import BenchError, ExitCode, safe_stop_unconfirmed, signal_exit_code

ROOT = Path(__file__).resolve().parents[1]


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; before = set(sys.modules); {statement}; print(' '.join(set(sys.modules) - before))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    return set(res.stdout.split())


def test_the_errors_and_the_entry_point_load_no_heavy_library():
    for statement in ("import drivers.errors", "import drivers", "import bench.cli.app"):
        loaded = {m.split(".")[0] for m in _loaded_after(statement)}
        assert not loaded & {"numpy", "typer", "rich", "pydantic", "yaml", "serial", "scipy"}, (statement, loaded)


def test_every_error_class_is_a_bench_error_and_its_old_home_names_the_same_class():
    classes = [c for _, c in inspect.getmembers(errors, inspect.isclass)
               if issubclass(c, Exception) and c.__module__ == errors.__name__]
    assert len(classes) >= 20 and all(issubclass(c, BenchError) for c in classes)
    from bench.compare.session import CompareError
    from bench.config.models import ConfigError
    from bench.core.result import TrialError
    from bench.kinematics.needle import UnreachableError
    from drivers.ultrasonic import StaleReadingError
    from trajectories import TrajectoryError

    assert TrajectoryError is errors.TrajectoryError and issubclass(TrajectoryError, ValueError)
    assert (CompareError, ConfigError, TrialError, UnreachableError, StaleReadingError) == (
        errors.CompareError, errors.ConfigError, errors.TrialError, errors.UnreachableError,
        errors.StaleReadingError)


def test_no_two_error_names_differ_by_a_suffix_alone():
    """ConfigError and ConfigurationError were two classes a reader could not tell apart."""
    names = [n for n in errors.__all__ if n.endswith("Error")]
    stems = [n[:-len("Error")].lower() for n in names]
    for a in stems:
        for b in stems:
            assert a == b or not (b.startswith(a) and b[len(a):] in ("uration", "ure", "s")), (a, b)


def test_exit_codes():
    assert [int(c) for c in (ExitCode.PASSED, ExitCode.FAILED, ExitCode.REFUSED,
                             ExitCode.STOP_UNCONFIRMED)] == [0, 1, 2, 3]
    assert signal_exit_code(2) == 130 and signal_exit_code(15) == 143 and signal_exit_code(1) == 129
    assert safe_stop_unconfirmed("torque off NOT confirmed for servo ID(s) [1] of 9: check the rig")
    assert safe_stop_unconfirmed("hold not confirmed: bus lost")
    assert not safe_stop_unconfirmed("torque off, confirmed by reading Torque Enable back from all 9 servos")
    assert not safe_stop_unconfirmed(None) and not safe_stop_unconfirmed("")


def _exit_literals(path: Path) -> list[str]:
    """Calls that end the process or a command with a number written out: ``typer.Exit(1)``,
    ``sys.exit(2)``, ``os._exit(70)``, ``fail(..., 130)``, ``SystemExit(1)``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call):
            continue
        name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
        args = list(node.args) + [k.value for k in node.keywords if k.arg == "code"]
        if name in ("Exit", "exit", "_exit", "SystemExit") and args[:1]:
            args = args[:1]
        elif name == "fail" and len(args) >= 2:
            args = args[1:2]
        else:
            continue
        if any(isinstance(a, ast.Constant) and isinstance(a.value, int) for a in args):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


@pytest.mark.parametrize("package", ["bench", "drivers"])
def test_exit_codes_come_from_the_table_never_a_literal(package):
    found = [hit for p in sorted((ROOT / package).rglob("*.py")) for hit in _exit_literals(p)]
    assert not found, found


def test_every_error_class_is_defined_in_the_one_errors_module():
    """The README's promise: every error the project raises on purpose is in drivers/errors.py."""
    import importlib
    import pkgutil

    import bench
    import drivers
    import trajectories
    from drivers.errors import BenchError

    for package in (bench, drivers, trajectories):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            importlib.import_module(info.name)
    seen, todo = set(), [BenchError]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            if sub not in seen:
                seen.add(sub)
                todo.append(sub)
    ours = [c for c in seen if c.__module__.split(".")[0] in ("bench", "drivers", "trajectories")]
    elsewhere = sorted(f"{c.__module__}.{c.__qualname__}" for c in ours if c.__module__ != "drivers.errors")
    assert not elsewhere, elsewhere
    assert len(ours) > 20
