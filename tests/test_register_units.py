"""Register units written once: each control-table register carries its SI unit and converter
(drivers/dynamixel/control_table.py, from the units in drivers/dynamixel/units.py), and no other
module of the bench or the drivers types a raw unit of its own."""

from __future__ import annotations

import ast
import math
import re
from pathlib import Path

import pytest

from drivers.dynamixel import units
from drivers.dynamixel.control_table import XL430_W250, XM430_W350, model_spec, supported_models, x_series_table

ROOT = Path(__file__).resolve().parents[1]
#: The two files where a register unit is written.
HOMES = {Path("drivers/dynamixel/units.py"), Path("drivers/dynamixel/control_table.py")}
RPM = 2 * math.pi / 60


# -- the converters, against the e-manual ---------------------------------------------------------
@pytest.mark.parametrize(("name", "raw", "si", "unit"), [
    ("Present Position", 2048, 0.0, "rad"),
    ("Present Position", 3072, math.pi / 2, "rad"),
    ("Goal Position", 0, -math.pi, "rad"),
    ("Homing Offset", 1024, math.pi / 2, "rad"),
    ("Present Velocity", 1, 0.229 * RPM, "rad/s"),
    ("Profile Velocity", 100, 22.9 * RPM, "rad/s"),
    ("Profile Acceleration", 1, 214.577 * 2 * math.pi / 3600, "rad/s²"),
    ("Return Delay Time", 250, 500e-6, "s"),
    ("Present Input Voltage", 120, 12.0, "V"),
    ("Max Voltage Limit", 160, 16.0, "V"),
    ("Present PWM", 885, 1.0, "1"),
    ("Goal PWM", -442.5, -0.5, "1"),
    ("Present Temperature", 80, 80.0, "°C"),
    ("Goal Current", 1, 2.69e-3, "A"),
    ("Current Limit", 1193, 1193 * 2.69e-3, "A"),
    ("Realtime Tick", 1000, 1.0, "s"),
    ("Bus Watchdog", 5, 0.1, "s"),
])
def test_each_register_converts_to_si_as_the_e_manual_says(name, raw, si, unit):
    register = x_series_table()[name]
    assert register.unit == unit
    assert register.to_si(raw) == pytest.approx(si, rel=1e-12, abs=1e-15)
    assert register.from_si(si) == pytest.approx(raw, rel=1e-12, abs=1e-9)


def test_decimal_units_convert_exactly():
    """What a servo reports in tenths of a volt reads as the volts it means (12.0 V, not
    12.000000000000002), and back to the same raw value: what doctor and scan print."""
    table = x_series_table()
    volts = table["Present Input Voltage"]
    assert [volts.to_si(raw) for raw in (95, 120, 140, 160)] == [9.5, 12.0, 14.0, 16.0]
    assert all(volts.from_si(volts.to_si(raw)) == raw for raw in range(256))
    assert table["Present PWM"].from_si(1.0) == 885.0 and table["Present PWM"].to_si(885) == 1.0
    assert table["Realtime Tick"].to_si(1234) == 1.234


def test_the_nearest_raw_value_is_what_a_decimal_setting_means():
    """A Return Delay Time of 123 µs is 61.5 units, written 62 (as round(123 / 2)), whatever the
    float quotient's last bit; the whole range agrees with integer arithmetic."""
    rdt = x_series_table()["Return Delay Time"]
    assert [rdt.nearest(us * 1e-6) for us in range(0, 509)] == [int(round(us / 2)) for us in range(0, 509)]
    pos = x_series_table()["Goal Position"]
    assert pos.nearest(0.0) == 2048 and pos.nearest(-math.pi / 2) == 1024
    assert pos.nearest(pos.to_si(1234)) == 1234


def test_models_without_current_sensing_report_load_in_tenths_of_a_percent():
    xl = model_spec(XL430_W250)
    assert "Present Current" not in xl.table and xl.table["Present Load"].unit == "1"
    assert xl.table["Present Load"].to_si(1000) == pytest.approx(1.0)
    assert xl.amps_per_unit == pytest.approx(xl.motor.stall_current / 1000)
    xm = model_spec(XM430_W350)
    assert xm.amps_per_unit == xm.table["Present Current"].scale == pytest.approx(2.69e-3)


#: Words in a register name that say it holds a physical quantity.
_PHYSICAL = re.compile(r"Position|Velocity|Acceleration|Current|Voltage|Temperature|PWM|Load|Delay|"
                       r"Offset|Threshold|Realtime|Watchdog")


@pytest.mark.parametrize("model", sorted(supported_models()))
def test_every_physical_register_has_a_unit(model):
    """Codes, counts, flags and gains have none; everything else says what it is in SI."""
    missing = [r.name for r in model_spec(model).table
               if _PHYSICAL.search(r.name) and not r.name.endswith("Gain") and not r.unit]
    assert not missing, f"{supported_models()[model]}: no unit for {missing}"


