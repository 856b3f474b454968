"""The train's own encoder: the rig reads the train's arc position through its ultrasonic sensor, but
its servo reads its pinion too. That reading goes into the log per cycle (``q_encoder``, joint units),
survives the journal and the checking loader (a log without it loads as before), and ``hilbench
identify`` fits the train's physics on it: on an emulated rig with a heavy train gearbox of its own,
the train's friction comes out within 15 % and its motor constant within 3 % (fitted on the
sensor's reading instead, the same log gave a motor 6 % weak and ran the peak's fade to the edge
of its range, where the model file takes the peers' friction)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.core.log import ENCODER_SERIES, TrialLog
from bench.core.rundir import RunDirError, load_run, read_journal, read_log_file
from bench.core.runner import Runner, Segment
from drivers import ActuatorsBase, JointLimits, JointState
from drivers.capabilities import SensedEncoder, find_capability

REPO = Path(__file__).resolve().parents[1]
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _encoder_log(rows: int = 5) -> TrialLog:
    log = TrialLog(["train", "theta3"], ["approach"], metadata={"control_period": 0.01})
    log.start_encoder("train")
    for k in range(rows):
        log.append(k * 0.01, 0, [0, 0], [0, 0], [0.001 * k, 0], [0, 0], [0, 0])
        log.encode(0.0011 * k)
    return log


def test_the_encoder_channel_survives_the_log_the_journal_and_the_checking_loader(tmp_path):
    log = TrialLog(["train", "theta3"], ["approach"])
    log.journal_to(tmp_path)
    log.start_encoder("train")  # the journal's reader learns the row width before any row
    assert json.loads((tmp_path / "trial.journal.json").read_text())["encoder_joint"] == "train"
    for k in range(5000):  # past the first capacity: the channel grows with the rows
        log.append(k * 0.01, 0, [0, 0], [0, 0], [k, k], [0, 0], [0, 0])
        log.encode(0.5 * k)
    log.append(50.0, 0, [0, 0], [0, 0], [0, 0], [0, 0], [0, 0])  # a row not read from the servo
    log.flush()
    want = np.append(0.5 * np.arange(5000), np.nan)
    np.testing.assert_array_equal(read_journal(tmp_path).q_encoder, want)
    path = log.save(tmp_path / "trial.npz")
    for back in (TrialLog.load(path), read_log_file(path)):
        assert back.encoder_joint == "train"
        np.testing.assert_array_equal(back.q_encoder, want)
    with pytest.raises(ValueError, match="no joint 'd2'"):
        TrialLog(["train"]).start_encoder("d2")


def _rewrite(path: Path, drop: tuple[str, ...] = (), **arrays) -> None:
    with np.load(path) as z:
        kept = {k: z[k] for k in z.files if k not in drop} | arrays
    np.savez(path, **kept)


def test_a_log_without_the_channel_loads_and_a_bad_one_is_refused(tmp_path):
    plain = TrialLog(["train"], ["approach"])
    plain.append(0.0, 0, [0], [0], [0], [0], [0])
    back = read_log_file(plain.save(tmp_path / "old.npz"))
    assert back.q_encoder is None and back.encoder_joint is None
    path = _encoder_log().save(tmp_path / "trial.npz")
    bad = np.array([0, 0, np.inf, 0, 0], dtype=float)
    _rewrite(path, q_encoder=bad)
    with pytest.raises(RunDirError, match=r"q_encoder holds inf at row 2"):
        read_log_file(path)
    _rewrite(path, q_encoder=np.zeros(4))
    with pytest.raises(RunDirError, match=r"not a float per row \(5 rows\)"):
        read_log_file(path)
    _rewrite(path, drop=(ENCODER_SERIES,))
    with pytest.raises(RunDirError, match="encoder_joint 'train' without q_encoder"):
        read_log_file(path)
    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
    meta["encoder_joint"] = "d2"
    _rewrite(path, q_encoder=np.zeros(5), meta=np.array(json.dumps(meta)))
    with pytest.raises(RunDirError, match="encoder_joint 'd2' is not one of its joints"):
        read_log_file(path)


class _SensedTrain(ActuatorsBase):
    """A rig whose train reads 1 mm off its encoder (its sensor's view of it)."""

    joint_names = ["train", "theta3"]
    limits = JointLimits(-np.ones(2), np.ones(2), np.ones(2), np.ones(2))
    encoder_joint = "train"

    def __init__(self) -> None:
        self._t0, self._q = time.monotonic(), np.zeros(2)

    def now(self) -> float:
        return time.monotonic() - self._t0

    def wait_until(self, t: float) -> None:
        time.sleep(max(0.0, t - self.now()))

    def read(self) -> JointState:
        return JointState(self.now(), self._q + [0.001, 0.0], np.zeros(2), np.zeros(2))

    def encoder_position(self) -> float:
        return float(self._q[0])

    def _command(self, position, velocity) -> None:
        self._q = np.array(position, dtype=float)

    def _enable(self) -> None: ...

    def _disable(self) -> None: ...

    def _close(self) -> None: ...


class _Ramp:
    dof, duration = 2, 0.2

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        q = np.stack([0.1 * t, np.zeros_like(t)], axis=-1)
        return q, np.zeros_like(q), np.zeros_like(q)


def test_the_runner_records_the_encoder_of_the_joint_read_through_another_sensor():
    act = _SensedTrain()
    assert find_capability(act, SensedEncoder) is act
    log = TrialLog(list(act.joint_names))
    Runner(act, 0.01).run([Segment("approach", _Ramp())], log)
    assert log.encoder_joint == "train" and len(log.q_encoder) == len(log) > 10
    # each row holds the encoder as of that row's read: the sensor's reading less its 1 mm
    np.testing.assert_allclose(log.q_encoder, log.q[:, 0] - 0.001, atol=1e-12)
    assert np.ptp(log.q_encoder) > 0.01


#: A train whose gearbox is heavier than the rest, with a friction at rest above its Coulomb level.
HIDDEN_T = {"all": {"coulomb_nm": 0.05},
            "train": {"coulomb_nm": 0.25, "stribeck_nm": 0.32, "stribeck_velocity_rads": 0.2, "viscous_nms": 0.03}}
#: The friction excitation on the train alone, each piece cut down.
TRAIN_ONLY = {"joints": ["train"], "chirp_s": 1.5, "multisine_s": 1.5, "multisine_period_s": 0.75,
              "pause_s": 0.2, "sweep_speeds": 3, "sweep_s": 0.5, "reversal_s": 1.0, "hold_s": 0.3}


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=600)


