"""The lab tools and the trial against a hostile servo bus: one line, never a traceback.

A pseudo-terminal peer impersonates the rig's nine XM430-W350 (IDs 1-9) and answers
every ping, or every register read, the way a broken bus would: late, garbage, from the
wrong ID, with a bad CRC, with the servo's error bits set, truncated, short, long or not
at all. ``hilbench scan``, ``doctor``, ``check``, ``trial`` and ``jog`` run against it
as the technician would run them (real processes, the real driver); each must end in a
line that says what is wrong, and doctor must tell a malformed reply from no answer.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Iterable, Optional

import pytest
import yaml

from drivers.dynamixel.protocol import Instruction, build_status
from test_hostile_peer import FIRMWARE, MODEL, HostilePeer

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
IDS = range(1, 10)
#: Every misbehaviour of a reply the driver is held to (test_hostile_peer.py's, plus error bits).
BEHAVIOURS = ("late", "garbage", "wrong_id", "bad_crc", "error_bits", "truncated", "short", "long",
              "silent")


def _table() -> bytearray:
    """An XM430-W350's control table at rest: 1 Mbps, position mode, 12 V, 35 °C, no fault."""
    t = bytearray(256)
    t[0:2] = MODEL.to_bytes(2, "little")
    t[6], t[8], t[11] = FIRMWARE, 3, 3
    t[31] = 80  # Temperature Limit
    t[32:34], t[34:36] = (160).to_bytes(2, "little"), (95).to_bytes(2, "little")  # voltage limits
    t[144:146], t[146] = (120).to_bytes(2, "little"), 35  # Present Input Voltage, Temperature
    return t


class RigImpostor(HostilePeer):
    """The rig's nine servos on a pty, answering broadcast pings too; ``behaviour`` for every
    request whose instruction is in ``instructions``, honest otherwise."""

    def __init__(self, behaviour: str, instructions: Iterable[int], seed: int = 0) -> None:
        wanted = frozenset(int(i) for i in instructions)
        super().__init__(seed, 0.0, policy=lambda r: behaviour if r.instruction in wanted else "honest")
        self.tables = {sid: _table() for sid in IDS}

    def _honest(self, request):
        if request.id == 0xFE and request.instruction == Instruction.PING:
            return b"".join(build_status(sid, 0, bytes(t[0:2]) + bytes((FIRMWARE,)))
                            for sid, t in self.tables.items()), {}
        return super()._honest(request)


@pytest.fixture
def impostor():
    peers: list[RigImpostor] = []

    def make(behaviour: str, *instructions: int) -> RigImpostor:
        peers.append(RigImpostor(behaviour, instructions))
        return peers[-1]

    yield make
    for p in peers:
        p.close()


def rig_config(tmp_path: Path, port: str, ultrasonic: Optional[str] = None) -> Path:
    """lab_real.yaml pointed at ``port``; the ultrasonic sensor dropped (or on ``ultrasonic``)."""
    cfg = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())
    cfg["backend"]["port"] = port
    if ultrasonic is None:
        cfg["backend"].pop("ultrasonic")
    else:
        cfg["backend"]["ultrasonic"]["port"] = ultrasonic
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def hilbench(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=timeout)


def lines(text: str) -> list[str]:
    return [x for x in text.splitlines() if x.strip()]


def assert_no_traceback(res: subprocess.CompletedProcess) -> None:
    for stream in (res.stdout, res.stderr):
        assert "Traceback" not in stream, stream[-3000:]


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_doctor_ends_in_its_count_line_whatever_the_register_reads_get(impostor, tmp_path, behaviour):
    """Every servo answers its ping, then its register reads go wrong: doctor fails each servo
    in one line naming a malformed reply or a late/lost one, never a traceback, and --json
    gives the reason and one line on stderr."""
    peer = impostor(behaviour, Instruction.READ)
    cfg = rig_config(tmp_path, peer.port)
    res = hilbench("doctor", str(cfg))
    assert_no_traceback(res)
    assert res.returncode == 1, res.stderr
    out = lines(res.stderr)
    assert out[-1].startswith("not ready: 9 failed"), out
    servo_lines = [x for x in out if x.startswith("FAIL") and "(ID " in x]
    assert len(servo_lines) == 9
    malformed = [x for x in servo_lines if "malformed reply: answers a ping, then not a register read" in x]
    lost = [x for x in servo_lines if "answers a ping, then no reply to a register read" in x]
    assert len(malformed) + len(lost) == 9, servo_lines  # and none says "no answer"
    if behaviour == "silent":
        assert not malformed
    elif behaviour != "late":  # bytes came back; a starved machine may still see some too late
        assert malformed, servo_lines


