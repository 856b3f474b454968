"""`trial --capture FILE`: every byte the bench sent and received on its ports, with its time. On
the virtual clock the same file bit for bit; in real time the same instructions in the same order,
the plan's goals byte for byte."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.wirecapture import CAPTURE_HEADER, packets, read_capture

REPO = Path(__file__).resolve().parents[1]
LAB = REPO / "hil_configs" / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
SYNC_WRITE, FAST_SYNC_READ = 0x83, 0x8A
#: Instructions that only ask (ping, read, sync read, fast sync read, bulk read)
ASKING = {0x01, 0x02, 0x82, 0x8A, 0x92}
#: The servos whose goals the bench computes from readings: the train (its host loop closes on the
#: ultrasonic sensor) and the needle slide (the insertion is planned from the entry reached). The
#: others' goals are the plan's alone.
FROM_READINGS = {1, 9}


def _capture(tmp: Path, name: str, *clock: str) -> tuple[Path, dict]:
    path = tmp / f"{name}.txt"
    done = subprocess.run([HILBENCH, "trial", str(LAB), "--emulate", *clock, "--capture", str(path),
                           "--out", str(tmp / "runs"), "--json"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return path, json.loads(done.stdout)


def _goals(packet: bytes) -> dict[int, int]:
    """A Sync Write's goal per servo ID (4-byte items after the address and size)."""
    body = packet[12:-2]
    return {body[i]: int.from_bytes(body[i + 1:i + 5], "little", signed=True) for i in range(0, len(body), 5)}


def _commands(sent: list[bytes]) -> list[bytes]:
    """The instructions but the cycles' state reads, a question repeated at once counted once."""
    kept: list[bytes] = []
    for p in sent:
        if p[7] == FAST_SYNC_READ or (p[7] in ASKING and kept and kept[-1] == p):
            continue
        kept.append(p)
    return kept


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("capture")
    return {"virtual": _capture(tmp, "virtual", "--clock", "virtual"),
            "again": _capture(tmp, "again", "--clock", "virtual"),
            "realtime": _capture(tmp, "realtime")}


def test_a_virtual_trials_capture_is_the_same_file_bit_for_bit(captures):
    a, b = captures["virtual"][0], captures["again"][0]
    assert a.read_bytes() == b.read_bytes()
    chunks = read_capture(a)
    assert {c[1] for c in chunks} == {"dynamixel", "ultrasonic"}
    sent = packets(chunks, "dynamixel", ">")
    kinds = [p[7] for p in sent]
    cycles = captures["virtual"][1]["loop_timing"]["cycles"]
    # one goal write a cycle (and the last), one fast sync read a cycle, beside the set-up's
    assert kinds.count(SYNC_WRITE) >= cycles and kinds.count(FAST_SYNC_READ) >= cycles
    assert len(packets(chunks, "dynamixel", "<")) >= cycles
    for role in ("dynamixel", "ultrasonic"):  # each port's in the order it crossed, on the line's clock
        times = [c[0] for c in chunks if c[1] == role]
        assert times == sorted(times), role


def _cycles(run: dict, sent: list[bytes]) -> tuple[list[bytes], dict[str, list[bytes]], list[bytes], dict[str, float]]:
    """A trial's commands as the set-up's, each segment's goal writes (one a cycle, the log's
    segment of that cycle; the last, held, ends the last segment) and the safe stop's; and each
    segment's planned duration and settle, as the log's events state them."""
    from bench.trial.record import load_record

    log, _ = load_record(Path(run["run_dir"]))
    cycles = run["loop_timing"]["cycles"]
    writes = [i for i, p in enumerate(sent) if p[7] == SYNC_WRITE]
    assert len(writes) == cycles + 1  # one goal a cycle, and the last one, held to the safe stop
    segment = np.asarray(log.segment)[:cycles]
    goals = [sent[i] for i in writes[:cycles]]
    per_segment = {name: [g for g, s in zip(goals, segment) if s == k] for k, name in enumerate(log.segment_names)}
    per_segment[log.segment_names[-1]].append(sent[writes[-1]])  # the last goal, held: the last segment's end
    between = [p for p in sent[writes[0]:writes[-1]] if p[7] != SYNC_WRITE]  # the start's reads
    planned = {}
    for e in log.events:  # "start approach (2.842 s + 1.000 s settle)"
        if e.kind == "segment":
            name, move, settle = re.fullmatch(r"start (\S+) \(([\d.]+) s \+ ([\d.]+) s settle\)", e.message).groups()
            planned[name] = float(move) + float(settle)
    return sent[:writes[0]] + between, per_segment, sent[writes[-1] + 1:], planned


def test_the_real_time_capture_holds_the_same_instructions_in_the_same_order(captures):
    """The set-up and the safe stop byte for byte, and each segment's goals: the plan's byte for
    byte, the train's and the slide's (computed from readings) within a reading's noise. A plan's
    move from the start is re-aimed at the first reading, the train's on the ultrasonic sensor:
    where a real-time start read a millimetre off and the move from it took a cycle more or less,
    that segment is a different plan, its length is what its planned duration says, and the
    segments planned alike are compared."""
    virtual = _commands(packets(read_capture(captures["virtual"][0]), "dynamixel", ">"))
    real = _commands(packets(read_capture(captures["realtime"][0]), "dynamixel", ">"))
    v_setup, v_segments, v_stop, v_planned = _cycles(captures["virtual"][1], virtual)
    r_setup, r_segments, r_stop, r_planned = _cycles(captures["realtime"][1], real)
    assert v_setup == r_setup and v_stop == r_stop  # every register access outside the cycles
    assert v_segments.keys() == r_segments.keys() == v_planned.keys() == r_planned.keys()
    dt = captures["virtual"][1]["loop_timing"]["period_s"]
    plan_only, expected, compared = 0, 0, []
    for name, a in v_segments.items():
        b = r_segments[name]
        if v_planned[name] != r_planned[name]:  # re-aimed at another first reading: its length is its plan's
            assert name == "approach" and abs(len(a) - len(b) - round((v_planned[name] - r_planned[name]) / dt)) <= 1, (
                name, v_planned[name], r_planned[name], len(a), len(b))
            continue
        assert len(a) == len(b), (name, v_planned[name])
        compared.append(name)
        expected += 7 * len(a)  # the seven servos whose goals are the plan's alone
        for ga, gb in zip(map(_goals, a), map(_goals, b)):
            assert ga.keys() == gb.keys()
            for sid in ga.keys() - FROM_READINGS:
                assert ga[sid] == gb[sid], (name, sid, ga[sid], gb[sid])
                plan_only += 1
            for sid in ga.keys() & FROM_READINGS:  # a reading's millimetre of noise, a few ticks
                assert abs(ga[sid] - gb[sid]) <= 20, (name, sid, ga[sid], gb[sid])
    assert {"insert", "retract"} <= set(compared)  # planned from the entry, never re-aimed
    assert plan_only >= expected


def test_capture_is_refused_where_there_is_no_bus_and_a_file_that_is_not_one_is_named(tmp_path):
    done = subprocess.run([HILBENCH, "trial", str(REPO / "hil_configs" / "sim_target1.yaml"), "--capture",
                           str(tmp_path / "c.txt"), "--out", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode == 2 and "--capture" in done.stderr and "pybullet" in done.stderr
    assert len([ln for ln in done.stderr.splitlines() if ln.strip()]) == 1
    bad = tmp_path / "bad.txt"
    bad.write_text(CAPTURE_HEADER + "\n0.1 dynamixel > zz\n")
    with pytest.raises(ValueError, match="line 2"):
        read_capture(bad)