def test_identify_fits_the_trains_friction_on_its_encoder(tmp_path):
    data = yaml.safe_load((REPO / "hil_configs" / "identify.yaml").read_text())
    data["name"] = "train_encoder"
    data["emulator"]["servo_physics"] = HIDDEN_T
    data["emulator"]["clock"] = "virtual"  # the same log on any machine
    data["excitation"].update(TRAIN_ONLY)
    cfg = tmp_path / "train.yaml"
    cfg.write_text(yaml.safe_dump(data))

    res = _run("trial", str(cfg), "--emulate", "--json", "--out", str(tmp_path / "runs"))
    assert res.returncode == 0, res.stderr
    run = json.loads(res.stdout)
    assert run["passed"] and run["completed"], run
    log = load_run(Path(run["run_dir"])).log
    assert log.encoder_joint == "train" and np.all(np.isfinite(log.q_encoder))
    # the encoder is the servo's pinion in steps of a tick, where the sensor's reading moves in
    # whole millimetres of arc (6 mrad) with a millimetre of noise; the two agree within one of those
    sensed = log.q[:, log.joint("train")]
    step = lambda x: np.median(np.abs(np.diff(x))[np.diff(x) != 0])  # noqa: E731
    assert step(log.q_encoder) < 0.2 * step(sensed)
    assert 0 < np.median(np.abs(log.q_encoder - sensed)) < step(sensed)
    _the_true_physics_draws_the_logged_current_at_speed(Path(run["run_dir"]))
    from bench.identify.run import identify

    result = identify([Path(run["run_dir"])], tmp_path / "m.yaml", workers=2, report=False)
    assert all(r.train_on_encoder for r in result.runs)
    fitted = result.fit.joints["train"].values
    # the friction the train's servo showed at the speeds its sweeps ran (rad/s at the servo's
    # shaft), Coulomb level, peak and viscous part together: its split between them is not what
    # a short excitation tells (the fit says so; where its peak's fade runs to the edge of its
    # range, the model file takes the peers' friction instead), the torque it takes to move is
    for v in (0.1, 0.3, 1.0):
        got, want = _friction(fitted, v), _friction({**HIDDEN_T["all"], **HIDDEN_T["train"]}, v)
        assert got == pytest.approx(want, rel=0.15), (v, got, want, fitted)
    assert fitted["kt_scale"] == pytest.approx(1.0, abs=0.03), fitted  # the train's motor is as its datasheet


