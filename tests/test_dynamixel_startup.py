"""The driver's start-up under a load: enable never drops what a servo holds, and returns only once
every servo holds still at its goal, so a plan starts from a servo at rest.

One XM430 on an emulated bus, driving a joint that gravity pulls with 1.5 N·m (the wrist's order):
at the factory gains (P 800, no I) it sags about 50 ticks (4.4°) off its goal."""

from __future__ import annotations

import threading
import time

import numpy as np

from drivers.dynamixel.backend import DynamixelActuators
from drivers.dynamixel.control_table import XM430_W350
from drivers.dynamixel.settings import DynamixelSettings, ServoSettings
from drivers.emulator import DynamixelBusEmulator, InertiaPlant, ServoModel

TICK = 2 * np.pi / 4096
GRAVITY_NM = -1.5
I_GAIN = 2000  # an integrator that takes the load up in about a second (kp/ki = 0.2 s)


def _bus(torque_on: bool) -> DynamixelBusEmulator:
    servo = ServoModel(XM430_W350, registers={"Baud Rate": 3, "Return Delay Time": 0, "Operating Mode": 3})
    plant = InertiaPlant(1, inertia=0.02, viscous=0.05, gravity=GRAVITY_NM)
    bus = DynamixelBusEmulator({1: servo}, plant)
    if torque_on:  # a servo left holding its pose at the factory gains: sagged, its goal at the centre
        servo.set("Torque Enable", 1)
        bus.advance(2.0)
    return bus


def _settings(port: str) -> DynamixelSettings:
    return DynamixelSettings(port=port, baud=1_000_000,
                             servos=[ServoSettings(joint="j", id=1, model=1020, mode="position",
                                                   gains=(None, I_GAIN, None))],
                             joint_names=["j"], lower=[-1.0], upper=[1.0], velocity=[1.0], effort=[3.0])


def _enable_watching(bus: DynamixelBusEmulator) -> tuple[DynamixelActuators, np.ndarray]:
    """Enable a backend on ``bus``; the plant's angle (rad) sampled every 2 ms meanwhile, torque on."""
    act = DynamixelActuators(_settings(bus.port))
    seen, stop = [], threading.Event()

    def watch() -> None:
        while not stop.is_set():
            with bus.lock:
                if bus.servo(1).get("Torque Enable"):  # from torque on
                    seen.append(float(bus.plant.position()[0]))
            time.sleep(0.002)

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    try:
        act.enable()
    finally:
        stop.set()
        t.join()
    return act, np.array(seen)


def test_a_servo_found_holding_keeps_its_goal_and_is_not_dropped():
    with _bus(torque_on=True) as bus:
        sag = float(bus.plant.position()[0])
        assert sag < -40 * TICK  # the load has pulled it well off its goal (tick 2048, 0 rad)
        act, seen = _enable_watching(bus)
        with act:
            # its goal stays where it held the load; writing the sagged reading as the goal would
            # have taken away the proportional term's torque and let the load swing it further
            assert bus.servo(1).get("Goal Position") == 2048
            assert seen.min() >= sag - 2 * TICK
            # enable returned with the integrator holding it at its goal, still
            st = act.read()
            assert abs(st.position[0]) <= 2 * TICK
            assert abs(st.velocity[0]) < 0.05  # two of its 0.229 rpm units: a holding servo's hunt


def test_enable_returns_once_a_servo_switched_on_under_load_has_settled():
    with _bus(torque_on=False) as bus:
        act, seen = _enable_watching(bus)
        with act:
            goal = (bus.servo(1).get("Goal Position") - 2048) * TICK  # where it was switched on
            assert seen.min() < goal - 20 * TICK  # the load took it down before the integrator caught it
            st = act.read()  # and enable waited for it to come back and hold still
            assert abs(st.position[0] - goal) <= 2 * TICK
            assert abs(st.velocity[0]) < 0.05  # two of its 0.229 rpm units: a holding servo's hunt
