"""One servo core: every simulator of a servo steps the same firmware, motor, friction and joint
integrator, fed by one parameter path. These tests fail if a copy comes back: a friction law or a
joint integrator written outside the core, an emulated servo running another motor than its model
file's, a simulator drifting from the others on the same model and goals."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.identify.logs import LoggedRun, RigSetup
from bench.identify.simulate import SlotPhysics, simulate_run
from bench.stand.emulated import BAUD, EmulatedStand
from bench.stand.predict import predict
from bench.stand.record import record_stand_log, write_stand_log
from bench.stand.session import emulated_clock
from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.control_table import XL330_M288, XM430_W350
from drivers.dynamixel.stand import StandServo
from drivers.dynamixel.units import CENTER_TICK
from drivers.emulator import ServoModel
from drivers.servo import ServoArray, ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.joints import joint_damping
from drivers.servo.plant import PyBulletPlant

REPO = Path(__file__).resolve().parents[1]
#: The physics ``hilbench identify`` fitted on the twelve real XL330 logs (the stand's gravity offset too).
IDENTIFIED = REPO / "tests" / "data" / "xl330_stand_identified.yaml"
STAND_URDF = REPO / "urdf" / "test_stand_xl330.urdf"
RAD_PER_TICK = 2 * np.pi / 4096
CORE = {"drivers/servo/friction.py", "drivers/servo/joints.py"}

#: A friction law evaluated: a smoothed or signed Coulomb term, a Stribeck fade, a stick-slip force.
FRICTION_LAW = re.compile(r"np\.tanh\(|np\.exp\(\s*-\s*\(|np\.exp\(\s*-\s*np\.abs|math\.copysign\(|"
                          r"sign\([^)]*\)\s*\*\s*\w*(coulomb|level|friction)|\b(c|coulomb)\s*\*\s*direction")
#: A joint integrator: a velocity or position advanced by a step's acceleration or velocity.
INTEGRATOR = re.compile(r"\b(qd|v|omega|velocity)(_new)?\s*=\s*\(?\s*(qd|v|omega|velocity)\s*[+*].*\bdt\b|"
                        r"\bq(_new)?\s*=\s*q\s*\+\s*(dt\s*\*\s*qd|qd\s*\*\s*dt)")


def _sources() -> list[Path]:
    return [p for d in ("drivers", "bench", "benchmarks") for p in sorted((REPO / d).rglob("*.py"))]


def test_no_friction_law_or_joint_integrator_is_written_outside_the_core() -> None:
    """Scans every module of the bench and the drivers (and the benchmarks): a friction law lives in
    drivers/servo/friction.py, the joints' integration in drivers/servo/joints.py, and nowhere else."""
    found = []
    for path in _sources():
        rel = path.relative_to(REPO).as_posix()
        if rel in CORE:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if FRICTION_LAW.search(code) or INTEGRATOR.search(code):
                found.append(f"{rel}:{number}: {line.strip()}")
    assert not found, "a second copy of the servo core:\n" + "\n".join(found)
    # and the scan does see a copy: the old inline friction and steps of identification's rollout,
    # the stand's rollout, the bus's InertiaPlant and the robot's plant
    old = ("        friction = level * np.tanh(w_ * smoothing) * inv_r\n"
           "        qd = qd + dt * (tau * inv_r + (b_emf - b) * qd - load[s].take(flat) - friction) / (\n"
           "        q = q + dt * qd\n"
           "            qd = qd + net / inertia * dt\n"
           "            q = q + qd * dt\n"
           "                v_new = (inertia * v + dt * (tau - c * direction)) / (inertia + dt * b)\n"
           "        qd_new = qd + dt * self._potrs(self._cholesky, rhs)[0]\n"
           "            rhs -= self._joint_friction * np.tanh(qd / FRICTION_SMOOTHING_RAD_S)\n")
    assert all(FRICTION_LAW.search(x) or INTEGRATOR.search(x) for x in old.splitlines())


#: The servo's damping on its joint recomputed: the back-EMF's damping or the armature read off the
#: parameters (their one reader is :func:`drivers.servo.joints.joint_damping`).
DAMPING = re.compile(r"\.back_emf_damping\b|\.armature\s*[/*+]|\.armature\s*$")


