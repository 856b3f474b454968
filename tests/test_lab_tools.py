"""The lab-rig tools (scan, doctor, calibrate, jog) against the emulated rig on pseudo-terminals."""

from __future__ import annotations

import contextlib
import gc
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.config.models import ConfigError, load_trial_config
from bench.kinematics.registry import get_robot
from bench.rig.emulated import EmulatedRig, Planted

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
TICK = 2 * math.pi / 4096


def hilbench(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=timeout)


def rig_config(path: Path, rig: EmulatedRig, base: dict, **top) -> Path:
    """A config file like ``base`` with its ports pointed at the rig, and the emulated sensor's
    staleness allowance that ``--emulate`` gives (the emulator shares this loaded host's CPU)."""
    from bench.rig.emulated import EMULATOR_STALE_S

    data = json.loads(json.dumps(base))
    data["backend"]["port"] = rig.ports.dynamixel_port
    data["backend"]["ultrasonic"]["port"] = rig.ports.ultrasonic_port
    data["backend"]["ultrasonic"]["stale_after_s"] = EMULATOR_STALE_S
    data.update(top)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@contextlib.contextmanager
def emulated(*args, **kwargs):
    """An EmulatedRig serving from this process's threads, answering even when the host is busy.

    The session's heap is frozen out of the garbage collector meanwhile (a full
    collection over it holds the interpreter for ~0.1 s), and the physics catches
    up in 20 ms slices between answers: the emulated servos never go silent for
    long just because the machine is loaded.
    """
    gc.collect()
    gc.freeze()
    try:
        with EmulatedRig(*args, **kwargs) as rig:
            rig.bus.max_batch_s = 0.02
            yield rig
    finally:
        gc.unfreeze()


def lab_data(**servo_changes) -> dict:
    data = yaml.safe_load(LAB.read_text())
    for servo in data["backend"]["servos"].values():
        servo.update(servo_changes)
    return data


# ---------------------------------------------------------------------------
# scan and doctor: a bus with planted problems
# ---------------------------------------------------------------------------

# Two servos at 57600 bps (the config says 1 Mbps), a wrong model on ID 6, an overload on ID 3.
FAULTS = Planted(servo_registers={"theta5": {"Baud Rate": 1}, "d9": {"Baud Rate": 1}},
                 servo_models={"theta7": "XM540-W270"})


@pytest.fixture(scope="module")
def faulty_rig(tmp_path_factory):
    cfg = load_trial_config(LAB)
    with emulated(cfg, planted=FAULTS) as rig:
        rig.bus.servo(3).raise_hardware_error("overload")
        yield rig, rig_config(tmp_path_factory.mktemp("faulty") / "lab.yaml", rig, lab_data())


def test_scan_all_bauds_finds_every_servo(faulty_rig):
    rig, _ = faulty_rig
    t0 = time.monotonic()
    out = hilbench("scan", "--port", rig.ports.dynamixel_port, "--all-bauds", "--json")
    elapsed = time.monotonic() - t0
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("\n") == 1
    found = {s["id"]: s for s in json.loads(out.stdout)}
    assert sorted(found) == list(range(1, 10))
    assert {i: s["baud"] for i, s in found.items()} == {
        i: 57_600 if i in (4, 8) else 1_000_000 for i in range(1, 10)}
    assert found[6]["model"] == "XM540-W270" and found[6]["model_number"] == 1120
    assert all(found[i]["model"] == "XM430-W350" for i in found if i != 6)
    assert found[3]["hardware_error"] == ["overload"] and found[3]["torque"] is False
    assert all(not found[i]["hardware_error"] and found[i]["torque"] for i in found if i != 3)
    assert found[1]["operating_mode"] == "extended_position" and found[2]["operating_mode"] == "position"
    assert all(s["firmware"] == 48 and s["voltage_v"] == 12.0 for s in found.values())
    assert elapsed < 40  # 8 broadcast pings (about 11 s of waiting for IDs up to 252), not minutes


