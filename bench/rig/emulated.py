"""The emulated rig: the robot's servo bus and ultrasonic sensor on pseudo-terminals, or on
``virtual://`` lines of this process on a virtual clock.

Built from the same trial config a technician edits for the real rig: the
servos (IDs, models, modes, transmissions) become emulated X-series servos
whose plant is the robot in PyBullet under torque control, and the ultrasonic
sensor reports the train's true d2 (plus the standoff) with the configured
noise, rate and dropouts. The real driver then talks to it byte for byte.

On the wall clock (``emulator.clock: realtime``) the rig serves ptys from threads (or from a child
process, :class:`EmulatorProcess`) and keeps real time, as the rig would. On a
:class:`~drivers.clock.VirtualClock` (``clock: virtual``) the same devices are steps of that clock
in this process (:mod:`drivers.emulator.virtual`): the driver opens ``virtual://`` URLs, its
waits advance the clock, and the trial is the same bit for bit on any machine.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import itertools
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Sequence

import numpy as np

from bench.config.models import (DynamixelBackendConfig, EmulatorConfig, TrialConfig, load_trial_config,
                                 model_number)
from bench.kinematics.arc_train import train_pose
from bench.kinematics.registry import get_robot
from bench.rig import serving
from bench.rig.backends import with_physics
from bench.rig.hooks import RemoteRigHooks, RigHooks, follow_commands
from drivers.dynamixel.control_table import x_series_table
from drivers.dynamixel.units import BAUD_RATES, OPERATING_MODES
from drivers.clock import VirtualClock
from drivers.emulator import DynamixelBusEmulator, ServoModel, UltrasonicEmulator
from drivers.emulator.virtual import VirtualBusEmulator, VirtualUltrasonic
from drivers.errors import BackendSetupError, ExitCode
from drivers.link import is_virtual_port
from drivers.servo import ServoParams
from drivers.servo.plant import PyBulletPlant
from drivers.timing import FrozenHeap, raise_priority


_RIG_NUMBERS = itertools.count(1)


@dataclass
class RigPorts:
    dynamixel_port: str
    ultrasonic_port: Optional[str]


@dataclass(frozen=True)
class Planted:
    """What the emulated rig has that its config does not say, to rehearse the lab tools.

    ``servo_registers``: register presets per joint (e.g. ``{"theta5": {"Baud Rate": 1}}``
    puts that servo at 57600 bps); ``servo_models``: a different model than configured;
    ``zero_errors``: mechanical zero errors (joint units): the true joint value at the
    servo's tick 2048 is the configured ``offset`` plus this; ``ultrasonic_offset_m`` and
    ``ultrasonic_scale``: the sensor reports ``scale · true distance + offset``.
    """

    servo_registers: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    servo_models: Mapping[str, str] = field(default_factory=dict)
    zero_errors: Mapping[str, float] = field(default_factory=dict)
    ultrasonic_offset_m: float = 0.0
    ultrasonic_scale: float = 1.0


def hidden_servo_params(emulator: EmulatorConfig, names: Sequence[str], models: Sequence[int]) -> ServoParams:
    """The emulated servos' physics: the datasheet's, with what ``emulator.servo_physics`` sets."""
    return with_physics(ServoParams.datasheet(models), [emulator.physics_of(n) for n in names])


class EmulatedRig:
    """Both emulators for one config; a context manager that serves until closed."""

    def __init__(self, config: TrialConfig, initial_position: Optional[np.ndarray] = None,
                 realtime: bool = True, planted: Optional[Planted] = None,
                 warm_start_s: float = 0.0, rest_after_s: Optional[float] = None,
                 clock: Optional[VirtualClock] = None) -> None:
        """``warm_start_s`` > 0 starts the rig as a previous session left it: the servos
        hold their pose with the config's PID gains written, and the physics has run that
        long (integrators charged, gravity sag gone) before the ports open.
        ``rest_after_s``: pause the physics once nothing has moved or been written for
        that long (``hilbench emulate`` does, so an idle rig costs no CPU).
        ``clock``: serve on ``virtual://`` lines as devices of that virtual clock instead of
        on ptys in real time."""

        if config.backend.kind != "dynamixel":
            raise ValueError(f"{config.source}: --emulate needs backend.kind: dynamixel")
        b: DynamixelBackendConfig = config.backend
        e = config.emulator
        planted = planted or Planted()
        self.config = config
        self.planted = planted
        self.robot = get_robot(config.robot)
        names = self.robot.joint_names
        q0 = self.robot.chain.home if initial_position is None else np.asarray(initial_position)
        ratio = [b.servos[n].ratio for n in names]
        offset = [b.servos[n].offset + planted.zero_errors.get(n, 0.0) for n in names]
        friction = [e.joint_friction.get(n, 0.0) for n in names]

        models = {n: model_number(planted.servo_models.get(n, b.servos[n].model)) for n in names}
        self.servo_params = hidden_servo_params(e, names, [models[n] for n in names])
        self.plant = PyBulletPlant(config.robot_urdf, names, ratio, offset, q0, self.servo_params,
                                   physics_dt=1.0 / e.physics_hz, joint_friction=friction)

        baud_index = _baud_index(b.baud)
        servos = {}
        joints = {}
        for j, n in enumerate(names):
            sc = b.servos[n]
            deadband = int(round(math.radians(e.deadband_deg) / x_series_table()["Present Position"].scale))
            # The rig as the lab keeps it: EEPROM already set up, servos holding their pose.
            return_delay = x_series_table()["Return Delay Time"].nearest(b.return_delay_us * 1e-6)
            registers = {"Baud Rate": baud_index, "Operating Mode": OPERATING_MODES[sc.mode],
                         "Return Delay Time": return_delay}
            if warm_start_s > 0:
                gains = zip(("Position P Gain", "Position I Gain", "Position D Gain"),
                            (sc.position_p, sc.position_i, sc.position_d))
                registers.update({k: v for k, v in gains if v is not None})
            registers.update(planted.servo_registers.get(n, {}))
            servos[sc.id] = ServoModel(models[n], id=sc.id, registers=registers, deadband_ticks=deadband,
                                       motor=self.servo_params.take(j))
            joints[sc.id] = j
        self.clock = clock
        name = f"rig-{next(_RIG_NUMBERS)}"  # in-process lines: unique within it, the same in every run
        if clock is not None:
            self.bus = VirtualBusEmulator(servos, self.plant, joints=joints, clock=clock,
                                          name=f"{name}/servos", physics_dt=1.0 / e.physics_hz,
                                          seed=e.seed)
        else:
            self.bus = DynamixelBusEmulator(servos, self.plant, joints=joints,
                                            physics_dt=1.0 / e.physics_hz,
                                            wire_timing=e.wire_timing, seed=e.seed, realtime=realtime,
                                            rest_after_s=rest_after_s)
        #: What a backend built on this bus carries as its fault hooks: the bus's faults and the plant's.
        self.hooks = RigHooks(self.bus)
        if e.start_torque_on:
            for servo in servos.values():
                servo.set("Torque Enable", 1)
        if warm_start_s > 0:
            self.bus.advance(warm_start_s)
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

            sensor = dict(rate_hz=e.ultrasonic_rate_hz or u.rate_hz,
                          noise_std_m=e.ultrasonic_noise_mm * 1e-3, dropout_prob=e.ultrasonic_dropout,
                          seed=e.seed + 1, offset_m=planted.ultrasonic_offset_m,
                          scale=planted.ultrasonic_scale)
            if clock is not None:
                self.ultrasonic = VirtualUltrasonic(distance, clock=clock, name=f"{name}/ultrasonic",
                                                    baud=u.baud, **sensor)
            else:
                self.ultrasonic = UltrasonicEmulator(distance, **sensor)

    def _d2_function(self):

        params = self.robot.params
        return lambda eps: float(train_pose(eps, params).d2)

    @property
    def ports(self) -> RigPorts:
        return RigPorts(self.bus.port, self.ultrasonic.port if self.ultrasonic else None)

    def start(self) -> "EmulatedRig":
        self.bus.start()
        if self.ultrasonic is not None:
            self.ultrasonic.start()
        serving.attach(self.bus.port, self.hooks)  # backends built on this port get its hooks
        return self

    def close(self) -> None:
        serving.detach(self.bus.port)
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

    for k, v in BAUD_RATES.items():
        if v == baud:
            return k
    raise ValueError(f"baud {baud} is not an X-series rate; choose from {sorted(BAUD_RATES.values())}")


def serve(config: TrialConfig, announce, report=None, applied=None) -> None:
    """Run the rig until SIGINT/SIGTERM; SIGUSR1 unplugs the bus, SIGUSR2 plugs it back; the
    commands on stdin change its faults, each told to ``applied`` by its number once done.

    ``report`` gets the bus's counters at the end (physics skipped when the host starved
    the emulator of CPU, packets, errors), so a rehearsal never hides a slow rig."""
    stop = threading.Event()
    # The rig's physics keeps real time ahead of a browser or a second job, where the OS allows
    # (its threads, started below, inherit it); a trial's own priority comes with the trial.
    raise_priority()
    with EmulatedRig(config, rest_after_s=REST_AFTER_S) as rig:
        previous = {}

        def on_stop(signum, frame):  # noqa: ARG001
            stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_stop)
        signal.signal(signal.SIGUSR1, lambda *a: rig.bus.unplug())
        signal.signal(signal.SIGUSR2, lambda *a: rig.bus.replug())
        if not sys.stdin.isatty():  # a parent process drives the rig's faults through our stdin
            threading.Thread(target=follow_commands, args=(rig.hooks, rig.bus, sys.stdin, applied),
                             daemon=True).start()
        with FrozenHeap():  # what the rig set up is never walked while it serves
            announce(rig.ports)
            try:
                while not stop.wait(0.2):
                    pass
            finally:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
                if report is not None:
                    with rig.bus.lock:
                        report(dataclasses.asdict(rig.bus.stats))


EMULATOR_TIMEOUT_MS = 50.0
#: Staleness allowance for the emulated ultrasonic sensor (s): its reader thread and the
#: emulator share a loaded host's CPU, so a line can come a few periods late.
EMULATOR_STALE_S = 0.5
#: An emulated rig left alone (servos still, no writes) pauses its physics after this long.
REST_AFTER_S = 0.5
#: How long a command to the emulated rig's process may take to be applied (s).
COMMAND_TIMEOUT_S = 5.0


class EmulatorProcess:
    """`hilbench emulate CONFIG --json` in a child process (its own core, its own GIL).

    ``faults`` changes the faults of the running emulator: its bus's (dropped, late or
    corrupted status packets) and its plant's (a contact on a joint, a friction that drifts),
    so fault wrappers reach the wire and the physics through it.
    """

    def __init__(self, config_path: Path, start_timeout: float = 30.0) -> None:
        exe = Path(sys.executable).with_name("hilbench")
        cmd = ([str(exe)] if exe.exists() else [sys.executable, "-m", "bench.cli.app"])
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")

        self._stderr = tempfile.TemporaryFile(mode="w+")
        # Its own session: a Ctrl-C or hang-up meant for the trial must not take the rig
        # away before the trial's safe stop has talked to it; the trial ends it after.
        # And it dies with its parent, even one killed outright.
        self.proc = subprocess.Popen(cmd + ["emulate", str(config_path), "--json"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._stderr, text=True, env=env,
                                     start_new_session=True,
                                     preexec_fn=functools.partial(_die_with_parent, os.getpid()))
        line = self._first_line(start_timeout)
        try:
            ports = json.loads(line)
        except json.JSONDecodeError:
            try:
                self.proc.wait(5)  # a child that failed is exiting: let it finish its message
            except subprocess.TimeoutExpired:
                pass
            self._stderr.seek(0)
            err = [ln.strip() for ln in (line + self._stderr.read()).splitlines() if ln.strip()]
            self.close()
            why = err[-1].removeprefix("error: ") if err else f"it exited with {self.proc.returncode}"
            raise RuntimeError(f"the emulator did not start: {why}") from None
        self.ports = RigPorts(ports["dynamixel_port"], ports.get("ultrasonic_port"))
        #: The bus's counters, read when the emulator has stopped (see :func:`serve`).
        self.stats: dict = {}
        # what the child says after its ports: each command's number once applied, its counters last
        self._sent = self._applied = 0
        self._answers: dict[int, dict] = {}
        self._told = threading.Condition()
        self._listener = threading.Thread(target=self._listen, daemon=True)
        self._listener.start()
        # the child validated the config it serves: its robot says how many joints the plant has
        joints = len(get_robot(load_trial_config(config_path).robot).joint_names)
        self.faults = RemoteRigHooks(self._send, joints)
        serving.attach(self.ports.dynamixel_port, self.faults)  # backends built on this port get its hooks

    def _first_line(self, timeout: float) -> str:
        out: list[str] = []
        t = threading.Thread(target=lambda: out.append(self.proc.stdout.readline()), daemon=True)
        t.start()
        t.join(timeout)
        if not out:
            self.close()
            raise RuntimeError(f"the emulator did not announce its ports within {timeout:.0f} s")
        return out[0]

    def _listen(self) -> None:
        for line in self.proc.stdout:
            try:
                said = json.loads(line)
            except ValueError:
                continue
            if not isinstance(said, dict):
                continue
            applied = said.get("applied")
            with self._told:
                if isinstance(applied, int):
                    self._applied = max(self._applied, applied)
                    if len(said) > 1:  # an answer beside the number: kept for the one who asked
                        self._answers[applied] = said
                self.stats = said.get("stats", self.stats)
                self._told.notify_all()
        with self._told:  # the child is gone: nobody waits for it any longer
            self._applied = self._sent = max(self._applied, self._sent)
            self._told.notify_all()

    def _send(self, cmd: dict) -> dict:
        """Send a command and wait until the child has applied it: a fault is in the plant before
        the trial goes on (a push sent and not yet taken would be a push the log never saw). The
        child's answer, where the command asked something ({} otherwise, or once the child is gone)."""
        if self.proc.poll() is not None:
            return {}
        with self._told:
            self._sent += 1
            seq = self._sent
        try:
            self.proc.stdin.write(json.dumps(cmd | {"seq": seq}) + "\n")
            self.proc.stdin.flush()
        except (OSError, ValueError):
            return {}  # the child is gone; the trial learns it from its bus
        with self._told:
            if not self._told.wait_for(lambda: self._applied >= seq, COMMAND_TIMEOUT_S):
                raise BackendSetupError(f"the emulated rig did not apply {json.dumps(cmd)} within "
                                        f"{COMMAND_TIMEOUT_S:g} s")
            return self._answers.pop(seq, {})

    def unplug(self) -> None:
        self.proc.send_signal(signal.SIGUSR1)

    def replug(self) -> None:
        self.proc.send_signal(signal.SIGUSR2)

    def close(self) -> None:
        if getattr(self, "ports", None) is not None:
            serving.detach(self.ports.dynamixel_port)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        listener = getattr(self, "_listener", None)
        if listener is not None:
            listener.join(5)  # the child has exited: its last line (the counters) is read
        for stream in (self.proc.stdin, self.proc.stdout, self._stderr):
            try:
                stream.close()
            except (OSError, ValueError, AttributeError):
                pass

    def retarget(self, config: TrialConfig) -> TrialConfig:
        return retarget(config, self.ports)

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _die_with_parent(parent: int) -> None:
    """In the child before exec: killed by the kernel the moment ``parent`` dies (Linux prctl
    PR_SET_PDEATHSIG).

    SIGKILL, not SIGTERM: an orphaned rig has no one to answer and nothing to save, and a
    graceful stop needs its own code to run (the handler, then joining two serving threads, up
    to 5 s each, that a starved machine keeps busy catching up the physics): an emulator could
    outlive its killed trial by over 10 s. The kernel's SIGKILL needs none of it."""
    if sys.platform.startswith("linux"):

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
        if os.getppid() != parent:  # the parent died before prctl took effect (adopted by init
            os._exit(ExitCode.ORPHANED)  # or by a subreaper, whichever pid that is)