def test_the_servos_damping_on_its_joint_is_computed_once() -> None:
    """Every simulator of a servo (the robot's plant, the twin, identification's rollout, the stand's)
    takes the armature and the back-EMF's and viscous damping through the transmission, and the
    implicit step's share of them, from ``joint_damping``; a copy of that law fails here."""
    found = []
    for path in _sources():
        rel = path.relative_to(REPO).as_posix()
        if rel in CORE | {"drivers/servo/model.py"}:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if DAMPING.search(line.split("#", 1)[0]):
                found.append(f"{rel}:{number}: {line.strip()}")
    assert not found, "the damping law computed outside drivers/servo/joints.py:\n" + "\n".join(found)
    old = ("        self._implicit = p.armature / r2 + FIRMWARE_PERIOD_S * (p.back_emf_damping + p.viscous) / r2\n"
           "    matrix = inertia + dt * (p.back_emf_damping + viscous)\n"
           "        self._Ja = servos.armature / r2\n")
    assert all(DAMPING.search(x) for x in old.splitlines())
    p = ServoParams.datasheet([XM430_W350] * 2, viscous=0.02)
    d = joint_damping(p, np.array([1.0, 0.01]))
    assert np.allclose(d.armature, p.armature / [1.0, 1e-4]) and np.allclose(d.back_emf, p.back_emf_damping / [1.0, 1e-4])
    assert np.allclose(d.implicit(1e-3), d.armature + 1e-3 * (d.back_emf + d.viscous))


def test_the_implicit_friction_law_solves_its_step_and_meets_free_and_held_joints_at_its_limits() -> None:
    """The twin's step of dry friction at 10 ms: the speed that solves
    A·v + dt·F·tanh(v/(r·ω_ε)) = A·q̇ + dt·rhs, to a hundredth of ω_ε; without friction A⁻¹ times the
    momentum; sliding fast, the momentum less the friction's impulse; held (momentum under the
    impulse), no faster than the smoothed law's creep, and the same through step_joints (which
    refuses a full mass matrix for it)."""
    from drivers.servo.friction import FRICTION_SMOOTHING_RAD_S as W, implicit_smooth_speed
    from drivers.servo.joints import step_joints

    rng = np.random.default_rng(3)
    inertia = rng.uniform(0.01, 0.2, 200)  # the twin's diagonal at 10 ms, kg·m² (slides: ×1e4)
    level = 0.01 * rng.uniform(0.0, 0.15, 200)  # dt × the dry level, N·m·s
    scale = rng.choice([1.0, 20.0, 100.0], 200)  # the shaft's speed per joint speed
    momentum = rng.normal(0.0, 1.0, 200) * level * rng.choice([0.5, 2.0, 50.0], 200)
    v = implicit_smooth_speed(inertia, momentum, level, scale)
    balance = inertia * v + level * np.tanh(scale * v / W) - momentum
    assert np.all(np.abs(balance) <= 0.01 * W / scale * (inertia + level * scale / W)), balance
    free = implicit_smooth_speed(inertia, momentum, 0.0 * level, scale)
    assert np.allclose(free, momentum / inertia, rtol=1e-12, atol=0)
    fast = np.abs(momentum) > 10 * level
    assert np.allclose(v[fast], (momentum - np.sign(momentum) * level)[fast] / inertia[fast], rtol=1e-6)
    held = np.abs(momentum) < level
    creep = W / scale[held] * np.arctanh(np.abs(momentum / level)[held])
    assert held.sum() > 20 and np.all(np.abs(v[held]) <= creep)
    q, qd, rhs = np.zeros(200), rng.normal(0, 1e-3, 200), rng.normal(0, 1.0, 200)
    _, stepped = step_joints(q, qd, 0.01, rhs, inertia, level / 0.01, "implicit", None, shaft_scale=scale)
    assert np.array_equal(stepped, implicit_smooth_speed(inertia, inertia * qd + 0.01 * rhs, level, scale))
    with pytest.raises(ValueError, match="diagonal"):
        step_joints(q[:2], qd[:2], 0.01, rhs[:2], lambda b: b, level[:2], "implicit")


def test_an_emulated_servo_runs_the_motor_its_model_file_describes() -> None:
    """One parameter path: an emulated servo built from the model's parameters (Kt, Ke and R
    identified, not the datasheet's) gives the servo array's torque step for step."""
    params = ServoParams.datasheet([XL330_M288]).with_(kt=0.30, ke=0.22, resistance=3.1)
    servo = ServoModel(XL330_M288, motor=params, input_voltage=7.0)
    array = ServoArray(params.with_(supply_voltage=7.0))
    servo.power_on(0.0)
    servo.set("Torque Enable", 1)
    servo.power_on(0.0)  # goal = present with torque on, as a torque-on write does
    array.reset(np.zeros(1))
    goal = 0.4
    servo._write_goal_position(int(CENTER_TICK + np.round(goal / RAD_PER_TICK)))
    array.set_goal(np.array([goal]))
    q = qd = 0.0
    for _ in range(300):
        tau = servo.step(0.001, q, qd)
        expected = array.step(0.001, np.array([q]), np.array([qd]))[0]
        assert tau == pytest.approx(expected, rel=0, abs=1e-9)
        qd += 0.001 * tau / 0.01
        q += 0.001 * qd
    assert q > 0.1  # it moved
    datasheet = ServoModel(XL330_M288, input_voltage=7.0)
    assert datasheet._kt != pytest.approx(0.30)  # the datasheet's motor is another one


