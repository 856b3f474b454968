"""The emulated lab rig and the servo-model sim move alike: Target 1 on datasheet physics, the same
plan, every joint within 0.5° (the train's arc angle and the revolute joints) or 0.5 mm (the racks
d9 and d10) of the other over the whole trial.

One rig trial on the virtual clock, as ``hilbench trial --emulate --clock virtual`` runs it: the
same on any machine. The sim then replays the rig's schedule: each cycle reads at the instant the
rig read and sends the rig's command when the rig's went out. A stall longer than 20 ms (which only
a real-time rig on a held-up machine has) would leave the 0.3 s after it out of the comparison; the
start, where a servo taking up its load kicked the wrist 9° off its command, is held on the rig's
own tracking as well.

The train's position is compared through its pinion encoder against the sim's true arc angle (its
ultrasonic reading is the sensor's, 1 mm noise); every other joint by what the driver read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.compare.homing import starting_at
from bench.compare.session import EMULATED_RETRIES, sim_counterpart
from bench.config.models import TrialConfig, load_trial_config
from bench.core.log import TrialLog
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend
from bench.rig.emulated import VirtualRig
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
TOLERANCE_RAD = np.radians(0.5)
TOLERANCE_M = 0.5e-3
STALL_S = 0.02  # a cycle this late may have starved the emulator's physics as well
RECOVERY_S = 0.3  # how long the servos take to forget it (their position loop's response)


def _rig_trial(cfg: TrialConfig, out: Path) -> tuple[TrialLog, dict]:
    cfg = cfg.model_copy(update={"backend": cfg.backend.model_copy(update={"retries": EMULATED_RETRIES})})
    with VirtualRig(cfg) as rig:
        res = run_trial(prepare(cfg).with_config(rig.retarget(cfg)), out, TrialHooks(report=False))
    assert res.completed, res.reason
    return TrialLog.load(res.log_path), rig.stats


def _servo_sim(cfg: TrialConfig, rig: TrialLog):
    """The servo-model sim of the rig's config (its servo table, gains and sensor, the emulator's
    sensor noise), started where the rig's plan started, its train where its encoder read."""
    sim = sim_counterpart(cfg, servo_model="datasheet")
    u = sim.backend.ultrasonic.model_copy(update={"noise_mm": cfg.emulator.ultrasonic_noise_mm})
    sim = sim.model_copy(update={"backend": sim.backend.model_copy(update={"ultrasonic": u})})
    start = dict(zip(rig.joint_names, map(float, rig.q[0])))
    start[rig.encoder_joint] = float(rig.q_encoder[0])
    sim = starting_at(sim, start)
    return make_backend(sim, get_robot(sim.robot))


def _replay(act, rig: TrialLog, period: float) -> tuple[np.ndarray, np.ndarray]:
    """The sim's readings and true positions at the rig's read instants, each cycle's command sent
    when the rig's went out (its deadline plus how late it ended)."""
    origin = rig.loop_start[0]
    read_at = rig.time - origin
    sent_at = np.maximum((np.arange(len(rig)) + 1) * period + np.nan_to_num(rig.loop_late), read_at)
    read, truth = [], []
    act.enable()
    t0 = act.now()
    try:
        for k in range(len(rig)):
            act.wait_until(t0 + read_at[k])
            read.append(act.read().position)
            truth.append(act.true_position())
            act.wait_until(t0 + sent_at[k])
            act.command(rig.q_cmd[k], rig.qd_cmd[k])
    finally:
        act.close()
    return np.array(read), np.array(truth)


def _compared_rows(rig: TrialLog) -> np.ndarray:
    t = rig.time - rig.loop_start[0]
    keep = np.ones(len(rig), bool)
    for k in np.flatnonzero(np.nan_to_num(rig.loop_late) > STALL_S):
        keep &= ~((t >= t[k] - STALL_S) & (t <= t[k] + RECOVERY_S))
    return keep


@pytest.mark.timeout(240)
def test_emulated_rig_and_servo_sim_agree_within_half_a_degree(tmp_path):
    cfg = load_trial_config(LAB)
    rig, stats = _rig_trial(cfg, tmp_path / "rig")
    assert stats["physics_skipped_s"] == 0.0 and rig.metadata["loop_clock"] == "virtual"
    names = rig.joint_names
    assert rig.encoder_joint == "train" and len(rig) > 800  # the whole of Target 1: 8.4 s at 100 Hz

    # the start: no joint kicked off its command as its servo took up its load (theta5 strayed 9.1°)
    start = (rig.time - rig.time[0]) < 0.5
    strayed = np.abs(rig.q[start] - rig.q_cmd[start]).max(axis=0)
    wrist = [names.index(n) for n in ("theta4", "theta5", "theta6")]
    assert np.all(strayed[wrist] < np.radians(1.0)), dict(zip(names, np.degrees(strayed).round(2)))

    read, truth = _replay(_servo_sim(cfg, rig), rig, cfg.control_period)
    rig_q = rig.q.copy()
    sensed = names.index(rig.encoder_joint)
    rig_q[:, sensed], read[:, sensed] = rig.q_encoder, truth[:, sensed]
    keep = _compared_rows(rig)
    assert keep.mean() > 0.5, f"only {keep.mean():.0%} of the cycles kept time well enough to compare"
    assert keep[start].mean() > 0.5, "the start itself was lost to stalls"
    gap = np.abs(rig_q[keep] - read[keep]).max(axis=0)
    prismatic = np.array([n.startswith("d") for n in names])
    tolerance = np.where(prismatic, TOLERANCE_M, TOLERANCE_RAD)
    shown = {n: f"{g * 1e3:.3f} mm" if p else f"{np.degrees(g):.3f}°"
             for n, g, p in zip(names, gap, prismatic)}
    assert np.all(gap <= tolerance), shown
