"""What the Dynamixel backend is told: the port, each servo and the train's ultrasonic sensor.

Plain settings, checked by :class:`~drivers.dynamixel.backend.DynamixelActuators` at start-up
(the bench's config layer builds them from a validated config).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Literal, Optional, Sequence

from drivers.dynamixel.units import CENTER_TICK

__all__ = ["DynamixelSettings", "ServoSettings", "UltrasonicSettings"]


@dataclass(frozen=True)
class ServoSettings:
    joint: str
    id: int
    model: int  # model number, e.g. 1020 for XM430-W350
    mode: str = "extended_position"
    ratio: float = 1.0  # joint units per shaft radian
    offset: float = 0.0  # joint value at shaft angle 0 (the centre tick)
    current_limit_a: Optional[float] = None
    zero_tick: int = CENTER_TICK
    gains: tuple[Optional[int], Optional[int], Optional[int]] = (None, None, None)  # P, I, D


@dataclass(frozen=True)
class UltrasonicSettings:
    port: str
    joint: str
    to_joint: Callable[[float], float]  # measured distance (m) -> joint value
    baud: int = 9600
    median_window: int = 5
    stale_after_s: Optional[float] = None  # default: from the nominal rate
    rate_hz: float = 6.0  # the sensor's nominal reading rate
    range_m: tuple[float, float] = (0.3, 5.0)
    no_target_m: float = 5.0
    loop_gain: float = 0.5  # 1/s: how fast the host loop removes train error
    max_correction: float = 0.05  # joint units


@dataclass
class DynamixelSettings:
    port: str
    baud: int
    servos: Sequence[ServoSettings]
    joint_names: Sequence[str]
    lower: Sequence[float]
    upper: Sequence[float]
    velocity: Sequence[float]
    effort: Sequence[float]
    return_delay_us: int = 0
    fast_sync_read: bool = True
    retries: int = 3
    timeout_s: Optional[float] = None  # per cycle transaction; default: 3 × wire time + latency
    safe_stop: Literal["torque_off", "hold"] = "torque_off"
    reboot_on_hardware_error: bool = False
    ultrasonic: Optional[UltrasonicSettings] = None
    warnings: list[str] = field(default_factory=list)
    limit_tolerance: float = 0.01  # a joint read further beyond a limit at enable: torque refused
    # enable waits until every servo with an integrator is within settle_ticks of its goal and
    # none moved over a tick for settle_still_s (at most settle_timeout_s; 0: no wait)
    settle_ticks: int = 2
    settle_still_s: float = 0.1
    settle_timeout_s: float = 10.0
