"""The emulated rig on the virtual clock: the real driver's code on ``virtual://`` lines, time that
advances only when each instant's work is done, and the same trial bit for bit on any machine."""

from __future__ import annotations

import json
import math
import multiprocessing
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.rig.emulated import VirtualRig
from drivers.clock import VirtualClock
from drivers.dynamixel.io import BlockingPortHandler, StuffingPacketHandler
from drivers.link import open_port
from drivers.virtual.protocol_virtual import Serial as VirtualSerial

REPO = Path(__file__).resolve().parents[1]
LAB = REPO / "hil_configs" / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


class _Ticker:
    """A device that does a piece of work every ``period`` s and notes when it ran."""

    def __init__(self, clock: VirtualClock, period: float, name: str, ran: list) -> None:
        self.clock, self.period, self.name, self.ran, self.k = clock, period, name, ran, 0

    def next_due(self) -> float:
        return (self.k + 1) * self.period

    def run_until(self, t: float) -> float:
        while self.next_due() <= t:
            self.k += 1
            self.ran.append((self.name, self.k * self.period, self.clock.now()))
            return self.k * self.period  # one piece at a time: the clock looks again
        return self.k * self.period


def test_the_virtual_clock_runs_its_devices_work_in_time_order_and_stops_when_asked():
    clock = VirtualClock()
    ran: list = []
    clock.attach(_Ticker(clock, 0.003, "slow", ran))
    clock.attach(_Ticker(clock, 0.002, "fast", ran))
    clock.advance(0.0125)
    instants = [t for _, t, _ in ran]
    assert instants == sorted(instants) and len(ran) == 6 + 4
    assert clock.now() == 0.0125
    # a wait until a condition stops at the first instant it holds, and says so
    assert clock.advance(1.0, until=lambda: len(ran) >= 12) and clock.now() == pytest.approx(0.015)
    assert not clock.advance(0.015, until=lambda: False) and clock.now() == pytest.approx(0.015)
    clock.advance(0.001)  # never backwards
    assert clock.now() == pytest.approx(0.015)
    empty = VirtualClock(5.0)
    assert not empty.advance(math.inf, until=lambda: False) and empty.now() == 5.0  # nothing due: it ends now


def test_the_driver_talks_to_a_virtual_line_through_the_same_packet_handler():
    """The SDK's packet handler on a port opened by URL: a ping's status comes after the wire's time
    at the bus's baud (instruction, return delay, status), on the clock and not the wall."""
    cfg = load_trial_config(LAB)
    with VirtualRig(cfg) as rig:
        port = BlockingPortHandler(rig.ports.dynamixel_port)
        assert port.openPort() and port.setBaudRate(cfg.backend.baud)
        clock = port.clock
        assert clock is rig.clock and clock.virtual
        assert isinstance(port.ser, VirtualSerial)  # the handler pyserial found for virtual://
        t0 = clock.now()
        sid = cfg.backend.servos["theta5"].id
        model, result, error = StuffingPacketHandler().ping(port, sid)
        took = clock.now() - t0
        port.closePort()
        assert result == 0 and error == 0 and model == rig.rig.bus.servo(sid).model_number
    wire = (10 + 14) * 10 / cfg.backend.baud + cfg.backend.return_delay_us * 1e-6  # PING, its status
    assert took == pytest.approx(wire, abs=2e-6)


def test_a_virtual_url_nothing_serves_is_refused_in_one_line(tmp_path):
    with pytest.raises(Exception, match="no emulated line 'nobody' in this process"):
        open_port("virtual://nobody", 1_000_000)
    data = yaml.safe_load(LAB.read_text())
    data["backend"]["port"] = "virtual://nobody"
    cfg = tmp_path / "virtual_port.yaml"
    cfg.write_text(yaml.safe_dump(data))
    res = subprocess.run([HILBENCH, "trial", str(cfg), "--out", str(tmp_path)], capture_output=True, text=True,
                         timeout=120)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and "virtual://nobody" in lines[0], res.stderr


