"""Emulated hardware on pseudo-terminals: a DYNAMIXEL X-series bus and an ultrasonic sensor.

Everything here runs without hardware: the host-side drivers open the pty
path an emulator exposes, exactly as they would open a U2D2 or a USB-serial
sensor, so the bench's Dynamixel backend is tested byte for byte.
"""

from drivers.dynamixel.control_table import (
    XC430_W150,
    XL430_W250,
    XM430_W350,
    XM540_W270,
    Access,
    Area,
    ControlTable,
    ModelSpec,
    MotorSpec,
    Register,
    model_spec,
    supported_models,
)
from drivers.emulator.bus import BusFaults, BusStats, DynamixelBusEmulator
from drivers.emulator.plant import InertiaPlant, Plant
from drivers.emulator.servo import ServoModel
from drivers.emulator.ultrasonic import UltrasonicEmulator, standoff_distance
from drivers.emulator.virtual import VirtualBusEmulator, VirtualUltrasonic

__all__ = [
    "Access",
    "Area",
    "BusFaults",
    "BusStats",
    "ControlTable",
    "DynamixelBusEmulator",
    "InertiaPlant",
    "ModelSpec",
    "MotorSpec",
    "Plant",
    "Register",
    "ServoModel",
    "UltrasonicEmulator",
    "VirtualBusEmulator",
    "VirtualUltrasonic",
    "XC430_W150",
    "XL430_W250",
    "XM430_W350",
    "XM540_W270",
    "model_spec",
    "standoff_distance",
    "supported_models",
]
