"""Fault injection: wrappers that make any ``Actuators`` behave like imperfect hardware.

Every fault is an ``Actuators`` around an ``Actuators`` (``gymnasium.Wrapper``
style), one behaviour per class, so faults stack and run unchanged on the
simulator and on the real or emulated servo bus. Trial configs declare them
by name (see :mod:`bench.faults.spec` for the YAML form and :data:`FAULTS`
for every fault and its parameters).

Modules: ``base`` (the fault base, on :class:`drivers.ActuatorsWrapper`), ``tolerance`` (deadband, bias,
backlash, quantisation, noise), ``torque`` (torque limit), ``comms``
(dropped, late and corrupted status packets), ``ultrasonic`` (the train's
distance sensor), ``physical`` (a contact pushing on a joint, a friction that
drifts, a joint that stops following), ``spec`` (parsing and stacking).
"""

from bench.faults.base import FaultWrapper, joint_kinds
from bench.faults.comms import DroppedStatus, EmulatorStatusFault, LateStatus
from bench.faults.physical import Contact, FrictionDrift, Stuck
from bench.faults.spec import (
    FAULTS,
    FaultDef,
    FaultSpec,
    Param,
    apply_faults,
    fault_generator,
    fault_names,
    parse_fault,
    parse_faults,
)
from bench.faults.tolerance import Backlash, Bias, Deadband, Noise, Quantisation
from bench.faults.torque import TorqueLimit
from bench.faults.ultrasonic import UltrasonicDropout, UltrasonicNoise, UltrasonicStuck

__all__ = [
    "FAULTS",
    "Backlash",
    "Bias",
    "Contact",
    "Deadband",
    "DroppedStatus",
    "EmulatorStatusFault",
    "FaultDef",
    "FaultSpec",
    "FaultWrapper",
    "FrictionDrift",
    "LateStatus",
    "Noise",
    "Param",
    "Quantisation",
    "Stuck",
    "TorqueLimit",
    "UltrasonicDropout",
    "UltrasonicNoise",
    "UltrasonicStuck",
    "apply_faults",
    "fault_generator",
    "fault_names",
    "joint_kinds",
    "parse_fault",
    "parse_faults",
]