def test_the_emulated_stand_with_the_identified_physics_is_what_predict_says(tmp_path) -> None:
    """The stand emulated on the bus (byte for byte, its URDF in PyBullet, the emulated servo's
    motor from the model file) with the physics identified from the twelve real logs, recorded on
    BAM's four trajectories and predicted by that same model file: within 0.002 rad mean MAE
    (measured 0.0012; 0.029 when the emulated motor took only kt_scale from the file)."""
    model = yaml.safe_load(IDENTIFIED.read_text())
    physics, offset = model["joints"]["pendulum"], model["stand"]["gravity_offset_rad"]
    assert offset != 0.0
    paths = []
    with EmulatedStand(physics, mass=0.49, length=0.1, supply_v=7.0, source_ohm=1.0,
                       gravity_offset_rad=offset) as stand, \
            ServoBus(stand.port, BAUD, tries=30) as bus:
        wait = emulated_clock(stand)

        for name, kp in (("sin_sin", 400), ("lift_and_drop", 200), ("up_and_down", 400), ("sin_time_square", 800)):
            log = record_stand_log(StandServo(bus), name, kp=kp, mass=stand.mass, length=stand.length, vin=7.4,
                                   wait=wait)
            paths.append(write_stand_log(log, tmp_path / f"{name}.json"))
    prediction = predict(IDENTIFIED, paths)
    assert prediction.mean_mae <= 0.002, [s.mae for s in prediction.scores]
    assert max(np.ptp(s.log.position) for s in prediction.scores) > 0.5  # the arm really moved
    # the check can fail: the datasheet's motor (no identified R or Ke) misses by far more
    physics.pop("resistance_ohm"), physics.pop("ke_scale")
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({**model, "joints": {"pendulum": physics}}))
    assert predict(other, paths).mean_mae > 5 * prediction.mean_mae


def _sim_log(params: ServoParams, seconds: float = 3.0) -> tuple[LoggedRun, RigSetup]:
    """The servo-model sim's plant and fused loop on one joint (the stand's pendulum, an XM430
    behind it) following a sweep, logged every 1 ms as identification reads a trial log."""
    dt = 0.001
    plant = PyBulletPlant(STAND_URDF, ["pendulum"], [1.0], [0.0], [0.0], params, physics_dt=dt)
    servos = ServoArray(params)
    servos.reset(np.zeros(1))
    loop = PositionLoop(servos, dt, np.ones(1), np.zeros(1))
    rows = int(round(seconds / dt))
    t = np.arange(rows) * dt
    goal = (0.9 * np.sin(2 * np.pi * 0.4 * t) * np.minimum(t / 0.5, 1.0))[:, None]
    q, qd, current, inertia, load = (np.empty((rows, 1)) for _ in range(5))
    for k in range(rows):
        q[k], qd[k] = plant.state()
        current[k] = servos.current
        M, h = plant.dynamics(q[k], qd[k])
        inertia[k], load[k] = M[0, 0], h[0]
        loop.set_goal(goal[k])
        plant.step_joint(loop.step_joint(*plant.state()))
    plant.close()
    run = LoggedRun(run_dir=Path("sim"), sha256="", time=t, goal=goal, q=q, qd=qd, current=current,
                    inertia=inertia, load=load, excited=np.array([True]))
    setup = RigSetup(robot="stand", joint_names=("pendulum",), kinds=("revolute",), models=(XM430_W350,),
                     ratio=np.ones(1), offset=np.zeros(1), lower=np.array([-10.0]), upper=np.array([10.0]),
                     datasheet=params, kt_datasheet=params.kt.copy(), train=None, signature=())
    return run, setup


