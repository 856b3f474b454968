"""The emulated rig: the robot's servo bus and ultrasonic sensor on pseudo-terminals.

Built from the same trial config a technician edits for the real rig: the
servos (IDs, models, modes, transmissions) become emulated X-series servos
whose plant is the robot in PyBullet under torque control, and the ultrasonic
sensor reports the train's true d2 (plus the standoff) with the configured
noise, rate and dropouts. The real driver then talks to it byte for byte.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from bench.config import DynamixelBackendConfig, TrialConfig, model_number


@dataclass
class RigPorts:
    dynamixel_port: str
    ultrasonic_port: Optional[str]


class EmulatedRig:
    """Both emulators for one config; a context manager that serves until closed."""

    def __init__(self, config: TrialConfig, initial_position: Optional[np.ndarray] = None,
                 realtime: bool = True) -> None:
        from bench.robots import get_robot
        from drivers.emulator import DynamixelBusEmulator, ServoModel, UltrasonicEmulator
        from drivers.emulator.pybullet_plant import PyBulletPlant

        if config.backend.kind != "dynamixel":
            raise ValueError(f"{config.source}: --emulate needs backend.kind: dynamixel")
        b: DynamixelBackendConfig = config.backend
        e = config.emulator
        self.config = config
        self.robot = get_robot(config.robot)
        names = self.robot.joint_names
        q0 = self.robot.chain.home if initial_position is None else np.asarray(initial_position)
        ratio = [b.servos[n].ratio for n in names]
        offset = [b.servos[n].offset for n in names]
        friction = [e.joint_friction.get(n, 0.0) for n in names]
        from drivers.emulator.control_table import model_spec

        motors = [model_spec(model_number(b.servos[n].model)).motor for n in names]
        self.plant = PyBulletPlant(config.robot_urdf, names, ratio, offset, q0,
                                   motor_damping=[m.kt * m.ke / m.resistance for m in motors],
                                   physics_dt=1.0 / e.physics_hz, friction=friction)
        from drivers.dynamixel_backend import MODES

        baud_index = _baud_index(b.baud)
        servos = {}
        joints = {}
        for j, n in enumerate(names):
            sc = b.servos[n]
            deadband = int(round(math.radians(e.deadband_deg) / (2 * math.pi / 4096)))
            # The rig as the lab keeps it: EEPROM already set up, servos holding their pose.
            registers = {"Baud Rate": baud_index, "Operating Mode": MODES[sc.mode],
                         "Return Delay Time": int(round(b.return_delay_us / 2))}
            servos[sc.id] = ServoModel(model_number(sc.model), id=sc.id, registers=registers,
                                       deadband_ticks=deadband)
            joints[sc.id] = j
        self.bus = DynamixelBusEmulator(servos, self.plant, joints=joints,
                                        physics_dt=1.0 / e.physics_hz,
                                        wire_timing=e.wire_timing, seed=e.seed, realtime=realtime)
        if e.start_torque_on:
            for servo in servos.values():
                servo.set("Torque Enable", 1)
        self.ultrasonic = None
        if b.ultrasonic is not None:
            u = b.ultrasonic
            train = names.index(u.joint)
            standoff = u.standoff_mm * 1e-3
            d2_of = self._d2_function()

            def distance() -> float:
                with self.bus.lock:
                    q = self.plant.joint_position()[train]
                return standoff + d2_of(q)

            self.ultrasonic = UltrasonicEmulator(distance, rate_hz=e.ultrasonic_rate_hz,
                                                 noise_std_m=e.ultrasonic_noise_mm * 1e-3,
                                                 dropout_prob=e.ultrasonic_dropout, seed=e.seed + 1)

    def _d2_function(self):
        from bench.kinematics.arc_train import train_pose

        params = self.robot.params
        return lambda eps: float(train_pose(eps, params).d2)

    @property
    def ports(self) -> RigPorts:
        return RigPorts(self.bus.port, self.ultrasonic.port if self.ultrasonic else None)

    def start(self) -> "EmulatedRig":
        self.bus.start()
        if self.ultrasonic is not None:
            self.ultrasonic.start()
        return self

    def close(self) -> None:
        if self.ultrasonic is not None:
            self.ultrasonic.stop()
        self.bus.stop()
        self.plant.close()

    def __enter__(self) -> "EmulatedRig":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def retarget(self, config: TrialConfig) -> TrialConfig:
        """The config with its ports pointed at this rig."""
        return retarget(config, self.ports)


def _baud_index(baud: int) -> int:
    from drivers.emulator.control_table import BAUD_RATES

    for k, v in BAUD_RATES.items():
        if v == baud:
            return k
    raise ValueError(f"baud {baud} is not an X-series rate; choose from {sorted(BAUD_RATES.values())}")


def serve(config: TrialConfig, announce) -> None:
    """Run the rig until SIGINT/SIGTERM; SIGUSR1 unplugs the bus, SIGUSR2 plugs it back."""
    stop = threading.Event()
    with EmulatedRig(config) as rig:
        previous = {}

        def on_stop(signum, frame):  # noqa: ARG001
            stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_stop)
        signal.signal(signal.SIGUSR1, lambda *a: rig.bus.unplug())
        signal.signal(signal.SIGUSR2, lambda *a: rig.bus.replug())
        announce(rig.ports)
        try:
            while not stop.wait(0.2):
                pass
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


class EmulatorProcess:
    """`hilbench emulate CONFIG --json` in a child process (its own core, its own GIL)."""

    def __init__(self, config_path: Path, start_timeout: float = 30.0) -> None:
        exe = Path(sys.executable).with_name("hilbench")
        cmd = ([str(exe)] if exe.exists() else [sys.executable, "-m", "bench.cli"])
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
        self.proc = subprocess.Popen(cmd + ["emulate", str(config_path), "--json"],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env=env)
        line = self._first_line(start_timeout)
        try:
            ports = json.loads(line)
        except json.JSONDecodeError:
            err = self.proc.stderr.read() if self.proc.poll() is not None else ""
            self.close()
            raise RuntimeError(f"the emulator did not start: {(line + err).strip()}") from None
        self.ports = RigPorts(ports["dynamixel_port"], ports.get("ultrasonic_port"))

    def _first_line(self, timeout: float) -> str:
        out: list[str] = []
        t = threading.Thread(target=lambda: out.append(self.proc.stdout.readline()), daemon=True)
        t.start()
        t.join(timeout)
        if not out:
            self.close()
            raise RuntimeError(f"the emulator did not announce its ports within {timeout:.0f} s")
        return out[0]

    def unplug(self) -> None:
        self.proc.send_signal(signal.SIGUSR1)

    def replug(self) -> None:
        self.proc.send_signal(signal.SIGUSR2)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def retarget(self, config: TrialConfig) -> TrialConfig:
        return retarget(config, self.ports)

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def retarget(config: TrialConfig, ports: RigPorts) -> TrialConfig:
    """The config with its ports pointed at an emulated rig."""
    b = config.backend
    u = b.ultrasonic
    backend = b.model_copy(update={
        "port": ports.dynamixel_port,
        "ultrasonic": u.model_copy(update={"port": ports.ultrasonic_port}) if u else None})
    return config.model_copy(update={"backend": backend})