def test_doctor_flags_exactly_the_planted_problems(faulty_rig):
    _, path = faulty_rig
    out = hilbench("doctor", str(path), "--json")
    assert out.returncode == 1, out.stderr
    report = json.loads(out.stdout)
    assert report["ok"] is False
    checks = {c["name"]: c for c in report["checks"]}
    failed = {n for n, c in checks.items() if c["status"] == "fail"}
    assert failed == {"theta5 (ID 4)", "d9 (ID 8)", "theta7 (ID 6)", "theta4 hardware error"}
    assert all(f"{name}: {checks[name]['detail']}" in report["reason"] for name in failed)
    assert not [n for n, c in checks.items() if c["status"] == "warn"]
    assert "57600" in checks["theta5 (ID 4)"]["detail"] and "57600" in checks["d9 (ID 8)"]["detail"]
    assert "XM540-W270" in checks["theta7 (ID 6)"]["detail"]
    assert "overload" in checks["theta4 hardware error"]["detail"]
    assert "pseudo-terminal" in checks["latency timer"]["detail"]
    joints = ["train", "theta3", "theta4", "theta5", "theta6", "theta7", "theta8", "d9", "d10"]
    for j in joints:  # every servo was found (at some rate) and its health read
        for item in ("hardware error", "voltage", "temperature", "settings"):
            assert f"{j} {item}" in checks
    for name in ("servo port", "ultrasonic port", "ultrasonic stream", "ultrasonic range",
                 "ultrasonic vs train servo", "calibration"):
        assert checks[name]["status"] == "pass", checks[name]
    stream = checks["ultrasonic stream"]["detail"]  # measured against the nominal rate, counted
    rate = float(stream.split(" readings/s")[0])
    assert abs(rate - 50) < 10 and "(nominal 50)" in stream
    assert "0 unreadable line(s), 0 no-target reading(s) (R5000)" in stream
    assert len(checks) == len(report["checks"])  # one line per check, names unique


def test_doctor_port_and_latency_lines(tmp_path, monkeypatch):
    import bench.lab.doctor as doctor

    port = tmp_path / "ttyUSB0"
    port.write_text("")
    checks = []

    def add(name, status, detail):
        checks.append((name, status, detail))

    monkeypatch.setattr(doctor, "latency_timer_ms", lambda p: 16)
    doctor._latency_check(add, str(port), True)
    monkeypatch.setattr(doctor, "latency_timer_ms", lambda p: 1)
    doctor._latency_check(add, str(port), True)
    monkeypatch.setattr(doctor.os, "access", lambda p, mode: False)
    doctor._port_check(add, "servo port", str(port))
    doctor._port_check(add, "servo port", str(tmp_path / "ttyUSB9"))
    (n1, s1, d1), (_, s2, d2), (_, s3, d3), (_, s4, d4) = checks
    assert (n1, s1) == ("latency timer", "warn") and "16 ms" in d1 and "FTDI default" in d1
    assert "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer" in d1
    assert (s2, d2) == ("pass", f"1 ms on {port}")
    assert s3 == "fail" and "sudo usermod -aG dialout $USER" in d3
    assert s4 == "fail" and "not found" in d4


# ---------------------------------------------------------------------------
# calibrate: planted zero errors and a miscalibrated ultrasonic sensor
# ---------------------------------------------------------------------------

# within the plausible 2° / 2 mm of a hand-mounted horn (a larger change is refused as sag)
ZERO_ERRORS = {"train": math.radians(-1.5), "theta5": math.radians(1.8), "d9": 1.2e-3, "d10": -0.8e-3}
ULTRA_OFFSET_M, ULTRA_SCALE = 0.004, 1.02


@pytest.fixture
def miscalibrated_rig(tmp_path):
    """The robot held at its reference (home): integral gain on every joint, physics settled; on the
    virtual clock, so what calibration recovers is the same on any machine, however loaded."""
    from drivers.clock import VirtualClock

    base = lab_data(position_i=300)
    src = tmp_path / "base.yaml"
    src.write_text(yaml.safe_dump(base, sort_keys=False))
    planted = Planted(zero_errors=ZERO_ERRORS, ultrasonic_offset_m=ULTRA_OFFSET_M,
                      ultrasonic_scale=ULTRA_SCALE)
    cfg = load_trial_config(src)
    with EmulatedRig(cfg, planted=planted, warm_start_s=8.0, clock=VirtualClock()) as rig:
        yield rig, rig.retarget(cfg), base


