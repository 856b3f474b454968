"""Servo identification end to end: an emulated rig with hidden servo physics runs the excitation,
``hilbench identify`` fits its logs, and the fitted model recovers the hidden physics and predicts
the rig on a motion the fit never saw (Target 1). The rigs run on the virtual clock: their logs, and
so every figure here, are the same on any machine, however loaded."""

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

#: Two rigs whose servos differ from the datasheet: friction with a Stribeck peak everywhere, a
#: weak motor and a heavy rotor on theta4 (set A); a weaker theta5 motor, less friction and a
#: retuned theta5 (set B: another servo table, so its logs do not mix with A's).
HIDDEN_A = {"all": {"coulomb_nm": 0.08, "viscous_nms": 0.05, "stribeck_nm": 0.14, "stribeck_velocity_rads": 0.3},
            "theta4": {"armature_kgm2": 0.02, "kt_scale": 0.85, "coulomb_nm": 0.12}}
HIDDEN_B = {"all": {"coulomb_nm": 0.04, "stribeck_nm": 0.1, "stribeck_velocity_rads": 0.2},
            "theta5": {"kt_scale": 0.7}}
DATASHEET = {"kt_scale": 1.0, "armature_kgm2": 0.012, "viscous_nms": 0.0, "coulomb_nm": 0.0, "stribeck_nm": 0.0,
             "stribeck_velocity_rads": 0.1}
#: Below these a value counts as recovered whatever its relative error (values near zero).
FLOOR = {"kt_scale": 0.02, "armature_kgm2": 0.001, "viscous_nms": 0.01, "coulomb_nm": 0.01, "stribeck_nm": 0.01,
         "stribeck_velocity_rads": 0.05}


def hidden_value(hidden: dict, joint: str, key: str) -> float:
    values = {**DATASHEET, **hidden.get("all", {}), **hidden.get(joint, {})}
    if key == "stribeck_nm" and values["stribeck_nm"] == 0:  # no peak set: the friction at rest is Coulomb
        return values["coulomb_nm"]
    return values[key]


