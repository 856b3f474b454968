"""A worn rig identified from the friction excitation: heavy gearbox friction (a quarter of a
newton-metre and more), on θ4 a friction at rest below its Coulomb level, on θ5 one well above it
with a weaker motor, Kt down a tenth everywhere. The excitation's sweeps, reversals and holds
(on the train and those three joints), ``hilbench identify`` and ``hilbench compare --sim-model``
on Target 1, as a user would; the fitted values are held to the hidden ones, and the identified
sim to the rig. The rig runs on the virtual clock: its logs, and every figure here, are the same on
any machine, however loaded."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
HILBENCH = str(Path(sys.executable).with_name("hilbench"))

#: The worn rig's hidden physics (set W): every joint's gearbox heavy, θ4's friction at rest
#: below Coulomb (0.24 against 0.32 N·m), θ5's above it and its motor weaker still.
HIDDEN_W = {"all": {"coulomb_nm": 0.22, "stribeck_nm": 0.3, "stribeck_velocity_rads": 0.25,
                    "viscous_nms": 0.04, "kt_scale": 0.9},
            "theta4": {"coulomb_nm": 0.32, "stribeck_nm": 0.24},
            "theta5": {"stribeck_nm": 0.38, "kt_scale": 0.85}}
#: The joints excited: the three whose friction differs, and the train (the host loop steering it on
#: its sensor places it by its own friction and viscous slope, through its pinion at 20 times the
#: arc's speed: its peers' values, fitted to slower joints, left it a sixth of a degree off).
EXCITED = ["train", "theta4", "theta5", "theta6"]
FRICTION = ("coulomb_nm", "stribeck_nm", "stribeck_velocity_rads", "viscous_nms")
#: A short friction excitation: the pieces of the lab plan, each cut down.
SHORT = {"joints": EXCITED, "amplitude_deg": 6.0, "chirp_s": 1.5, "multisine_s": 1.5,
         "multisine_period_s": 0.75, "pause_s": 0.2, "sweep_speeds": 3, "sweep_s": 0.5, "reversal_s": 1.0,
         "hold_s": 0.3}


DATASHEET = {"kt_scale": 1.0, "armature_kgm2": 0.012, "viscous_nms": 0.0, "coulomb_nm": 0.0,
             "stribeck_nm": 0.0, "stribeck_velocity_rads": 0.1}


def hidden(joint: str, key: str) -> float:
    return {**DATASHEET, **HIDDEN_W["all"], **HIDDEN_W.get(joint, {})}[key]


def _config(tmp: Path, base: str, **changes) -> Path:
    data = yaml.safe_load((REPO / "hil_configs" / f"{base}.yaml").read_text())
    data["emulator"]["servo_physics"] = HIDDEN_W
    data["emulator"]["clock"] = "virtual"  # the same logs on any machine
    for key, value in changes.items():
        data[key].update(value) if isinstance(value, dict) else data.__setitem__(key, value)
    path = tmp / f"{base}_worn.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def worn(tmp_path_factory):
    """The worn rig excited, identified and compared on Target 1 (one fixture for every assert)."""
    tmp = tmp_path_factory.mktemp("worn")
    res = _run("trial", str(_config(tmp, "identify", name="worn", excitation=SHORT)), "--emulate", "--json",
               "--out", str(tmp / "runs"))
    assert res.returncode == 0, res.stderr
    run = json.loads(res.stdout)
    assert run["passed"] and run["completed"], run
    model = tmp / "worn_model.yaml"
    res = _run("identify", run["run_dir"], "--out", str(model), "--json")
    assert res.returncode == 0, res.stderr
    fit = json.loads(res.stdout)

    res = _run("compare", str(_config(tmp, "lab_real")), "--emulate", "--repeats", "2", "--sim-model",
               str(model), "--json", "--out", str(tmp / "cmp"))
    assert res.returncode in (0, 1), res.stderr
    return {"fit": fit, "model": model, "compare": json.loads(res.stdout)}


def _predicts(compared: dict) -> None:
    pred = compared["prediction"]
    print(pred)
    assert len(pred["tip_error_mm"]["per_repeat"]) == 2
    assert pred["tracking_gap_ratio"] <= 0.2, pred
    ideal = float(np.linalg.norm(compared["tip_deviation_mm"]["mean"]))
    assert ideal > 1.0  # the worn rig sags millimetres where the ideal motors do not
    assert pred["tip_error_mm"]["mean"] <= min(0.5, ideal / 5), (pred, ideal)


def test_the_worn_rigs_friction_is_recovered_or_said_not_observable(worn):
    """Each friction value of each moved joint lies within 15 % of the hidden one, or is reported
    not observable (the report says why); a motor constant told, within 5 %, the weak θ5's among them."""
    from bench.config.servo_model import load_servo_model_file

    model = load_servo_model_file(worn["model"])
    wrong, told = [], []
    for joint in EXCITED:
        values = model.joints[joint].model_dump(exclude_none=True)
        hidden_out = set(model.unobservable.get(joint, []))
        for key in FRICTION + ("kt_scale",):
            if key in hidden_out:
                continue
            told.append(f"{joint}.{key}")
            truth = hidden(joint, key)
            if abs(values[key] - truth) > (0.05 if key == "kt_scale" else 0.15) * truth:
                wrong.append(f"{joint}.{key}: {values[key]:.4g} vs hidden {truth:.4g}")
    assert not wrong, wrong
    assert "theta5.kt_scale" in told, told
    html = Path(worn["fit"]["report"]).read_text()
    if len(told) < len(EXCITED) * (len(FRICTION) + 1):
        assert "not observable" in html


