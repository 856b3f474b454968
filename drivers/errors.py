"""Every error the project raises on purpose, and the exit code each command ends with.

One light module (standard library only, no numpy) at the bottom of the layers, so
that every package — ``trajectories/`` too — derives its errors from
:class:`BenchError`, and the command line imports it eagerly and catches by class
without importing the library that raises. The classes keep their historical homes
as re-exports (``bench.config.models.ConfigError`` is this ``ConfigError``).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = [
    "ActuatorError",
    "BackendSetupError",
    "BenchError",
    "CampaignBusy",
    "CampaignDirError",
    "CameraError",
    "CampaignError",
    "CampaignSpecError",
    "CampaignStoreError",
    "CommandError",
    "CommunicationError",
    "CompareError",
    "ConfigError",
    "ContractViolation",
    "ExitCode",
    "GoalOutOfRange",
    "HardwareFault",
    "IdentifyError",
    "NotEnabledError",
    "PlanMismatchError",
    "RunDirError",
    "StaleReadingError",
    "StandError",
    "StuffingError",
    "TrajectoryError",
    "TrialError",
    "UnreachableError",
    "YamlRefused",
    "safe_stop_unconfirmed",
    "signal_exit_code",
]


class ExitCode(IntEnum):
    """How a ``hilbench`` command ends; the one table the code and the README follow."""

    #: It ran and passed (or the tool found nothing wrong).
    PASSED = 0
    #: It ran and failed: acceptance limits, an interlock, a lost bus, a rig problem found.
    FAILED = 1
    #: Refused before anything moved: bad config, unreachable target, missing port.
    REFUSED = 2
    #: Stopped, but the safe stop was not confirmed (a servo did not read back torque off,
    #: or the hold could not be commanded): the rig may still be powered; check it first.
    STOP_UNCONFIRMED = 3
    #: A child process whose parent is gone: a campaign's worker, the emulated rig (EX_SOFTWARE).
    ORPHANED = 70
    #: Stopped by signal N: exit SIGNAL_BASE + N (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP).
    SIGNAL_BASE = 128


def signal_exit_code(signum: int) -> int:
    """The exit code of a command stopped by signal ``signum``: 128 + N, as a shell reports it."""
    return int(ExitCode.SIGNAL_BASE) + int(signum)


def safe_stop_unconfirmed(report: str | None) -> bool:
    """Whether a backend's safe-stop report says the stop was not confirmed (torque off not
    read back from every servo, or a hold that could not be commanded)."""
    return bool(report) and "not confirmed" in str(report).lower()


class BenchError(Exception):
    """The root of every error the bench and its drivers raise on purpose.

    Like ``gymnasium.error.Error``: one ``except BenchError`` handles every
    refusal and failure the project itself reports, and nothing else.
    """


# -- actuators (drivers/) ------------------------------------------------------------------


class ActuatorError(BenchError, RuntimeError):
    """Base class of everything a backend raises on purpose."""


class CommandError(ActuatorError, ValueError):
    """A command the actuators refuse before it reaches the hardware (wrong shape, not finite)."""


class NotEnabledError(ActuatorError):
    """A command arrived while the actuators were not enabled."""


class BackendSetupError(ActuatorError):
    """The backend cannot start with the settings it was given (a port, a servo, a joint)."""


class CameraError(BenchError, RuntimeError):
    """A camera that cannot be opened, or a frame that cannot be had (drivers/camera)."""


class CommunicationError(ActuatorError):
    """The bus or a sensor stopped answering (after the allowed retries)."""


class StaleReadingError(CommunicationError):
    """No fresh reading within the staleness timeout (sensor silent or unplugged)."""


class HardwareFault(ActuatorError):
    """A servo reported a hardware error (overload, overheating, ...)."""

    def __init__(self, message: str, faults: dict[str, list[str]] | None = None) -> None:
        super().__init__(message)
        self.faults = faults or {}


class StuffingError(BenchError, ValueError):
    """A stuffed region holds ``FF FF FD`` not followed by the stuffing ``FD``."""


class ContractViolation(BenchError, AssertionError):
    """The actuators break a rule of the :class:`~drivers.Actuators` contract; the message says which."""


# -- motions (trajectories/) ---------------------------------------------------------------


class TrajectoryError(BenchError, ValueError):
    """The requested motion is invalid or cannot be achieved within the limits."""


# -- files and plans (bench/) --------------------------------------------------------------


class YamlRefused(BenchError, ValueError):
    """The file is not a config this bench will read; the message says why, in one line."""


class ConfigError(BenchError, ValueError):
    """A configuration file that cannot be used; the message names the field."""


class CampaignSpecError(ConfigError):
    """A campaign spec that cannot be used; the message names the field path."""


class UnreachableError(BenchError, ValueError):
    """The target cannot be reached; the message says why in mm and degrees.

    ``equations`` names the paper's equations behind the refusal (for a report or a
    developer); the message itself speaks to the person who wrote the target.
    """

    def __init__(self, message: str, equations: str = "") -> None:
        super().__init__(message)
        self.equations = equations


class TrialError(BenchError, RuntimeError):
    """The trial could not start; nothing moved."""


class PlanMismatchError(BenchError, ValueError):
    """Two logs that are not of the same robot and plan; the message names what differs."""


class CompareError(BenchError, RuntimeError):
    """The comparison could not run; nothing moved (or the rig was stopped safely)."""


class CampaignError(BenchError, RuntimeError):
    """A campaign that cannot be created, found or run; the message says what to do."""


class IdentifyError(BenchError, ValueError):
    """The logs cannot be identified together (missing, not the rig's, two different rigs)."""


class CampaignBusy(BenchError, RuntimeError):
    """Another process is running this campaign directory."""


class CampaignDirError(BenchError, ValueError):
    """A campaign directory that is not what the bench writes; the message says where and what."""


class CampaignStoreError(BenchError, RuntimeError):
    """A file that is not a campaign's database."""


class StandError(BenchError, ValueError):
    """A stand log or servo model that cannot be used (malformed, unknown motor, torque never on)."""


class RunDirError(BenchError, ValueError):
    """A run directory that is not what the bench writes; the message names the run and the fault."""


class GoalOutOfRange(CommandError):
    """A goal position beyond what the servo's mode or its joint's limits allow; never sent."""