def _config(tmp: Path, name: str, hidden: dict, excitation: dict, **servo_changes) -> Path:
    data = yaml.safe_load((REPO / "hil_configs" / "identify.yaml").read_text())
    data["name"] = name
    data["excitation"].update(excitation)
    data["emulator"]["servo_physics"] = hidden
    data["emulator"]["clock"] = "virtual"  # the same logs on any machine
    for joint, changes in servo_changes.items():
        data["backend"]["servos"][joint].update(changes)
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _run(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    """Excitation runs on two emulated rigs on the virtual clock (side by side), every joint briefly."""
    tmp = tmp_path_factory.mktemp("identify")
    short = {"chirp_s": 2.0, "multisine_s": 2.0, "multisine_period_s": 1.0, "updown_s": 1.0, "pause_s": 0.2,
             "sweep_speeds": 0}  # the earlier plan: chirp, multi-sine and up-and-down (no friction sweeps)
    cfg_a = _config(tmp, "rig_a", HIDDEN_A, short)
    cfg_b = _config(tmp, "rig_b", HIDDEN_B, short, theta5={"position_i": 400})

    def start(c: Path) -> subprocess.Popen:
        return subprocess.Popen([HILBENCH, "trial", str(c), "--emulate", "--json", "--out", str(tmp / "runs")],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    runs = []
    for p in [start(c) for c in (cfg_a, cfg_b)]:
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        res = json.loads(out)
        assert res["passed"] and res["completed"]
        assert res["loop_timing"]["clock"] == "virtual"
        runs.append(Path(res["run_dir"]))
    return {"tmp": tmp, "a": runs[0], "b": runs[1]}


HIDDEN = {"a": HIDDEN_A, "b": HIDDEN_B}


@pytest.fixture(scope="module")
def models(rigs):
    """Both rigs identified (side by side): {set: (the --json line, the model file)}."""
    outs = {k: rigs["tmp"] / f"model_{k}.yaml" for k in HIDDEN}
    procs = {k: subprocess.Popen([HILBENCH, "identify", str(rigs[k]), "--out", str(outs[k]), "--json"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in HIDDEN}
    found = {}
    for k, p in procs.items():
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        assert len(out.strip().splitlines()) == 1
        found[k] = (json.loads(out), outs[k])
    return found


@pytest.fixture(scope="module")
def identified(models):
    return models["a"]


def test_identify_fits_every_moved_joint_and_its_error_falls(identified):
    d, _ = identified
    assert set(d) >= {"model", "joints", "mae_before", "mae_after", "report"}
    assert set(d["joints"]) >= {"theta3", "theta4", "theta5", "theta7", "d9"}
    for name, j in d["joints"].items():
        assert j["mae_after"] < j["mae_before"], name
    assert d["mae_after"] < 0.6 * d["mae_before"]


@pytest.mark.parametrize("which", ["a", "b"])
def test_identify_recovers_the_hidden_physics_where_the_logs_tell_it(models, which):
    """Every value the fit calls observable is within 15 % of the hidden one (or of its floor
    near zero); the weak motor (θ4 Kt × 0.85 in A, θ5 × 0.7 in B) and the friction at rest are among them."""
    from bench.config.servo_model import load_servo_model_file

    d, path = models[which]
    hidden = HIDDEN[which]
    model = load_servo_model_file(path)
    assert model.robot == "arc-train" and len(model.sources) == 1
    wrong, told = [], 0
    for joint, physics in model.joints.items():
        hidden_out = set(model.unobservable.get(joint, []))
        for key, value in physics.model_dump(exclude_none=True).items():
            if key in hidden_out:
                continue
            told += 1
            truth = hidden_value(hidden, joint, key)
            if abs(value - truth) > max(0.15 * abs(truth), FLOOR[key]):
                wrong.append(f"{joint}.{key}: {value:.4g} vs hidden {truth:.4g}")
    assert not wrong, wrong
    weak, kt = ("theta4", 0.85) if which == "a" else ("theta5", 0.7)
    assert "kt_scale" not in model.unobservable.get(weak, [])
    assert model.joints[weak].kt_scale == pytest.approx(kt, rel=0.05)
    assert told >= 8
    # the needle slide never moves around the entry pose: it takes its fitted peers' median
    fitted = [j for j in model.joints if j not in ("d10",)]
    assert "d10" in d["skipped"] and set(model.unobservable["d10"]) == set(DATASHEET)
    assert model.joints["d10"].stribeck_nm == pytest.approx(
        float(np.median([model.joints[j].stribeck_nm for j in fitted])))
    # the report says which values the logs could not tell, joint by joint
    html = Path(d["report"]).read_text()
    assert "not observable" in html and html.count("<img") == len(d["joints"])


def test_identify_refuses_logs_of_two_rigs_or_of_the_simulator(rigs, tmp_path):
    res = _run("identify", str(rigs["a"]), str(rigs["b"]), "--out", str(tmp_path / "m.yaml"))
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "theta5" in lines[0] and "not the same rig" in lines[0]
    assert not (tmp_path / "m.yaml").exists()
    sim = _run("trial", str(REPO / "hil_configs" / "sim_target1_fast.yaml"), "--json", "--out", str(tmp_path))
    assert sim.returncode == 0, sim.stderr
    res = _run("identify", json.loads(sim.stdout)["run_dir"], "--out", str(tmp_path / "m.yaml"))
    assert res.returncode == 2 and "pybullet trial" in res.stderr
    res = _run("identify", str(rigs["a"]), "--out", str(tmp_path / "m.txt"))
    assert res.returncode == 2 and ".yaml" in res.stderr


@pytest.mark.parametrize("which", ["a", "b"])
def test_the_identified_sim_predicts_the_rig_on_a_motion_it_never_saw(rigs, models, which):
    """compare on Target 1 (the fit saw only the excitation): the identified sim tracks the rig far
    closer than PyBullet's ideal motors do, and places the needle closer to where the rig does."""
    _, model = models[which]
    data = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())
    data["emulator"]["servo_physics"] = HIDDEN[which]
    data["emulator"]["clock"] = "virtual"
    if which == "b":
        data["backend"]["servos"]["theta5"]["position_i"] = 400
    cfg = rigs["tmp"] / f"lab_{which}.yaml"
    cfg.write_text(yaml.safe_dump(data))

    res = _run("compare", str(cfg), "--emulate", "--repeats", "2", "--sim-model", str(model), "--json",
               "--out", str(rigs["tmp"] / f"cmp_{which}"))
    assert res.returncode in (0, 1), res.stderr
    d = json.loads(res.stdout)
    pred = d["prediction"]
    print(pred)
    assert pred["tracking_gap_ratio"] <= 0.2, pred  # 80 % of the ideal sim's gap closed
    # the ideal sim misses the rig's sag: its tip is millimetres off the rig's; the identified
    # sim's lies within a tenth of the 5 mm acceptance limit of it
    ideal_tip = np.asarray(d["tip_deviation_mm"]["mean"])
    assert float(np.linalg.norm(ideal_tip)) > 1.0
    # mean over the repeats; most of it is the train, placed by its host loop on an ultrasonic
    # reading of whole millimetres with a millimetre of noise, which the rig does not repeat to
    # better than a quarter of a millimetre of arc (the worn rig's test: 0.05 to 0.42 mm a repeat).
    # Set B's train (P gain only) is fitted from the short chirp the excitation gives it; from one
    # log its placement came within 0.1 mm, from another 0.2° of arc (0.45 mm of tip) off.
    assert pred["tip_error_mm"]["mean"] <= (0.5 if which == "a" else 0.6), pred
    assert len(pred["tip_error_mm"]["per_repeat"]) == 2


def test_a_value_fitted_to_the_edge_of_its_range_is_not_observable_and_takes_its_peers():
    """A friction peak at the fit's upper bound (what a train read through its noisy sensor, barely
    moved, can take) is no measurement: it is listed as not observable, with its level and shape,
    and the model file holds the median of the same servo model's joints that fitted inside."""
    from types import SimpleNamespace

    from bench.identify.fit import LOWER, UPPER, FitResult, JointFit, at_bound_keys
    from bench.identify.run import model_file_of
    from bench.identify.simulate import PHYSICS

    inside = np.array([0.9, 0.012, 0.0, 0.04, 0.1, 0.2])
    assert at_bound_keys(inside) == ()
    peak = inside.copy()
    peak[PHYSICS.index("stribeck_nm")] = UPPER[PHYSICS.index("stribeck_nm")]
    assert set(at_bound_keys(peak)) == {"stribeck_nm", "coulomb_nm", "stribeck_velocity_rads"}
    broad = inside.copy()  # a peak fading too slowly to tell from Coulomb and viscous friction
    broad[PHYSICS.index("stribeck_velocity_rads")] = UPPER[PHYSICS.index("stribeck_velocity_rads")]
    assert set(at_bound_keys(broad)) == {"stribeck_nm", "coulomb_nm", "stribeck_velocity_rads"}
    weak = inside.copy()
    weak[PHYSICS.index("kt_scale")] = LOWER[PHYSICS.index("kt_scale")]
    assert at_bound_keys(weak) == ("kt_scale",)
    free = inside.copy()
    free[PHYSICS.index("coulomb_nm")] = 0.0  # no Coulomb friction: a physical answer
    free[PHYSICS.index("stribeck_nm")] = 0.0  # nor a friction at rest
    assert at_bound_keys(free) == ()
    level = inside.copy()
    level[PHYSICS.index("coulomb_nm")] = UPPER[PHYSICS.index("coulomb_nm")]
    assert set(at_bound_keys(level)) == {"stribeck_nm", "coulomb_nm", "stribeck_velocity_rads"}

    def joint(name, stribeck, edge=()):
        values = {**DATASHEET, "stribeck_nm": stribeck, "coulomb_nm": stribeck / 2}
        return JointFit(name, values, {k: 0.0 for k in values}, {k: k not in edge for k in values},
                        1.0, 0.5, 1.0, 0.5, 3, edge)

    edge = ("stribeck_nm", "coulomb_nm", "stribeck_velocity_rads")
    fit = FitResult({"train": joint("train", 2.0, edge), "theta3": joint("theta3", 0.1),
                     "theta4": joint("theta4", 0.12), "theta5": joint("theta5", 0.3)})
    setup = SimpleNamespace(robot="arc-train", joint_names=("train", "theta3", "theta4", "theta5"),
                            models=(1020, 1020, 1020, 1020))
    model = model_file_of(setup, [], fit)
    assert model.joints["train"].stribeck_nm == pytest.approx(0.12)  # not 2.0
    assert model.joints["train"].coulomb_nm == pytest.approx(0.06)
    assert set(edge) <= set(model.unobservable["train"])
    assert any("train" in n and "edge" in n for n in model.notes)


def test_a_batch_simulated_on_the_pool_is_the_batch_simulated_alone(rigs):
    """The pool splits a batch's servos between processes (a wide batch: a long log's): each servo's
    simulation is its own, so the split changes no number, and a narrow batch stays in one process."""
    from concurrent.futures import ProcessPoolExecutor

    from bench.identify.fit import _Problem, initial_physics
    from bench.identify.logs import load_runs

    setup, runs = load_runs([rigs["a"]])
    joints = np.flatnonzero(np.any([r.excited for r in runs], axis=0))
    rng = np.random.default_rng(5)
    which = np.resize(np.arange(len(joints)), 3 * len(joints))
    physics = initial_physics(setup)[joints][which] * rng.uniform(0.7, 1.3, (len(which), 6))
    alone = _Problem(setup, runs, joints, None).simulate(physics, which)
    with ProcessPoolExecutor(2) as pool:
        pooled = _Problem(setup, runs, joints, pool, workers=2)
        narrow = pooled.simulate(physics, which)  # under the pool's threshold: one process
        assert not pool._processes
        pooled.pool_min_servos = 1
        split = pooled.simulate(physics, which)
        assert len(pool._processes) == 2
    for a, b, c in zip(alone, narrow, split):
        for x, y, z in zip(a, b, c):
            assert np.array_equal(x, y) and np.array_equal(x, z)
