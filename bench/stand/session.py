"""A stand config's excitation run on the stand (or its emulation), each run's log written in
BAM's format into one run directory; the servo is left torque-off whatever happens."""

from __future__ import annotations

import signal
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Optional

from bench.stand.config import StandConfig
from bench.stand.emulated import EmulatedStand
from bench.stand.record import record_stand_log, write_stand_log
from drivers.clock import WALL, Clock, VirtualClock
from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.stand import StandServo

__all__ = ["emulated_clock", "paced", "record_session", "serve_stand"]


def paced(clock: Clock) -> Callable[[float], float]:
    """A recording's wait on ``clock``: to ``dt`` past its last tick (not past now: no drift); it
    says how long it has run. The wall clock at the stand; a virtual one on an emulated stand
    whose wire takes time too."""
    start = clock.now()
    due = [start]

    def wait(dt: float) -> float:
        if dt > 0:
            due[0] += dt
            clock.sleep_until(due[0])
        return clock.now() - start
    return wait


def emulated_clock(stand: EmulatedStand) -> Callable[[float], float]:
    """A recording's wait on the emulated stand: the physics advanced by ``dt``, its time returned
    (no wall clock: the stand runs as fast as the machine allows)."""
    clock = [0.0]

    def wait(dt: float) -> float:
        if dt > 0:
            stand.advance(dt)
            clock[0] += dt
        return clock[0]
    return wait


def _run_all(config: StandConfig, bus: ServoBus, wait: Callable[[float], float], run_dir: Path,
             progress: Optional[Callable[[int, int], None]]) -> list[Path]:
    servo = StandServo(bus, config.servo_id)
    paths = []
    try:
        for i, run in enumerate(config.runs):
            log = record_stand_log(servo, run.trajectory, kp=run.kp, mass=config.mass_kg,
                                   length=config.length_m, vin=config.vin, wait=wait, period_s=config.period_s,
                                   motor=config.motor)
            paths.append(write_stand_log(log, run_dir / f"{i + 1:02d}_{run.trajectory}_kp{run.kp}.json"))
            if progress:
                progress(i + 1, len(config.runs))
    finally:
        servo.torque(False)
    return paths


def record_session(config: StandConfig, out: Path, *, emulate: bool = False, clock: Optional[str] = None,
                   progress: Optional[Callable[[int, int], None]] = None) -> tuple[Path, list[Path]]:
    """Run every run of ``config``; (the run directory, the logs written). ``clock="virtual"``: the
    emulated stand on a virtual clock (its logs the same bit for bit on any machine)."""
    stem = Path(out) / f"{config.name}-{datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%S')}"
    run_dir, n = stem, 1
    while run_dir.exists():  # two sessions within a second
        n += 1
        run_dir = stem.with_name(f"{stem.name}-{n}")
    run_dir.mkdir(parents=True)
    if emulate:
        vc = VirtualClock() if clock == "virtual" else None
        physics = config.emulator.physics.model_dump(exclude_none=True)
        with EmulatedStand(physics, mass=config.mass_kg, length=config.length_m,
                           supply_v=config.emulator.supply_v, motor=config.motor, servo_id=config.servo_id,
                           source_ohm=config.emulator.source_ohm, clock=vc) as stand, \
                ServoBus(stand.port, config.baud, **({} if vc else {"tries": 30})) as bus:
            # (stepped: more tries than a real bus needs, a busy machine may starve the emulator's thread)
            wait = paced(vc) if vc else emulated_clock(stand)
            return run_dir, _run_all(config, bus, wait, run_dir, progress)
    with ServoBus(config.port, config.baud) as bus:
        return run_dir, _run_all(config, bus, paced(WALL), run_dir, progress)


def serve_stand(config: StandConfig, announce: Callable[[str], None]) -> None:
    """The config's emulated stand on a pseudo-terminal in real time, until SIGINT or SIGTERM: for
    a recorder of one's own (BAM's, at the config's baud) to talk to."""
    stop = threading.Event()
    physics = config.emulator.physics.model_dump(exclude_none=True)
    with EmulatedStand(physics, mass=config.mass_kg, length=config.length_m, supply_v=config.emulator.supply_v,
                       motor=config.motor, servo_id=config.servo_id, source_ohm=config.emulator.source_ohm,
                       realtime=True) as stand:
        previous = {sig: signal.signal(sig, lambda *a: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
        announce(stand.port)
        try:
            while not stop.wait(0.2):
                pass
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
