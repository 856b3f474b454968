"""The servo core every simulator of a servo composes: X-series firmware and motor (model.py, the
fused loop in fast.py), every friction law (friction.py) and the one joint integrator (joints.py),
vectorised over joints."""

from drivers.servo.friction import friction_torque
from drivers.servo.model import FIRMWARE_PERIOD_S, ServoArray, ServoParams

__all__ = ["FIRMWARE_PERIOD_S", "ServoArray", "ServoParams", "friction_torque"]
