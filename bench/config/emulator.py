"""The emulated rig a trial config describes (``emulator:``): its physics, its sensor, its clock."""

from __future__ import annotations

from typing import Annotated, Literal, Optional

from pydantic import Field

from bench.config.base import Strict
from bench.config.servo_model import ServoPhysics, physics_for

__all__ = ["SEED_MAX", "EmulatorConfig"]

SEED_MAX = 2**63 - 1  # campaigns derive 63-bit trial seeds


class EmulatorConfig(Strict):
    """The emulated rig used by `--emulate` and `hilbench emulate` (ignored on real hardware)."""

    physics_hz: float = Field(default=1000.0, ge=100, le=10_000,
                              description="the emulated robot's physics steps per second")
    wire_timing: bool = Field(default=False,
                              description="answer after the real wire time at the bus's baud")
    ultrasonic_rate_hz: Optional[float] = Field(
        default=None, gt=0, le=100, description="default: the sensor's backend.ultrasonic.rate_hz")
    ultrasonic_noise_mm: float = Field(default=1.0, ge=0, le=100,
                                       description="standard deviation of each reading (mm)")
    ultrasonic_dropout: float = Field(default=0.0, ge=0, lt=1,
                                      description="probability that a reading is not sent")
    deadband_deg: float = Field(default=0.0, ge=0, le=10,
                                description="each servo's position deadband (°)")
    start_torque_on: bool = Field(default=True, description="servos hold their pose at power-up, "
                                                            "as a rig left enabled")
    joint_friction: dict[str, Annotated[float, Field(ge=0, le=100)]] = Field(
        default_factory=dict, max_length=32,
        description="extra Coulomb friction per joint (N·m or N), keyed by joint name")
    servo_physics: dict[str, ServoPhysics] = Field(
        default_factory=dict, max_length=32,
        description="hidden servo physics by joint name or `all` (a joint's own entry wins)")
    seed: int = Field(default=0, ge=0, le=SEED_MAX, description="seed of the emulator's noise")
    clock: Literal["realtime", "virtual"] = Field(default="realtime", description=(
        "realtime: the rig's pace; virtual: the same log bit for bit on any machine, faster (--clock)"))

    def physics_of(self, joint: str) -> dict[str, float]:
        """The hidden physics set for ``joint``: its own entry over ``all``, unset keys left out."""
        return physics_for(self.servo_physics, joint)
