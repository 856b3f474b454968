"""The lab tools and the trial against a hostile servo bus: one line, never a traceback.

A pseudo-terminal peer impersonates the rig's nine XM430-W350 (IDs 1-9) and answers
every ping, or every register read, the way a broken bus would: late, garbage, from the
wrong ID, with a bad CRC, with the servo's error bits set, truncated, short, long or not
at all. ``hilbench scan``, ``doctor``, ``check``, ``trial`` and ``jog`` run against it
as the technician would run them (real processes, the real driver); each must end in a
line that says what is wrong, and doctor must tell a malformed reply from no answer.

Each command runs in a process of its own, through hilbench's entry point, but forked from
one that has imported the commands already (:class:`ForkedHilbench`): what is tested here
is the command against the bus, not the interpreter's start-up, which test_signals.py
holds to account. The cases of one test run at once, each against its own peer, so their
waits for replies that never come overlap; jog runs on a terminal of its own, spawned.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Hashable, Iterable, Iterator, Mapping, Optional, Sequence

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
#: What the commands here import on demand: the forking process imports it once for all.
PRELOAD = ("bench.lab.doctor", "bench.lab.scan", "bench.trial.check", "bench.trial.run",
           "drivers.dynamixel.backend")

#: The forking process: imports hilbench's commands, then for each line of JSON on stdin (a
#: list of [argv, stdout file, stderr file]) forks one child per command, all at once, and
#: writes their pids, then their exit codes, as lines of JSON on the descriptor that was its
#: stdout. A child points stdin at /dev/null and stdout and stderr at its files, then runs
#: ``bench.cli.app.main``, the console script's own entry point, whose SystemExit ends the
#: child as it ends hilbench (exit code, atexit, an uncaught exception's traceback).
FORK_SERVER = r"""
import json, os, sys
replies = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)  # anything an import prints stays off the replies
import bench.cli.commands
for module in sys.argv[1:]:
    __import__(module)