def test_calibrate_recovers_planted_zero_offsets_and_ultrasonic(miscalibrated_rig, tmp_path):
    """Calibration against the driver as at the rig (packets, sync reads, the sensor's lines), on
    the virtual clock; the command line's own path is the sagging rig's test below."""
    from bench.lab.calibrate import calibrate

    rig, cfg, base = miscalibrated_rig
    clock = rig.clock
    servos = base["backend"]["servos"]
    ids = {j: s["id"] for j, s in servos.items()}

    # 1. Joint zeros as a config override: the servos are only read.
    res = calibrate(cfg, write="config", stops=0, out=tmp_path / "zeros.yaml")
    cal = yaml.safe_load((tmp_path / "zeros.yaml").read_text())
    assert cal["joint_offsets"] == "config" and not cal["homing_offsets"]
    for joint, s in servos.items():
        truth = s.get("offset", 0.0) + ZERO_ERRORS.get(joint, 0.0)
        one_tick = TICK * abs(s.get("ratio", 1.0))
        assert abs(cal["servos"][joint]["offset"] - truth) <= one_tick, joint
        assert cal["servos"][joint]["offset"] == pytest.approx(res.zeros[joint].offset)
    assert all(rig.bus.servo(i).torque_enabled for i in ids.values())
    assert all(rig.bus.servo(i).get("Homing Offset") == 0 for i in ids.values())

    # 2. Joint zeros into the Homing Offset registers, and the ultrasonic sensor over 4 stops.
    cal_file = tmp_path / "cal.yaml"
    calibrate(cfg, write="homing", stops=4, span=math.radians(60), samples=50, out=cal_file)
    cal = yaml.safe_load(cal_file.read_text())
    assert cal["joint_offsets"] == "homing" and not cal["servos"]
    for joint, s in servos.items():
        ratio = s.get("ratio", 1.0)
        written = rig.bus.servo(ids[joint]).get("Homing Offset") * TICK * ratio  # joint units
        assert abs(written - ZERO_ERRORS.get(joint, 0.0)) <= TICK * abs(ratio) + 1e-12, joint
    # the arm is held after driving, never dropped onto its stops
    assert all(s.torque_enabled for s in rig.bus.servos.values())
    clock.sleep(2.0)  # (the Homing Offset writes let each joint go for a moment; the servos hold it)
    held = rig.plant.joint_position()
    lower = rig.robot.chain.lower  # where a released arm falls to
    # held near the pose, and far from the stops a released arm falls to
    assert np.all(np.abs(held[1:7]) < math.radians(10)) and np.all(held[1:7] > lower[1:7] + math.radians(45))
    u = cal["ultrasonic"]
    standoff = base["backend"]["ultrasonic"]["standoff_mm"]
    true_offset_mm = ULTRA_SCALE * standoff + ULTRA_OFFSET_M * 1e3
    assert abs(u["offset_mm"] - true_offset_mm) < 1.0
    d2 = np.linspace(0.0, 380.0, 20)  # mm, the train's whole travel
    assert np.max(np.abs((u["offset_mm"] + u["scale"] * d2) - (true_offset_mm + ULTRA_SCALE * d2))) < 1.0
    assert len(u["stops"]) == 4 and u["residual_mm"] < 1.0

    # 3. A trial config naming the file reads the true joint values (registers + sensor fit).
    from bench.kinematics.arc_train import train_pose
    from bench.rig.backends import make_dynamixel_backend

    calibrated = cfg.model_copy(update={"calibration": str(cal_file)})
    calibrated = load_trial_config(_written(tmp_path / "calibrated.yaml", calibrated))
    ratio = np.array([servos[n].get("ratio", 1.0) for n in rig.robot.joint_names])
    p = rig.robot.params
    with make_dynamixel_backend(calibrated, get_robot(calibrated.robot)) as act:
        act.enable()  # the arm fell when the calibration let go of it: hold it where it is
        deadline = clock.now() + 10.0
        while True:  # (a wrong zero would never agree; a swinging arm agrees once it slows down)
            clock.sleep(0.3)
            st = act.read()
            truth = rig.plant.joint_position()
            joints_ok = np.all(np.abs(st.position[1:] - truth[1:]) <= 2 * TICK * np.abs(ratio[1:]))
            d2_err = abs(train_pose(st.position[0], p).d2 - train_pose(truth[0], p).d2)
            if (joints_ok and d2_err < 2e-3) or clock.now() > deadline:
                break
    assert joints_ok, (st.position - truth) / (TICK * np.abs(ratio))  # in ticks
    assert d2_err < 2e-3