def test_the_identified_sim_predicts_the_worn_rig_on_target_1(worn):
    """The identified sim predicts the worn rig: a tracking gap at most a fifth of the ideal sim's,
    and the needle tip (mean over the repeats) within a tenth of the 5 mm acceptance limit of the
    rig's and five times closer than the ideal sim's, which lies millimetres away. Only three
    joints are excited here (the others take their peers' median).

    The tip is held to 0.5 mm, not to the 0.2 mm it usually comes to: most of it is the train,
    placed by its host loop on an ultrasonic reading of whole millimetres with a millimetre of
    noise, and the rig does not repeat its own train to better than a quarter of a millimetre of
    arc. Per repeat, 0.05 to 0.30 mm over twelve repeats in real time (quiet and beside two CPU hogs),
    0.28 and 0.42 on a CI run: a mean of two such is not a figure to hold at 0.3."""
    _predicts(worn["compare"])


def test_the_identified_model_watches_the_worn_rig_without_an_alarm(worn, tmp_path):
    """The model file carries the spread its twin leaves on the excitation (σ per joint, at least the
    datasheet's encoder tick); the worn rig's Target 1 trial, watched by it, raises no alarm.

    σ is what the fit left, and a fit that said a value not observable (its peers' taken) leaves
    more: it is held to what the monitor is for, not to a fixed count of ticks. A joint the
    excitation never moved borrows its peers' largest σ with their physics: the needle's slide at
    its floor of two ticks (0.03 mm) once alarmed at 12-13 σ while inserting, the borrowed model's
    viscous term a little off. An offset of 2.5 σ held 0.25 s at 100 Hz raises the CUSUM (κ = 2 σ)
    by 12 σ, its threshold: so σ must keep that offset at least five times under the tracking
    interlock's 20°."""
    from bench.config.models import SafetyConfig
    from bench.config.servo_model import load_servo_model_file

    model = load_servo_model_file(worn["model"])
    tick = 2 * np.pi / 4096
    interlock = np.radians(SafetyConfig().tracking_error_deg)
    assert "train" not in model.twin_sigma and {"theta4", "theta5", "theta6"} <= set(model.twin_sigma)
    through = {"d9": 0.01, "d10": 0.01}  # the slides' 10 mm pinions; the arc's joints on their shafts
    ticks = {j: round(s / (tick * through.get(j, 1.0)), 2) for j, s in model.twin_sigma.items()}
    print("twin sigma (ticks):", ticks)
    assert all(tick * 0.999 <= model.twin_sigma[j] and 2.5 * model.twin_sigma[j] <= interlock / 5
               for j in ("theta4", "theta5", "theta6")), ticks
    # d10, the needle's slide, never moves in the excitation: its model is its peers', and so is its σ
    # (the largest they left, in ticks through its 10 mm pinion), not the tick it sat still within
    peers = max(v for j, v in ticks.items() if j != "d10")
    assert ticks["d10"] == pytest.approx(peers, abs=0.02), ticks
    # the current's σ beside it (A): never under the datasheet's 20 mA, the slide's its peers' too
    amps = model.twin_sigma_current
    print("twin current sigma (mA):", {j: round(1e3 * a, 1) for j, a in amps.items()})
    assert set(amps) == set(model.twin_sigma) and min(amps.values()) >= 0.02 * 0.999, amps
    assert amps["d10"] == pytest.approx(max(a for j, a in amps.items() if j != "d10")), amps

    res = _run("trial", str(_config(tmp_path, "lab_real")), "--emulate", "--monitor", str(worn["model"]),
               "--json", "--out", str(tmp_path / "runs"))
    assert res.returncode in (0, 1), res.stderr
    out = json.loads(res.stdout)
    assert out["loop_timing"]["clock"] == "virtual"
    assert out["monitor"]["alarms"] == [], (out["monitor"]["alarms"], out["loop_timing"])
