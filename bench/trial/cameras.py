"""A trial's cameras: opened with the backend, a capture each time the robot has settled (at the
entry, as the insertion starts; at the end of the insertion, as the retraction starts, or when the
plan ends there), measured once the actuators are safe, and kept in the record.

A camera that cannot be opened or read never stops the trial: the record says why there is no
measurement, and a trial judged by the cameras then fails on it (never on a guessed tip).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Callable, Optional

from bench.cameras.rig import TrialCameras, camera_source
from bench.core.log import TrialLog
from bench.core.outcome import SETTLED_WINDOW_S
from bench.core.result import PreparedTrial
from bench.rig.serving import rig_kind
import numpy as np

from drivers import Actuators, ActuatorsWrapper, JointState
from drivers.camera import CameraError
from drivers.errors import BenchError
from drivers.capabilities import EmulatorHooks, TruePosition, find_capability

__all__ = ["BackendReading", "TrialCaptures", "open_cameras"]

#: The capture taken as each segment starts: the robot has settled at the end of the one before.
CAPTURE_AT = {"insert": "entry", "retract": "insert"}


class BackendReading(ActuatorsWrapper):
    """Keeps the backend's own last reading, beneath the fault wrappers (a recorder, not a fault).

    The rendered cameras of an emulated rig show its plant's joints where they truly are (the
    rig's ``true_position``, asked of its process); a backend on a rig that cannot say has them
    where its own servos read them (to a tick; the median of the settle's last readings), which
    the bench's encoder faults do not touch, but a mechanical zero error would."""

    def __init__(self, actuators: Actuators) -> None:
        super().__init__(actuators)
        self._recent: deque = deque(maxlen=256)

    def read(self) -> JointState:
        st = self.actuators.read()
        self._recent.append((float(st.time), np.array(st.position, dtype=float)))
        return st

    def last(self) -> np.ndarray:
        """The median reading over the last ``SETTLED_WINDOW_S`` (a sensed joint's reading is noisy:
        the train's, through the ultrasonic sensor), as the encoders' settled placement is read."""
        if not self._recent:
            raise CameraError("the backend has not been read yet")
        t_end = self._recent[-1][0]
        kept = [q for t, q in self._recent if t >= t_end - SETTLED_WINDOW_S - 1e-9]
        return np.median(np.array(kept), axis=0)


class TrialCaptures:
    """The captures of one trial (nothing at all when the config has no cameras)."""

    def __init__(self, cameras: Optional[TrialCameras], log: TrialLog, problem: str = "") -> None:
        self.cameras, self.log, self.problem = cameras, log, problem
        self.taken: list[str] = []

    def phase(self, inner: Optional[Callable[[str], None]]) -> Optional[Callable[[str], None]]:
        """The runner's phase hook, a capture first where one is due."""
        if self.cameras is None:
            return inner

        def told(name: str) -> None:
            if name in CAPTURE_AT:
                self._capture(CAPTURE_AT[name])
            if inner is not None:
                inner(name)
        return told

    def settled(self, log: TrialLog) -> None:
        """The plan has ended: if it ended on the insertion, that is the insertion's capture."""
        if self.cameras is not None and log.segment_names and log.segment_names[-1] == "insert":
            self._capture("insert")

    def _capture(self, label: str) -> None:
        if label in self.taken:
            return
        self.taken.append(label)
        try:
            self.cameras.capture(label, float(self.log.time[-1]) if len(self.log) else 0.0)
        except CameraError as e:
            self.problem = str(e)

    def finish(self, run_dir: Path) -> None:
        """Measure the captures and keep them in the record (``log.metadata["camera"]``)."""
        if self.cameras is None:
            if self.problem:
                self.log.metadata["camera"] = {"problem": self.problem, "captures": {}}
            return
        try:
            self.log.metadata["camera"] = self.cameras.finish(run_dir) | (
                {"problem": self.problem} if self.problem else {})
        except CameraError as e:
            self.log.metadata["camera"] = {"problem": str(e), "captures": {}}
        finally:
            self.cameras.close()


def open_cameras(prep: PreparedTrial, act: Actuators, log: TrialLog,
                 reading: Optional[BackendReading] = None) -> TrialCaptures:
    """The config's cameras on this backend: rendered where its true joints are (the sim's
    ``TruePosition``, an emulated rig's plant; else the servos' own reading, ``reading``), or the
    devices (real rig)."""
    cfg = prep.config
    if cfg.cameras is None:
        return TrialCaptures(None, log)
    source = camera_source(cfg.cameras, log.metadata.get("rig") or rig_kind(cfg))
    truth = find_capability(act.unwrapped, TruePosition)
    hooks = find_capability(act.unwrapped, EmulatorHooks)
    rig_truth = getattr(hooks.fault_hooks, "true_position", None) if hooks is not None else None
    if truth is not None:
        where = truth.true_position
    elif rig_truth is not None:  # an emulated rig: its plant, as a camera on it sees it
        def where() -> np.ndarray:
            try:
                return rig_truth()
            except BenchError as e:  # a camera that cannot see never stops the trial
                raise CameraError(str(e)) from e
    else:
        where = None if reading is None else reading.last
    try:
        calibration = None if cfg.cameras.calibration is None else cfg.resolve(cfg.cameras.calibration)
        cams = TrialCameras(cfg.cameras, source, cfg.robot_urdf, prep.robot.joint_names,
                            cfg.resolve(cfg.urdf_dir), where, seed=cfg.seed, calibration=calibration)
    except CameraError as e:
        return TrialCaptures(None, log, f"the cameras could not be opened: {e}")
    return TrialCaptures(cams, log)