def _written(path: Path, cfg) -> Path:
    """``cfg`` as a config file (a calibration file is loaded with its config, as a user's is)."""
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json", exclude_none=True), sort_keys=False))
    return path


def test_calibrate_on_a_sagging_rig_refuses_the_sag_as_a_zero_and_says_why(tmp_path):
    # the shipped config on its own emulated rig: no integral gain on theta5/theta6 at power-up,
    # so the arm sags under gravity where the technician was told it is at its reference
    config = tmp_path / "lab.yaml"
    config.write_text(LAB.read_text())
    out = hilbench("calibrate", str(config), "--emulate", "--clock", "virtual", "--yes", "--stops", "0", "--json",
                   "--out", str(tmp_path / "cal.yaml"))
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert set(res["refused"]) == {"theta5", "theta6"}
    assert "N·m of gravity at its reference" in res["refused"]["theta5"]
    cal = yaml.safe_load((tmp_path / "cal.yaml").read_text())
    assert "theta5" not in cal["servos"] and "theta6" not in cal["servos"]
    assert all(abs(v["change"]) <= math.radians(2.0) for v in cal["servos"].values())
    assert not list(tmp_path.glob("calibration/*"))  # --out given: nothing else written
    # the technician can insist
    out = hilbench("calibrate", str(config), "--emulate", "--clock", "virtual", "--yes", "--stops", "0", "--json",
                   "--accept-large-offsets", "--out", str(tmp_path / "all.yaml"))
    assert out.returncode == 0 and json.loads(out.stdout)["refused"] == {}
    assert {"theta5", "theta6"} <= set(yaml.safe_load((tmp_path / "all.yaml").read_text())["servos"])


def test_doctor_on_the_emulated_rig_prints_problems_then_one_count_line(tmp_path):
    config = tmp_path / "lab.yaml"
    config.write_text(LAB.read_text())  # its ports do not exist here: --emulate brings its own
    out = hilbench("doctor", str(config), "--emulate", "--clock", "virtual")
    assert out.returncode == 0, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("ready for a trial: 0 failed, 0 warning(s), "), lines
    verbose = hilbench("doctor", str(config), "--emulate", "--clock", "virtual", "--verbose")
    passed = [ln for ln in verbose.stderr.splitlines() if ln.startswith("PASS")]
    assert verbose.returncode == 0 and len(passed) == int(lines[0].split(", ")[-1].split()[0]) > 20


def test_trial_record_names_its_calibration(tmp_path):
    from bench.config.calibration import CalibrationFile, ServoCalibration, save_calibration
    from bench.core.log import TrialLog
    from bench.rig.backends import make_backend
    from bench.trial.plan import prepare
    from bench.trial.run import TrialHooks, run_trial

    cal = save_calibration(CalibrationFile(
        config_name="lab-target1", created="2026-01-01T00:00:00+00:00",
        servos={"theta5": ServoCalibration(offset=0.01, change=0.01)}), tmp_path / "cal.yaml")
    data = lab_data()
    data.update(calibration=str(cal), plan={"velocity_scale": 1.0, "settle_s": 0.3, "retract": False})
    (tmp_path / "lab.yaml").write_text(yaml.safe_dump(data))
    cfg = load_trial_config(tmp_path / "lab.yaml")
    sim = prepare(load_trial_config(REPO / "hil_configs" / "sim_target1_fast.yaml"))
    res = run_trial(prepare(cfg), tmp_path / "runs",
                    TrialHooks(backend=lambda prep: make_backend(sim.config, sim.robot), report=False))
    meta = TrialLog.load(res.log_path).metadata
    assert meta["calibration"]["path"] == str(cal)
    assert meta["calibration"]["content"]["servos"]["theta5"]["offset"] == 0.01
    assert meta["config"]["calibration"] == str(cal)