# -- no raw unit outside its home --------------------------------------------------------------------
#: Values that are a register unit wherever they appear in code: Return Delay Time (2 µs), velocity
#: (0.229 rev/min), 0.088°, acceleration (214.577 rev/min²), current (2.69 mA), full PWM (885), the
#: Homing Offset range, and the servos' ±0.29° tolerance (written once, in the arc-and-train model).
_ALWAYS = {2e-6: "Return Delay Time unit", 0.229: "velocity unit", 0.088: "tick in degrees",
           0.087890625: "tick in degrees", 214.577: "acceleration unit", 0.00269: "current unit",
           2.69: "current unit (mA)", 885: "PWM full scale", 1_044_479: "Homing Offset range",
           0.29: "servo tolerance (bench.kinematics.arc_train.SERVO_TOL_DEG)"}
_TOLERANCE_HOME = Path("bench/kinematics/arc_train.py")
#: Values that are a unit in arithmetic whose words say so: (values, words, what).
_IN_CONTEXT = [
    ({2048, 4096}, re.compile(r"tick|cent(er|re)|\bpi\b|position|rad"), "ticks (use the position register)"),
    ({2, 0.5, 500_000}, re.compile(r"delay|rdt"), "Return Delay Time unit"),
    ({10, 0.1}, re.compile(r"volt|tenths"), "voltage unit"),
    ({1000, 0.001}, re.compile(r"stall|load"), "Present Load unit"),
]


def _is_number(node: ast.AST) -> bool:
    return (isinstance(node, ast.Constant) and isinstance(node.value, (int, float))
            and not isinstance(node.value, bool))


def raw_units(path: Path, rel: Path) -> list[str]:
    """``file:line what`` for each raw unit constant in a source file (strings and comments,
    where a unit may be explained, are not code and are not read)."""
    tree = ast.parse(path.read_text())
    found: set[tuple[int, str]] = set()
    function_of: dict[ast.AST, str] = {}
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                function_of[node] = fn.name
    for node in ast.walk(tree):
        if _is_number(node):
            value = node.value
            what = next((w for v, w in _ALWAYS.items() if math.isclose(value, v, rel_tol=1e-9)), None)
            if what and not (value == 0.29 and rel == _TOLERANCE_HOME):
                found.add((node.lineno, what))
        pairs: list[tuple[ast.AST, str]] = []
        if isinstance(node, ast.BinOp):
            pairs = [(side, ast.unparse(node)) for side in (node.left, node.right)]
        elif isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            pairs = [(node.value, " ".join(ast.unparse(t) for t in targets))]
        elif isinstance(node, ast.arguments):
            named = node.args[len(node.args) - len(node.defaults):] + node.kwonlyargs
            pairs = [(d, a.arg) for a, d in zip(named, node.defaults + node.kw_defaults) if d is not None]
        for side, text in pairs:
            if not _is_number(side):
                continue
            words = (text + " " + function_of.get(node, "")).lower()
            for values, pattern, what in _IN_CONTEXT:
                if side.value in values and pattern.search(words):
                    found.add((side.lineno, what))
    return [f"{rel}:{line} {what}" for line, what in sorted(found)]


def test_no_raw_register_unit_outside_the_units_and_the_table():
    hits = []
    for pkg in ("bench", "drivers"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if rel not in HOMES:
                hits += raw_units(path, rel)
    assert not hits, "convert through the register (control_table.py) instead:\n" + "\n".join(hits)


def test_the_scan_finds_each_kind_of_raw_unit(tmp_path):
    """The scan above is not a formality: the leftovers it was written against are each found."""
    src = tmp_path / "leftovers.py"
    src.write_text('''"""Docstrings may say 0.229 rev/min and tick 2048."""
import math
CHUNK = 2048  # a buffer, not a tick
zero_tick = 2048
def status(rdt, volts, stall_current, current, want_rdt):
    delay = rdt * 2e-6  # Return Delay Time
    deadband = round(0.5 / (2 * math.pi / 4096))
    ok = 2 * round(want_rdt / 2)
    v = volts / 10.0
    load = current / stall_current * 1000.0
    return read(fd, 4096), 0.29, 885
def _tenths(value):
    return value / 10.0
''')
    hits = raw_units(src, Path("leftovers.py"))
    assert [h.split()[0] for h in hits] == [
        "leftovers.py:4", "leftovers.py:6", "leftovers.py:7", "leftovers.py:8",
        "leftovers.py:9", "leftovers.py:10", "leftovers.py:11", "leftovers.py:11", "leftovers.py:13"]


#: The unit scales of units.py (every float it exports, and the whole fractions).
SCALES = {name for name in units.__all__ if isinstance(getattr(units, name), float)} | {
    "PWM_FULL_SCALE", "VOLTAGE_UNITS_PER_V", "LOAD_UNITS_PER_STALL", "REALTIME_TICKS_PER_S"}


def test_only_the_control_table_imports_the_unit_scales():
    """Every other module converts through a register, so a unit lives in one table."""
    assert {"RAD_PER_TICK", "VELOCITY_UNIT_RAD_S", "RETURN_DELAY_UNIT_S", "CURRENT_UNIT_A"} <= SCALES
    bad = []
    for pkg in ("bench", "drivers", "trajectories"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if rel in HOMES:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.module == "drivers.dynamixel.units":
                    bad += [f"{rel}:{node.lineno} {a.name}" for a in node.names if a.name in SCALES]
    assert not bad, "\n".join(bad)
