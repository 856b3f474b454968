"""Opening the rig for a lab tool: ports checked first, the trial's own driver, torque off on exit.

The tools drive the robot through the same :class:`~drivers.dynamixel.backend.DynamixelActuators`
a trial uses (same start-up checks, same joint mapping), built from the config
without planning a trial, and always with ``safe_stop: torque_off`` so that
leaving a tool — normally, by Ctrl-C or by error — leaves every servo limp.
"""

from __future__ import annotations

import os
from typing import Mapping, Optional

import serial

from bench.config.models import TrialConfig
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_dynamixel_backend
from drivers import Actuators, BackendSetupError
from drivers.dynamixel.bus import ServoBus, open_error
from drivers.link import port_usable

__all__ = ["LAB_RETRIES", "check_ports", "check_servos", "open_backend", "require_dynamixel"]

# Retries per bus transaction. A tool polls at 50 Hz, not a trial's control rate, so it
# rides out a busy host's pauses (up to about half a second) instead of stopping the
# technician's work; a trial's config allows at most 20.
LAB_RETRIES = 50


def require_dynamixel(config: TrialConfig, tool: str) -> None:
    """Refuse a config whose backend is not the Dynamixel servos (BackendSetupError)."""
    if config.backend.kind != "dynamixel":
        raise BackendSetupError(f"{config.source or config.name}: {tool} needs backend.kind: "
                                 f"dynamixel (this config is {config.backend.kind})")


def check_ports(config: TrialConfig, ultrasonic: bool = True) -> None:
    """Every port the config names exists and is readable and writable, or one line why not."""
    b = config.backend
    ports = [("servo", b.port)]
    if ultrasonic and b.ultrasonic is not None:
        ports.append(("ultrasonic", b.ultrasonic.port))
    for what, port in ports:
        if not port_usable(port):
            raise BackendSetupError(f"{what} {open_error(port)}")


def check_servos(bus: ServoBus, config: TrialConfig) -> None:
    """Every configured servo answers at the configured rate with the configured model."""
    b = config.backend
    for joint, sc in b.servos.items():
        reply = bus.ping(sc.id)
        if reply is None:
            raise BackendSetupError(
                f"servo ID {sc.id} ({joint}) did not answer on {b.port} at {b.baud} bps: "
                f"run `hilbench doctor {config.source or 'CONFIG'}`")
        if reply.model_name != sc.model:
            raise BackendSetupError(f"servo ID {sc.id} ({joint}) is {reply.model_name}, the "
                                     f"config says {sc.model}")


def open_backend(config: TrialConfig, *, ultrasonic: bool = True,
                 offsets: Optional[Mapping[str, float]] = None,
                 calibrated: bool = True, safe_stop: str = "torque_off") -> Actuators:
    """The config's Dynamixel backend, inactive, with torque off as its safe stop (or
    ``safe_stop="hold"``: the servos hold the measured position when it closes).

    ``ultrasonic=False`` reads the train from its servo's encoder; ``offsets``
    replace joint zero offsets (rad or m); ``calibrated=False`` ignores the
    config's calibration file.
    """


    require_dynamixel(config, "this tool")
    check_ports(config, ultrasonic)
    b = config.backend
    with ServoBus(b.port, b.baud) as bus:  # a missing servo named at once, before the driver's retries
        check_servos(bus, config)
    servos = {n: sc.model_copy(update={"offset": offsets[n]}) if offsets and n in offsets else sc
              for n, sc in b.servos.items()}
    backend = b.model_copy(update={"servos": servos, "safe_stop": safe_stop,
                                   "retries": max(b.retries, LAB_RETRIES),
                                   "ultrasonic": b.ultrasonic if ultrasonic else None})
    cfg = config.model_copy(update={"backend": backend,
                                    "calibration": config.calibration if calibrated else None})
    try:
        return make_dynamixel_backend(cfg, get_robot(cfg.robot))
    except (serial.SerialException, OSError) as e:
        raise BackendSetupError(f"servo {open_error(b.port, e)}") from None
