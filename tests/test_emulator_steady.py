"""The bus's steady path (every servo's position loop stepped at once) is the servo-by-servo path,
bit for bit: the same control tables after every batch, the same shafts, an overload tripping at
the same step."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.emulator import XL430_W250, XM430_W350, DynamixelBusEmulator, InertiaPlant, ServoModel
from drivers.emulator import clock as physics_clock

GOAL, TORQUE = 116, 64


def _bus(steady: bool, plain: bool = False) -> DynamixelBusEmulator:
    """Four servos on three joints: ``plain``, the bench's case (position loops with no profile, no
    deadband: the fused loop's); otherwise a deadband, a current-based mode and a profile beside it."""
    if plain:
        servos = {
            1: ServoModel(XM430_W350, registers={"Position I Gain": 300}, overload_time_s=0.03),
            2: ServoModel(XM430_W350, registers={"Drive Mode": 1, "Homing Offset": 100}),
            3: ServoModel(XM430_W350, registers={"Operating Mode": 4}),
            4: ServoModel(XL430_W250, registers={"Position D Gain": 200}),
        }
    else:
        servos = {
            1: ServoModel(XM430_W350, registers={"Position I Gain": 300}, overload_time_s=0.03),
            2: ServoModel(XM430_W350, registers={"Drive Mode": 1, "Homing Offset": 100}, deadband_ticks=2),
            3: ServoModel(XM430_W350, registers={"Operating Mode": 5, "Goal Current": 400}),
            4: ServoModel(XL430_W250, registers={"Profile Velocity": 60, "Profile Acceleration": 20}),
        }
    plant = InertiaPlant(3, inertia=0.01, coulomb=0.05, viscous=0.01, gravity=[0.3, 0.0, -0.2])
    bus = DynamixelBusEmulator(servos, plant, joints={1: 0, 2: 1, 3: 2, 4: 2}, realtime=False,
                               check_baud=False)
    bus.steady = steady
    return bus


def _script(bus: DynamixelBusEmulator) -> list:
    """Torque on, goals written between batches of 1 to 7 steps, a joint blocked until its servo's
    overload trips; every servo's control table (as a READ sees it) and the shafts after each batch."""
    seen = []
    servos = [bus.servo(i) for i in (1, 2, 3, 4)]
    for s in servos:
        assert s.write(TORQUE, b"\x01") == 0
    for k in range(120):
        if k % 10 == 0:
            for j, s in enumerate(servos):
                goal = 2048 + (-1) ** j * (40 * (k // 10) + 17 * j)
                assert s.write(GOAL, int(goal).to_bytes(4, "little", signed=True)) == 0
        if k == 60:
            bus.plant.block(0)  # servo 1 pushes against a stop: its overload trips within 30 ms
        bus._physics(1 + k % 7)
        seen.append([s.memory for s in servos] + [bus.plant.position().tobytes(), bus.plant.velocity().tobytes()])
    return seen


@pytest.mark.parametrize("plain", [True, False], ids=["plain loops", "deadband, current mode, profile"])
def test_the_steady_path_is_the_servo_by_servo_path_bit_for_bit(plain, monkeypatch):
    ran = []
    original = physics_clock.run_steady

    def counting(*args):
        done = original(*args)
        ran.append(done)
        return done

    monkeypatch.setattr(physics_clock, "run_steady", counting)
    steady = _bus(True, plain)
    with_steady = _script(steady)
    reference = _bus(False, plain)
    servo_by_servo = _script(reference)
    assert sum(ran) > 200 and 0 in ran  # most steps went the steady way, and the tripped servo's the other
    assert steady.servo(1).hardware_error_status & 0x20 and not steady.servo(1).torque_enabled
    assert reference.servo(1).hardware_error_status & 0x20
    for k, (a, b) in enumerate(zip(with_steady, servo_by_servo)):
        assert a == b, f"batch {k}: the steady path's state differs from the servo-by-servo path's"


@pytest.mark.parametrize("change", ["torque off", "forced", "undervoltage"])
def test_a_servo_off_the_position_loop_sends_the_batch_the_servo_by_servo_way(change, monkeypatch):
    """Torque off, a forced report, a supply out of its limits: that servo's step is its own, so the
    whole batch takes the servo-by-servo path (and the supply's fault latches as there)."""
    bus = _bus(True)
    servos = [bus.servo(i) for i in (1, 2, 3, 4)]
    for s in servos:
        s.write(TORQUE, b"\x01")
    if change == "torque off":
        servos[1].write(TORQUE, b"\x00")
    elif change == "forced":
        servos[1].force("Present Temperature", 80)
    else:
        servos[1].input_voltage = 5.0
    ran = []
    original = physics_clock.run_steady
    monkeypatch.setattr(physics_clock, "run_steady", lambda *a: ran.append(original(*a)) or ran[-1])
    bus._physics(5)
    assert ran == [0]
    if change == "undervoltage":
        assert servos[1].hardware_error_status & 0x01
    assert np.isfinite(bus.plant.position()).all()