def test_identifications_rollout_on_one_joint_is_the_servo_model_sim() -> None:
    """Identification's one-joint rollout, given the sim's own log (its inertia and bias along it) and
    the sim's physics, retraces the servo-model sim to the last bit or two — with a Stribeck exponent
    of 1.5 and load-dependent gear friction, which the rollout's old copy of the friction left out
    (that copy lands 2.7 mrad off) — and a Coulomb level 3 times off does not."""
    params = ServoParams.datasheet([XM430_W350], armature=0.01, coulomb=0.03, viscous=0.02, stribeck=0.06,
                                   stribeck_velocity=0.2).with_(stribeck_alpha=1.5, load_motor=0.1,
                                                                load_external=0.15)
    run, setup = _sim_log(params)
    truth = np.array([[1.0, 0.01, 0.02, 0.03, 0.06, 0.2]])
    q_sim = simulate_run(setup, run, SlotPhysics(np.zeros(1, dtype=int), truth), window_s=10.0)[0][:, 0]
    error = np.abs(q_sim - run.q[:, 0]).mean()
    assert np.ptp(run.q) > 1.0 and error < 1e-9, error  # measured 2e-16
    # the rollout's old copy of the friction (exponent 2, no load-dependent friction): 2.7 mrad off
    import dataclasses

    old_law = dataclasses.replace(setup, datasheet=params.with_(stribeck_alpha=2.0, load_motor=0.0,
                                                                load_external=0.0))
    q_old = simulate_run(old_law, run, SlotPhysics(np.zeros(1, dtype=int), truth), window_s=10.0)[0][:, 0]
    assert np.abs(q_old - run.q[:, 0]).mean() > 1e-3
    wrong = truth.copy()
    wrong[0, 3] *= 3
    q_wrong = simulate_run(setup, run, SlotPhysics(np.zeros(1, dtype=int), wrong), window_s=10.0)[0][:, 0]
    assert np.abs(q_wrong - run.q[:, 0]).mean() > 100 * max(error, 1e-8)


def test_the_emulated_rigs_servos_run_the_motors_of_their_physics(tmp_path) -> None:
    """The emulated rig's bus steps the motors ``emulator.servo_physics`` describes (Kt, Ke and R
    each), the very parameters its plant and the sim's servo model are built from, not a datasheet
    motor scaled by kt_scale alone."""
    import yaml

    from bench.config.models import load_trial_config
    from bench.rig.emulated import EmulatedRig

    data = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())
    data.setdefault("emulator", {})["servo_physics"] = {
        "all": {"kt_scale": 0.8, "ke_scale": 0.9, "resistance_ohm": 6.5},
        "theta5": {"resistance_ohm": 9.0}}
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(data))
    with EmulatedRig(load_trial_config(path), realtime=False) as rig:
        hidden, bank = rig.servo_params, rig.bus._bank.params
        joints = [joint for _, joint in rig.bus._servos]
        for name in ("kt", "ke", "resistance"):
            assert np.array_equal(getattr(bank, name), getattr(hidden, name)[joints]), name
        theta5 = rig.robot.joint_names.index("theta5")
        assert hidden.resistance[theta5] == 9.0 and set(hidden.resistance) == {6.5, 9.0}
        datasheet = ServoParams.datasheet([XM430_W350])
        assert not np.allclose(bank.ke, 0.8 * datasheet.ke[0])  # Ke scaled on its own, as the file says


def test_the_emulated_rigs_servos_follow_goals_as_the_servo_sims_do(tmp_path) -> None:
    """The emulated rig (goals written to the servos' registers, the bus stepping the firmware in
    ticks, worn gearboxes and an identified motor) and the servo-model sim's core (the same
    parameters, the fused loop from the joints, its own plant) from the same pose, the same goals:
    the same joint paths to 0.2 mrad (measured 0.05) over moves of 0.17–0.37 rad."""
    import yaml

    from bench.config.models import load_trial_config
    from bench.rig.emulated import EmulatedRig

    data = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())
    data["emulator"]["servo_physics"] = {"all": {"coulomb_nm": 0.05, "stribeck_nm": 0.08, "viscous_nms": 0.1,
                                                 "kt_scale": 0.9, "resistance_ohm": 9.0}}
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = load_trial_config(path)
    with EmulatedRig(cfg, realtime=False) as rig:
        plant = rig.plant
        q0 = plant.joint_position()
        sim = PyBulletPlant(cfg.robot_urdf, list(rig.robot.joint_names), plant._ratio, plant._offset, q0,
                            rig.servo_params, physics_dt=0.001, joint_friction=plant._joint_friction)
        servos = ServoArray(rig.servo_params)
        servos.reset(sim.position())  # torque on where the rig's servos were switched on
        loop = PositionLoop(servos, 0.001, plant._ratio, plant._offset)
        delta = np.round(np.radians([20, 10, -15, 10, 10, -10, 10, 10, 10]) / RAD_PER_TICK)
        start = servos.goal.copy()
        worst = np.zeros(len(q0))
        for k in range(1500):
            if k == 300:  # after a while holding against gravity, every joint told to move
                for servo, j in rig.bus._servos:
                    sign = -1 if servo.get("Drive Mode") & 1 else 1
                    servo._write_goal_position(int(servo.get("Goal Position") + sign * delta[j]))
                loop.set_goal((start + delta) * RAD_PER_TICK)
            rig.bus.advance(0.001)
            sim.step_joint(loop.step_joint(*sim.state()))
            worst = np.maximum(worst, np.abs(plant.joint_position() - sim.joint_position()))
        moved = np.abs(plant.joint_position() - q0)
        sim.close()
    assert moved[1:7].min() > 0.15 and worst.max() < 2e-4, (worst, moved)
