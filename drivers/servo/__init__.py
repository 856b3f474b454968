"""The servo model shared by the emulated rig and the simulator: X-series firmware, motor and
gearbox, vectorised over joints."""

from drivers.servo.model import FIRMWARE_PERIOD_S, ServoArray, ServoParams, friction_torque

__all__ = ["FIRMWARE_PERIOD_S", "ServoArray", "ServoParams", "friction_torque"]