#: The clocks an emulated rig can keep: ``realtime`` (the wall clock) or ``virtual``.
CLOCKS = ("realtime", "virtual")


class VirtualRig:
    """The emulated rig of one command on a fresh :class:`~drivers.clock.VirtualClock`, in this
    process: what :class:`EmulatorProcess` is in real time (``retarget``, ``close``, ``stats``)."""

    def __init__(self, config: TrialConfig) -> None:
        self.clock = VirtualClock()
        self.rig = EmulatedRig(config, clock=self.clock).start()
        self.ports = self.rig.ports
        self.faults = self.rig.hooks
        #: The bus's counters, read when the rig has stopped.
        self.stats: dict = {}

    def retarget(self, config: TrialConfig) -> TrialConfig:
        return retarget(config, self.ports)

    def close(self) -> None:
        if self.rig is not None:
            with self.rig.bus.lock:
                self.stats = dataclasses.asdict(self.rig.bus.stats)
            self.rig.close()
            self.rig = None

    def __enter__(self) -> "VirtualRig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def clock_of(config: TrialConfig, clock: Optional[str]) -> str:
    """The clock an emulated rig keeps: the command line's ``--clock``, else the config's
    ``emulator.clock``; an unknown one is refused."""
    chosen = clock if clock is not None else config.emulator.clock
    if chosen not in CLOCKS:
        raise ValueError(f"--clock {chosen}: choose from {', '.join(CLOCKS)}")
    return chosen