def _the_true_physics_draws_the_logged_current_at_speed(run_dir: Path) -> None:
    """Identification's simulator, given the rig's hidden physics and the loop's latency from the
    log's timing, draws the train's logged current during its fast sweeps: no friction is left
    for a fit to invent (a Coulomb level 20 % high draws 0.03 A more; without the latency it draws about
    0.01 A less, in the direction of motion)."""
    from bench.identify.logs import load_runs
    from bench.identify.simulate import PHYSICS, SlotPhysics, simulate_run

    setup, runs = load_runs([run_dir])
    run, k = runs[0], setup.joint_names.index("train")
    assert np.all(run.applied - run.sampled >= 0.001)  # the goal lands a firmware sample or more later
    truth = {"kt_scale": 1.0, "armature_kgm2": 0.012, **HIDDEN_T["train"]}
    physics = SlotPhysics(joint=np.array([k]), values=np.array([[truth[p] for p in PHYSICS]]))
    _, current, _ = simulate_run(setup, run, physics)
    w = run.qd[:, k] / setup.ratio[k]
    fast = np.abs(w) > 1.0
    assert fast.sum() > 50

    def bias(current: np.ndarray) -> float:
        return float(np.mean(np.sign(w[fast]) * (run.current[fast, k] - current[fast, 0])))

    # the reading is the servo's state at some instant of its read: the loop's timing places it at
    # the read's start (a servo answers at once); an emulator held up by a loaded machine answers
    # with its state later in the read (a CI run beside another emulated rig: 0.6-1.7 ms reads,
    # 0.011 A off at the start and 0.004 at the end; 0.3-0.5 ms and 0.002-0.006 quiet)
    at_end = simulate_run(setup, dataclasses.replace(run, sampled=run.time), physics)[1]
    low, high = sorted((bias(current), bias(at_end)))
    assert low - 0.01 < 0 < high + 0.01, (low, high)


def _friction(p: dict, v: float) -> float:
    """Coulomb with a Stribeck peak plus viscous friction (N·m) at speed ``v`` (as drivers/servo/model.py)."""
    fade = np.exp(-(v / p["stribeck_velocity_rads"]) ** 2)
    return p["coulomb_nm"] + (p["stribeck_nm"] - p["coulomb_nm"]) * fade + p["viscous_nms"] * v


def test_the_live_view_reads_a_journal_with_the_encoder_channel(timed_journal):
    """The encoder's column follows the loop's timing in each journal row: the live view's row width
    counts it, so positions and missed deadlines read as before."""
    follower, log = timed_journal
    log.start_encoder(log.joint_names[0])
    q = np.full(len(log.joint_names), 0.25)
    for k in range(50):
        log.append(k * 0.01, 0, q, q * 0, q, q * 0, q * 0)
        log.time_cycle(k * 0.01, 0.002 if k == 7 else -0.0005, 0.0004)
        log.encode(0.125)
    log.flush()
    snap = follower.poll()
    assert (snap.timing["cycles"], snap.timing["missed"]) == (50, 1)
    assert np.allclose(snap.q, 0.25)