def test_calibration_files_that_cannot_apply_are_refused(tmp_path):
    data = lab_data()
    data["calibration"] = str(tmp_path / "missing.yaml")
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"a\.yaml: calibration: calibration file not found: .*missing"):
        load_trial_config(tmp_path / "a.yaml")
    (tmp_path / "cal.yaml").write_text("config_name: x\ncreated: now\nservos: {elbow: {offset: 0}}\n")
    data["calibration"] = str(tmp_path / "cal.yaml")
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"unknown joint\(s\) \['elbow'\]"):
        load_trial_config(tmp_path / "b.yaml")


def test_ultrasonic_fit_and_stops():
    from bench.lab.calibrate import fit_ultrasonic, stop_angles

    d2 = np.array([0.1, 0.17, 0.23, 0.3])
    fit = fit_ultrasonic(d2, 0.31 + 1.02 * d2 + np.array([1e-4, -1e-4, -1e-4, 1e-4]))
    assert fit.offset == pytest.approx(0.31, abs=2e-4) and fit.scale == pytest.approx(1.02, abs=2e-3)
    assert fit.rms == pytest.approx(1e-4, rel=0.5)
    stops = stop_angles(0.0, 2.0, 5)
    assert stops[0] > 0.0 and stops[-1] < 2.0 and np.allclose(np.diff(stops), np.diff(stops)[0])
    with pytest.raises(ValueError, match="at least 3"):
        stop_angles(0.0, 2.0, 2)


# ---------------------------------------------------------------------------
# jog: keys in through a pseudo-terminal, screen out, torque off after
# ---------------------------------------------------------------------------

ANSI = re.compile(r"\x1b\[[0-9;?]*[ -/]*[@-~]|\x1b[()][0-9A-Za-z]|\x1b[=>]")


class Screen:
    """What a pexpect child has written, without terminal escapes, searched as it arrives."""

    def __init__(self, child) -> None:
        self.child = child
        self.text = ""

    def wait_for(self, pattern: str, timeout: float = 30.0) -> re.Match:
        import pexpect

        end = time.monotonic() + timeout
        while True:
            m = re.search(pattern, ANSI.sub("", self.text))
            if m:
                self.text = ""
                return m
            if time.monotonic() > end:
                raise AssertionError(f"{pattern!r} not on screen: {ANSI.sub('', self.text)[-1500:]}")
            try:
                self.text += self.child.read_nonblocking(65536, timeout=0.2).decode(errors="replace")
            except pexpect.TIMEOUT:
                pass
            except pexpect.EOF:
                raise AssertionError(f"jog ended before {pattern!r}: "
                                     f"{ANSI.sub('', self.text)[-1500:]}") from None


@pytest.fixture
def jog_rig(tmp_path):
    cfg = load_trial_config(LAB)
    with emulated(cfg) as rig:
        yield rig, rig_config(tmp_path / "lab.yaml", rig, lab_data())


#: How long jog may take to show its screen: the start-up, and up to 10 s for the servos the rig
#: powered up holding at the factory gains to come back to their goals once the config's are written.
START_S = 60.0


def spawn_jog(path: Path, *extra: str):
    import pexpect

    child = pexpect.spawn(HILBENCH, ["jog", str(path), *extra], dimensions=(40, 120), timeout=60,
                          env={"TERM": "xterm-256color", "PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"})
    return child, Screen(child)


def quit_jog(child, screen: "Screen") -> None:
    """q, the closing line, the end of the process."""
    import pexpect

    child.send("q")
    screen.wait_for(r"jog ended \(q\): torque off")
    child.expect(pexpect.EOF, timeout=30)


def test_jog_moves_one_joint_and_leaves_torque_off(jog_rig):
    rig, path = jog_rig
    child, screen = spawn_jog(path)
    try:
        screen.wait_for(r"torque ON", timeout=START_S)
        assert all(s.torque_enabled for s in rig.bus.servos.values())
        child.send("7")  # theta8
        screen.wait_for(r"theta8 selected")
        child.send("s")  # step 1° -> 5°
        screen.wait_for(r"step 5°")
        child.send("+")
        child.send("\x1b[C")  # right arrow: one more step
        screen.wait_for(r"theta8 → \+10\.00°")
        screen.wait_for(r"7 │ theta8\s*│\s*\+(9\.9\d|10\.0\d)°")  # the servo got there
        with rig.bus.lock:
            theta8 = rig.plant.joint_position()[6]
        assert math.degrees(theta8) == pytest.approx(10.0, abs=0.3)
        child.send("8")
        child.send("-")  # d9 is at its home stroke (49 mm): one 5 mm step down is within limits
        screen.wait_for(r"d9 → \+(43\.9\d|44\.0\d) mm")
        quit_jog(child, screen)
    finally:
        child.close(force=True)
    assert child.exitstatus == 0
    assert not any(s.torque_enabled for s in rig.bus.servos.values())