@pytest.mark.parametrize("args, said", [(["--clock", "virtual"], "add --emulate"),
                                        (["--emulate", "--clock", "sometimes"], "choose realtime or virtual")])
def test_a_clock_a_real_rig_cannot_keep_is_refused_in_one_line(tmp_path, args, said):
    res = subprocess.run([HILBENCH, "trial", str(LAB), *args, "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and said in lines[0], res.stderr
    assert not any(tmp_path.iterdir())  # nothing ran, nothing written


def _hog(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def _arrays(run_dir: Path) -> dict[str, np.ndarray]:
    with np.load(run_dir / "trial.npz") as z:
        return {k: z[k] for k in z.files if k != "meta"}


#: What a trial's metadata records of the wall clock: when it started, how long its loop and its
#: cameras' measurements took.
WALL_FIELDS = {"start_time", "loop_wall_s", "wall_s", "cpu_s"}


def _without_wall(value):
    """``value`` (metadata) with every field of :data:`WALL_FIELDS` left out, at any depth."""
    if isinstance(value, dict):
        return {k: _without_wall(v) for k, v in value.items() if k not in WALL_FIELDS}
    if isinstance(value, list):
        return [_without_wall(v) for v in value]
    return value


def test_the_same_trial_on_the_virtual_clock_is_the_same_log_bit_for_bit_beside_two_cpu_hogs(tmp_path):
    """``hilbench trial lab_real.yaml --emulate --clock virtual`` twice, the second beside two CPU
    hogs: every array of the two logs is identical, and so is the metadata but for its wall-clock
    fields. The loop's timing is on the virtual clock: the trial's 8.4 s of Target 1, no deadline
    missed, its wall time reported beside it."""
    def trial(out: Path) -> dict:
        res = subprocess.run([HILBENCH, "trial", str(LAB), "--emulate", "--clock", "virtual", "--json",
                              "--out", str(out)], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        return json.loads(res.stdout)

    quiet = trial(tmp_path / "quiet")
    hogs = [multiprocessing.Process(target=_hog, args=(60.0,), daemon=True) for _ in range(2)]
    for h in hogs:
        h.start()
    try:
        loaded = trial(tmp_path / "loaded")
    finally:
        for h in hogs:
            h.terminate()
            h.join()
    for out in (quiet, loaded):
        timing = out["loop_timing"]
        assert out["passed"] and timing["clock"] == "virtual" and timing["missed"] == 0, timing
        assert timing["sim_s"] == pytest.approx(8.4) and timing["wall_s"] > 0, timing
        assert "torque off, confirmed" in out["safe_stop"]
    a, b = _arrays(Path(quiet["run_dir"])), _arrays(Path(loaded["run_dir"]))
    assert a.keys() == b.keys() and {"q", "q_cmd", "effort", "time", "loop_late", "bus_s"} <= set(a)
    different = [k for k in a if not np.array_equal(a[k], b[k], equal_nan=True)]
    assert not different, different
    meta_a, meta_b = (TrialLog.load(Path(o["run_dir"]) / "trial.npz").metadata for o in (quiet, loaded))
    assert _without_wall(meta_a) == _without_wall(meta_b)
    assert quiet["tip_deviation_mm"] == loaded["tip_deviation_mm"]


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_stop_signal_stops_a_virtual_trial_safely_with_one_line_and_128_plus_n(tmp_path, sig):
    """The virtual clock changes nothing of a trial's exit paths: a stop signal mid-trial ends it with
    the servos torque-off (read back from each), the log saved, one line and 128 + N."""
    import signal

    proc = subprocess.Popen([HILBENCH, "trial", str(LAB), "--emulate", "--clock", "virtual", "--out",
                             str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list(tmp_path.glob("*/trial.journal")):
        time.sleep(0.05)  # the run directory exists: the rig and the backend are being set up
    time.sleep(1.0)
    proc.send_signal(getattr(signal, sig))
    out, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert proc.returncode == 128 + getattr(signal, sig), err
    assert len(lines) == 1 and f"interrupted by {sig}" in lines[0], err
    assert "torque off, confirmed" in lines[0] or "never enabled" in lines[0], err
    assert "Traceback" not in err