def open_emulated_rig(config_path: Path, config: TrialConfig, clock: Optional[str] = None):
    """The config's emulated rig for one command: in real time a child process
    (:class:`EmulatorProcess`, its own core), on the virtual clock this process's
    (:class:`VirtualRig`). Both have ``retarget``, ``close`` and ``stats``."""
    if clock_of(config, clock) == "virtual":
        return VirtualRig(config)
    return EmulatorProcess(config_path)


def retarget(config: TrialConfig, ports: RigPorts) -> TrialConfig:
    """The config with its ports pointed at an emulated rig."""
    b = config.backend
    u = b.ultrasonic
    if is_virtual_port(ports.dynamixel_port):  # on a virtual clock nothing answers late: the
        backend = b.model_copy(update={          # config's own timeouts, as at the rig
            "port": ports.dynamixel_port,
            "ultrasonic": u.model_copy(update={"port": ports.ultrasonic_port}) if u else None})
        return config.model_copy(update={"backend": backend})
    backend = b.model_copy(update={
        "port": ports.dynamixel_port,
        # The emulator is a Python process sharing the CPU: its answers can come
        # milliseconds late where a servo's come in microseconds.
        "timeout_ms": max(b.timeout_ms or 0.0, EMULATOR_TIMEOUT_MS),
        "ultrasonic": u.model_copy(update={
            "port": ports.ultrasonic_port,
            "stale_after_s": max(u.stale_after_s or 0.0, EMULATOR_STALE_S)}) if u else None})
    return config.model_copy(update={"backend": backend})