def test_jog_on_its_own_emulated_rig(tmp_path):
    config = tmp_path / "lab.yaml"
    config.write_text(LAB.read_text())
    child, screen = spawn_jog(config, "--emulate")
    try:
        screen.wait_for(r"torque ON", timeout=START_S)
        child.send("7")
        screen.wait_for(r"theta8 selected")
        child.send("+")
        screen.wait_for(r"7 │ theta8\s*│\s*\+(0\.9\d|1\.0\d)°")  # one 1° step, reached
        quit_jog(child, screen)
    finally:
        child.close(force=True)
    assert child.exitstatus == 0


def test_jog_ctrl_c_leaves_torque_off(jog_rig):
    import pexpect

    rig, path = jog_rig
    child, screen = spawn_jog(path)
    try:
        screen.wait_for(r"torque ON", timeout=START_S)
        child.send("1")
        child.send("+")
        screen.wait_for(r"train → \+\d+\.\d\d°")  # one step up from where the sensor puts it
        child.send("\x03")  # raw mode: Ctrl-C arrives as a key
        screen.wait_for(r"jog ended \(Ctrl-C\): torque off")
        child.expect(pexpect.EOF, timeout=30)
    finally:
        child.close(force=True)
    assert child.exitstatus == 0
    assert not any(s.torque_enabled for s in rig.bus.servos.values())


def test_jog_whose_bus_dies_says_torque_off_not_confirmed(jog_rig):
    """The cable pulled while jogging: one line naming the servos that did not confirm, exit 3."""
    import pexpect

    rig, path = jog_rig
    child, screen = spawn_jog(path)
    try:
        screen.wait_for(r"torque ON", timeout=START_S)
        rig.bus.unplug()
        child.expect(pexpect.EOF, timeout=60)
    finally:
        child.close(force=True)
    text = ANSI.sub("", screen.text + (child.before or b"").decode(errors="replace"))
    assert "Traceback" not in text
    assert child.exitstatus == 3, text[-1500:]
    last = [x for x in text.splitlines() if x.strip()][-1]
    assert last.startswith("error: ") and "torque off NOT confirmed for servo ID(s)" in last, last


def test_jog_keys():
    from bench.lab.jog import JogState, parse_keys

    assert parse_keys(b"3\t+\x1b[A\x1b[Dsq\x03") == ["select:2", "next", "plus", "prev", "minus",
                                                     "step", "quit", "interrupt"]
    s = JogState(["a", "b"], [True, False], np.array([-0.1, 0.0]), np.array([0.1, 0.01]), np.zeros(2))
    for _ in range(20):
        s.handle("plus")
    assert s.target[0] == pytest.approx(0.1) and "upper limit" in s.message
    s.handle("next")
    s.handle("step")
    s.handle("plus")
    assert s.target[1] == pytest.approx(0.005) and s.handle("quit") is False


# ---------------------------------------------------------------------------
# bad input: one line, exit 2, nothing opened
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("args, words", [
    (["scan", "--port", "/dev/ttyNOPE0"], "servo port /dev/ttyNOPE0 not found"),
    (["scan", "--port", "/dev/ttyNOPE0", "--baud", "12345"], "--baud 12345 is not an X-series rate"),
    (["doctor", str(SIM)], "doctor needs backend.kind: dynamixel (this config is pybullet)"),
    (["calibrate", str(SIM), "--yes"], "calibrate needs backend.kind: dynamixel"),
    (["jog", str(SIM)], "jog needs backend.kind: dynamixel"),
    (["jog", str(LAB)], "jog reads keys from a terminal"),
    (["calibrate", str(LAB), "--yes"], "servo port /dev/ttyUSB0 not found"),
])
def test_bad_input_fails_with_one_line(args, words):
    from typer.testing import CliRunner

    from bench.cli.app import app

    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], res.stderr
    assert res.stdout == ""