@pytest.mark.parametrize("behaviour", ["garbage", "error_bits", "silent"])
def test_doctor_tells_a_malformed_ping_reply_from_no_answer(impostor, tmp_path, behaviour):
    peer = impostor(behaviour, Instruction.PING)
    cfg = rig_config(tmp_path, peer.port)
    res = hilbench("doctor", str(cfg), "--json")
    assert_no_traceback(res)
    assert res.returncode == 1
    assert len(lines(res.stdout)) == 1 and len(lines(res.stderr)) == 1
    assert lines(res.stderr)[0].startswith("not ready: ")
    servos = [c for c in json.loads(res.stdout)["checks"] if "(ID " in c["name"]]
    assert len(servos) == 9 and all(c["status"] == "fail" for c in servos)
    answers = [c["detail"].split(" at 1000000 bps")[0] for c in servos]
    assert set(answers) <= {"malformed reply", "no answer"}, answers
    if behaviour == "silent":
        assert set(answers) == {"no answer"}
    else:  # bytes came back; a starved machine may see some too late, never all
        assert "malformed reply" in answers, answers


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_scan_ends_in_one_line_on_any_reply(impostor, behaviour):
    """Broadcast pings and register reads both misbehave: a table and its summary line, or one
    error line (exit 1), never a traceback."""
    peer = impostor(behaviour, Instruction.PING, Instruction.READ)
    res = hilbench("scan", "--port", peer.port, "--baud", "1000000", "--max-id", "10")
    assert_no_traceback(res)
    out = lines(res.stderr)
    if res.returncode == 0:
        assert out[-1] == "scanned 1000000 bps, IDs 0–10"
    else:
        assert res.returncode == 1 and len(out) == 1 and out[0].startswith("error: "), out


@pytest.mark.parametrize("behaviour,instruction", [
    (b, Instruction.PING if k % 2 else Instruction.READ) for k, b in enumerate(BEHAVIOURS)])
def test_trial_is_refused_in_one_line_before_torque_goes_on(impostor, tmp_path, behaviour, instruction):
    peer = impostor(behaviour, instruction)
    cfg = rig_config(tmp_path, peer.port)
    res = hilbench("trial", str(cfg), "--out", str(tmp_path / "runs"))
    assert_no_traceback(res)
    assert res.returncode == 2, res.stderr
    out = lines(res.stderr)
    assert len(out) == 1 and out[0].startswith("error: "), out
    assert not any(peer.tables[sid][64] for sid in IDS)  # Torque Enable never written to 1


def test_check_names_the_ports_and_leaves_the_bus_alone(impostor, tmp_path):
    peer = impostor("garbage", Instruction.PING, Instruction.READ)
    res = hilbench("check", str(rig_config(tmp_path, peer.port)))
    assert_no_traceback(res)
    assert res.returncode == 0, res.stderr
    assert "ports: present and writable" in res.stdout
    assert peer.instructions == []  # check moves nothing and asks the servos nothing


@pytest.mark.parametrize("behaviour", ["garbage", "late", "error_bits"])
def test_jog_ends_in_one_line_with_torque_off(impostor, tmp_path, behaviour):
    pexpect = pytest.importorskip("pexpect")
    peer = impostor(behaviour, Instruction.READ)
    child = pexpect.spawn(HILBENCH, ["jog", str(rig_config(tmp_path, peer.port))], timeout=60,
                          encoding="utf-8", dimensions=(40, 120))
    child.expect(pexpect.EOF)
    child.close()
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", child.before)  # the terminal's colours
    assert "Traceback" not in text, text
    assert child.exitstatus == 1, text
    out = lines(text)
    assert len(out) == 1 and out[0].startswith("error: ") and out[0].endswith("torque off"), out
    assert not any(peer.tables[sid][64] for sid in IDS)
