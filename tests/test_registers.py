"""`hilbench registers`: one servo's whole control table, decoded through the register table, as
the emulated servo holds it; --watch refreshes the RAM area while the joint moves."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from cli_in_process import invoke as _invoke
from bench.lab.registers import read_table, watch_table
from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.control_table import XM430_W350, model_spec

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
#: Registers that change by themselves between two reads (time, the shaft, the supply, the drive).
VOLATILE = {"Realtime Tick", "Present PWM", "Present Current", "Present Velocity", "Present Position",
            "Velocity Trajectory", "Position Trajectory", "Present Input Voltage", "Present Temperature",
            "Moving", "Moving Status"}


def test_every_register_of_the_xm430_table_decoded_as_the_emulator_holds_it(cold_rig):
    rig, cfg = cold_rig
    sid = cfg.backend.servos["theta4"].id
    spec = model_spec(XM430_W350)
    with ServoBus(cfg.backend.port, cfg.backend.baud) as bus:
        table = read_table(bus, sid)
    assert table.model == "XM430-W350" and table.id == sid
    assert [r.name for r in table.registers] == [r.name for r in spec.table]  # every one, by address
    servo = rig.bus.servo(sid)
    for r in table.registers:
        reg = spec.table[r.name]
        assert (r.address, r.size, r.access) == (reg.address, reg.size, reg.access.value)
        if r.name not in VOLATILE:
            with rig.bus.lock:
                assert r.raw == servo.get(r.name), r.name
        if reg.unit:
            assert r.unit == reg.unit and r.value == pytest.approx(float(reg.to_si(r.raw)))
        else:
            assert r.value is None and r.unit == ""
    by_name = {r.name: r for r in table.registers}
    assert by_name["ID"].raw == sid and by_name["Torque Enable"].raw == 0
    assert by_name["Present Input Voltage"].unit == "V" and 10 < by_name["Present Input Voltage"].value < 14
    assert by_name["Current Limit"].value == pytest.approx(by_name["Current Limit"].raw * 2.69e-3)
    assert by_name["Goal Position"].value == pytest.approx((by_name["Goal Position"].raw - 2048) * 3.14159265 / 2048)


def test_watch_refreshes_present_position_while_the_joint_moves(cold_rig):
    rig, cfg = cold_rig
    sid = cfg.backend.servos["theta4"].id
    seen, goal = [], None
    with ServoBus(cfg.backend.port, cfg.backend.baud) as bus:
        for k, table in enumerate(watch_table(bus, sid, period_s=0.1, stop=lambda: len(seen) >= 12)):
            rows = {r.name: r for r in table.registers}
            seen.append(rows["Present Position"].raw)
            assert len(table.registers) == len(model_spec(XM430_W350).table)  # EEPROM rows kept
            if k == 1:  # jog the joint by 200 ticks through the same bus, as `hilbench jog` would
                goal = rows["Present Position"].raw + 200
                bus.write(sid, "Torque Enable", 1)
                bus.write(sid, "Goal Position", goal)
        bus.write(sid, "Torque Enable", 0)
    assert abs(seen[1] - goal + 200) <= 3  # still before the jog
    assert abs(seen[-1] - goal) <= 10  # the watch saw it arrive
    assert len(set(seen[2:])) >= 3  # and saw it on the way


def test_the_cli_prints_one_json_line_and_refuses_bad_calls_in_one_line():
    done = _invoke("registers", str(LAB), "--emulate", "--clock", "virtual", "--id", "2", "--json")
    assert done.exit_code == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["id"] == 2 and out["model"] == "XM430-W350"
    assert set(out["registers"][0]) == {"name", "address", "size", "access", "raw", "value", "unit"}
    assert len(out["registers"]) == len(model_spec(XM430_W350).table)
    for args, words in (([], "give a CONFIG"), (["--port", "/dev/null"], "--port needs --baud"),
                        ([str(LAB), "--watch", "--json"], "--watch shows a live table"),
                        ([str(LAB), "--emulate", "--id", "77"], "servo ID 77 did not answer")):
        args = args if "--id" in args else [*args, "--id", "1"]
        if "--emulate" in args:  # the emulated rig in real time: a process of its own, the installed command
            done = subprocess.run([HILBENCH, "registers", *args], capture_output=True, text=True, timeout=120)
            bad = SimpleNamespace(exit_code=done.returncode, stderr=done.stderr)
        else:
            bad = _invoke("registers", *args)
        assert bad.exit_code in (1, 2) and words in bad.stderr, bad.stderr
        assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr


def test_the_cli_watch_shows_present_position_follow_a_jog_until_ctrl_c(cold_rig):
    """`registers --watch` as the technician runs it, in a terminal: while another master on the
    bus jogs the joint 300 ticks, the live table's Present Position walks there; Ctrl-C ends it."""
    pexpect = pytest.importorskip("pexpect")
    rig, cfg = cold_rig
    sid = cfg.backend.servos["theta4"].id
    table = model_spec(XM430_W350).table
    servo = rig.bus.servo(sid)
    child = pexpect.spawn(HILBENCH, ["registers", "--port", cfg.backend.port, "--baud", str(cfg.backend.baud),
                                     "--id", str(sid), "--watch"], timeout=60, dimensions=(200, 140),
                          env={**os.environ, "LINES": "200", "COLUMNS": "140"}, encoding="utf-8")
    row = r"Present Position\W+%d\W+4\W+R\W+(-?\d+)" % table["Present Position"].address  # across the │
    try:
        child.expect(row)
        start = int(child.match.group(1))
        goal = start + 300
        slow = int(table["Profile Velocity"].from_si(0.4))  # rad/s: 300 ticks take about a second
        with rig.bus.lock:  # the jog: the WRITEs `hilbench jog` sends, applied as the servo applies them
            assert servo.write(table["Profile Velocity"].address, slow.to_bytes(4, "little")) == 0
            assert servo.write(table["Torque Enable"].address, bytes([1])) == 0
            assert servo.write(table["Goal Position"].address, goal.to_bytes(4, "little", signed=True)) == 0
        seen = []
        while not seen or abs(seen[-1] - goal) > 10:
            child.expect(row)  # each refresh redraws the table, Present Position with it
            seen.append(int(child.match.group(1)))
        child.sendintr()
        child.expect(pexpect.EOF)
    finally:
        child.close(force=True)
        with rig.bus.lock:
            servo.write(table["Torque Enable"].address, bytes([0]))
    assert len(set(seen)) >= 3 and all(start - 3 <= v <= goal + 10 for v in seen)  # seen on its way