from bench.cli.app import main
for line in sys.stdin:
    pids = []
    for argv, out, err in json.loads(line):
        pid = os.fork()
        if pid == 0:
            replies.close()
            for fd, path, flags in ((0, os.devnull, os.O_RDONLY),
                                    (1, out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                                    (2, err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
                opened = os.open(path, flags, 0o644)
                os.dup2(opened, fd)
                os.close(opened)
            sys.argv = argv
            main()
        pids.append(pid)
    replies.write(json.dumps(pids) + "\n")
    replies.flush()
    replies.write(json.dumps([os.waitstatus_to_exitcode(os.waitpid(p, 0)[1]) for p in pids]) + "\n")
    replies.flush()
"""


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
def impostor() -> Iterator[Callable[..., RigImpostor]]:
    """Makes a RigImpostor for the test; each one is closed after it."""
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


@dataclass(frozen=True)
class Run:
    """One hilbench command's run against its own impostor: how it ended and the peer it talked to."""

    returncode: int
    stdout: str
    stderr: str
    peer: RigImpostor


class ForkedHilbench:
    """hilbench commands as processes forked from one that imported them (:data:`FORK_SERVER`)."""

    def __init__(self, scratch: Path) -> None:
        self.scratch = scratch
        self._log = scratch / "fork-server.stderr"
        with open(self._log, "w") as log:
            self._server = subprocess.Popen([sys.executable, "-c", FORK_SERVER, *PRELOAD],
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log)
        self._pending = b""
        self._batches = 0

    def run_all(self, argvs: Sequence[Sequence[str]], timeout: float = 120.0) -> list[tuple[int, str, str]]:
        """Run every command at once; each one's (exit code, stdout, stderr). A command still
        running after ``timeout`` seconds is killed and the test fails."""
        self._batches += 1
        files = [(self.scratch / f"{self._batches}-{k}.out", self.scratch / f"{self._batches}-{k}.err")
                 for k in range(len(argvs))]
        batch = [[[HILBENCH, *argv], str(out), str(err)] for argv, (out, err) in zip(argvs, files)]
        assert self._server.stdin is not None
        self._server.stdin.write((json.dumps(batch) + "\n").encode())
        self._server.stdin.flush()
        deadline = time.monotonic() + timeout
        pids = self._reply(deadline)
        try:
            codes = self._reply(deadline)
        except TimeoutError:
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            self._reply(time.monotonic() + 30)
            raise AssertionError(f"a hilbench command ran over {timeout:.0f} s: {batch}") from None
        return [(code, out.read_text(), err.read_text()) for code, (out, err) in zip(codes, files)]

    def _reply(self, deadline: float) -> list[int]:
        """The server's next line (read unbuffered, so that waiting on its pipe is exact)."""
        assert self._server.stdout is not None
        fd = self._server.stdout.fileno()
        while b"\n" not in self._pending:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError
            chunk = os.read(fd, 4096)
            if not chunk:
                raise AssertionError(f"the fork server died: {self._log.read_text()[-3000:]}")
            self._pending += chunk
        line, _, self._pending = self._pending.partition(b"\n")
        return json.loads(line)

    def close(self) -> None:
        assert self._server.stdin is not None
        self._server.stdin.close()
        try:
            self._server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._server.kill()
            self._server.wait()


@pytest.fixture(scope="module")
def forked(tmp_path_factory) -> Iterator[ForkedHilbench]:
    server = ForkedHilbench(tmp_path_factory.mktemp("forked"))
    yield server
    server.close()


def against_impostors(server: ForkedHilbench, scratch: Path,
                      cases: Mapping[Hashable, tuple[str, Sequence[int]]],
                      argv: Callable[[Path, RigImpostor], list[str]]) -> dict[Hashable, Run]:
    """Every case's command, all at once, each against its own impostor: ``cases`` gives the
    misbehaviour and the instructions it answers so; ``argv`` the command, from a directory of
    the case's own and its impostor."""
    peers = {key: RigImpostor(behaviour, instructions) for key, (behaviour, instructions) in cases.items()}
    try:
        argvs = []
        for k, (key, peer) in enumerate(peers.items()):
            where = scratch / f"case-{k}"
            where.mkdir()
            argvs.append(argv(where, peer))
        done = server.run_all(argvs)
    finally:
        for peer in peers.values():
            peer.close()
    return {key: Run(code, out, err, peer) for (key, peer), (code, out, err) in zip(peers.items(), done)}


def lines(text: str) -> list[str]:
    return [x for x in text.splitlines() if x.strip()]


def assert_no_traceback(res: Run) -> None:
    for stream in (res.stdout, res.stderr):
        assert "Traceback" not in stream, stream[-3000:]


@pytest.fixture(scope="module")
def doctor_register_reads(forked, tmp_path_factory) -> dict[Hashable, Run]:
    """doctor against every misbehaviour of the register reads, after honest pings."""
    return against_impostors(forked, tmp_path_factory.mktemp("doctor-reads"),
                             {b: (b, [Instruction.READ]) for b in BEHAVIOURS},
                             lambda where, peer: ["doctor", str(rig_config(where, peer.port))])


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_doctor_ends_in_its_count_line_whatever_the_register_reads_get(doctor_register_reads, behaviour):
    """Every servo answers its ping, then its register reads go wrong: doctor fails each servo
    in one line naming a malformed reply or a late/lost one, never a traceback, and --json
    gives the reason and one line on stderr."""
    res = doctor_register_reads[behaviour]
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


@pytest.fixture(scope="module")
def doctor_pings(forked, tmp_path_factory) -> dict[Hashable, Run]:
    """doctor --json against pings answered with garbage, with error bits, or not at all."""
    return against_impostors(forked, tmp_path_factory.mktemp("doctor-pings"),
                             {b: (b, [Instruction.PING]) for b in ("garbage", "error_bits", "silent")},
                             lambda where, peer: ["doctor", str(rig_config(where, peer.port)), "--json"])


@pytest.mark.parametrize("behaviour", ["garbage", "error_bits", "silent"])
def test_doctor_tells_a_malformed_ping_reply_from_no_answer(doctor_pings, behaviour):
    res = doctor_pings[behaviour]
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


@pytest.fixture(scope="module")
def scans(forked, tmp_path_factory) -> dict[Hashable, Run]:
    """scan against every misbehaviour of both the broadcast pings and the register reads."""
    return against_impostors(forked, tmp_path_factory.mktemp("scans"),
                             {b: (b, [Instruction.PING, Instruction.READ]) for b in BEHAVIOURS},
                             lambda where, peer: ["scan", "--port", peer.port, "--baud", "1000000",
                                                  "--max-id", "10"])


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_scan_ends_in_one_line_on_any_reply(scans, behaviour):
    """Broadcast pings and register reads both misbehave: a table and its summary line, or one
    error line (exit 1), never a traceback."""
    res = scans[behaviour]
    assert_no_traceback(res)
    out = lines(res.stderr)
    if res.returncode == 0:
        assert out[-1] == "scanned 1000000 bps, IDs 0–10"
    else:
        assert res.returncode == 1 and len(out) == 1 and out[0].startswith("error: "), out


TRIAL_CASES = [(b, Instruction.PING if k % 2 else Instruction.READ) for k, b in enumerate(BEHAVIOURS)]


@pytest.fixture(scope="module")
def trials(forked, tmp_path_factory) -> dict[Hashable, Run]:
    """trial against each misbehaviour, of the pings or of the register reads by turns."""
    return against_impostors(forked, tmp_path_factory.mktemp("trials"),
                             {case: (case[0], [case[1]]) for case in TRIAL_CASES},
                             lambda where, peer: ["trial", str(rig_config(where, peer.port)),
                                                  "--out", str(where / "runs")])


@pytest.mark.parametrize("behaviour,instruction", TRIAL_CASES)
def test_trial_is_refused_in_one_line_before_torque_goes_on(trials, behaviour, instruction):
    res = trials[(behaviour, instruction)]
    assert_no_traceback(res)
    assert res.returncode == 2, res.stderr
    out = lines(res.stderr)
    assert len(out) == 1 and out[0].startswith("error: "), out
    assert not any(res.peer.tables[sid][64] for sid in IDS)  # Torque Enable never written to 1


def test_check_names_the_ports_and_leaves_the_bus_alone(forked, tmp_path):
    cases = {"garbage": ("garbage", [Instruction.PING, Instruction.READ])}
    (res,) = against_impostors(forked, tmp_path, cases,
                               lambda where, peer: ["check", str(rig_config(where, peer.port))]).values()
    assert_no_traceback(res)
    assert res.returncode == 0, res.stderr
    assert "ports: present and writable" in res.stdout
    assert res.peer.instructions == []  # check moves nothing and asks the servos nothing


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
