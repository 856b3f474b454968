"""The cameras a trial config asks for, and a trial's captures measured.

``source: auto`` renders the scene (drivers/camera/emulated) on the sim and the emulated rig and
opens the devices (drivers/camera/capture) on the real rig. A rendered camera shows where the
joints truly are (the backend's ``TruePosition``, not its encoders), as a camera on the rig would.

A capture is taken when the robot has settled (:meth:`TrialCameras.capture`): a real camera's
frame is grabbed then, in a thread of its own so the control loop keeps its time; an emulated
camera notes the true joints then and renders them once the motion is over (:meth:`finish`), so
the loop is never held up by the renderer. Frames are kept in the run directory (JPEG).
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.cameras.bedmarker import MOVED_PX, bed_marker_decal, marker_offset_px
from bench.cameras.calibrate import read_calibration
from bench.cameras.fiducial import emulated_fiducials, tip_in_holder
from bench.cameras.measure import Measurement, View, find_balls, measure_tip
from bench.config.cameras import CameraConfig, CamerasConfig
from bench.scene.room import default_scene
from drivers.camera import CameraError, Frame, Intrinsics, look_at
from drivers.camera.capture import CaptureCamera
from drivers.camera.emulated import EmulatedCamera, RenderedScene

__all__ = ["TrialCameras", "camera_source", "frame_file", "view_of"]

#: The frames are kept as JPEG (as an MJPEG camera sends them); measured before, from memory.
JPEG_QUALITY = 95


def view_of(cam: CameraConfig) -> View:
    """A configured camera as the metrology knows it (SI)."""
    i = cam.intrinsics
    w, h = cam.resolution
    intr = Intrinsics(w, h, i.fx_px, i.fy_px, i.cx_px, i.cy_px, tuple(i.distortion))
    pose = look_at(np.asarray(cam.pose.position_mm) / 1e3, np.asarray(cam.pose.look_at_mm) / 1e3)
    return View(cam.name, intr, pose)


def camera_source(cameras: CamerasConfig, rig: str) -> str:
    """"emulated" or "capture": what ``source: auto`` means on a sim, an emulated or a real rig."""
    if cameras.source != "auto":
        return cameras.source
    return "capture" if rig == "real" else "emulated"


def frame_file(label: str, camera: str) -> str:
    """The file a capture's frame is kept in, in the run directory."""
    return f"camera-{label}-{camera}.jpg"


class TrialCameras:
    """The two cameras of a trial and its captures (``entry``, ``insert``).

    ``truth`` (emulated cameras): the joints' true positions now; ``seed``: the noise's."""

    def __init__(self, cameras: CamerasConfig, source: str, urdf: Path, joint_names, urdf_dir: Path,
                 truth: Optional[Callable[[], np.ndarray]] = None, seed: int = 0,
                 calibration: Optional[Path] = None) -> None:
        self.config, self.source = cameras, source
        #: The cameras as configured (an emulated camera renders from there) and as the metrology
        #: knows them: from the calibration file when the config names one.
        self.true_views = [view_of(c) for c in cameras.views]
        self.views = list(self.true_views)
        if calibration is not None:
            calibrated = read_calibration(calibration)
            missing = [v.name for v in self.views if v.name not in calibrated]
            if missing:
                raise CameraError(f"{calibration}: no calibration for camera(s) {missing}")
            self.views = [calibrated[v.name] for v in self.views]
        self._pending: dict[str, list] = {}
        self._scene = None
        self._cams: list = []
        self._threads: Optional[ThreadPoolExecutor] = None
        self.cpu_s = 0.0
        self.wall_s = 0.0
        began = time.perf_counter(), time.process_time()
        if source == "emulated":
            if truth is None:
                raise CameraError("emulated cameras render where the joints truly are, and this "
                                  "backend does not say (no TruePosition)")
            self._truth = truth
            self._scene = RenderedScene(urdf, joint_names, default_scene(urdf_dir), emulated_fiducials(),
                                        [bed_marker_decal()])
            self._state = {"q": None, "t": 0.0}
            for k, (c, v) in enumerate(zip(cameras.views, self.true_views)):
                self._cams.append(EmulatedCamera(
                    c.name, self._scene, lambda: (self._state["q"], self._state["t"]), v.intrinsics,
                    v.pose, noise=c.emulated.noise, blur_px=c.emulated.blur_px, seed=seed * 16 + k))
        else:
            try:
                for c, v in zip(cameras.views, self.views):
                    self._cams.append(CaptureCamera(c.name, c.device, v.intrinsics, c.exposure))
            except CameraError:
                self.close()
                raise
            self._threads = ThreadPoolExecutor(max_workers=len(self._cams))
        self._spent(began)

    @property
    def cameras(self) -> list:
        return list(self._cams)

    def park(self) -> None:
        """Emulated cameras: pose the scene where ``truth`` says (the robot parked), now."""
        self._state["q"], self._state["t"] = np.array(self._truth(), dtype=float), 0.0
        self._scene.pose(self._state["q"])

    def capture(self, label: str, t: float) -> None:
        """Take ``label``'s frames now (a real camera) or note what they will show (emulated)."""
        began = time.perf_counter(), time.process_time()
        if self._scene is not None:
            self._pending[label] = [np.array(self._truth(), dtype=float), float(t)]
        else:
            self._pending[label] = [self._threads.submit(c.grab) for c in self._cams]
        self._spent(began)

    def _spent(self, began: tuple[float, float]) -> None:
        self.wall_s += time.perf_counter() - began[0]
        self.cpu_s += time.process_time() - began[1]

    def _frames(self, label: str) -> list[Frame]:
        got = self._pending[label]
        if self._scene is not None:
            self._state["q"], self._state["t"] = got
            return [c.grab() for c in self._cams]
        return [f.result() if isinstance(f, Future) else f for f in got]

    def finish(self, run_dir: Path) -> dict:
        """Every capture's frames (rendered now, for emulated cameras) saved and measured: what the
        trial's record keeps (``log.metadata["camera"]``)."""
        import cv2  # heavy: OpenCV, only when frames are measured

        began = time.perf_counter(), time.process_time()
        tip_local, axis_local = tip_in_holder()
        captures = {}
        for label in list(self._pending):
            entry: dict = {}
            try:
                frames = self._frames(label)
            except CameraError as e:
                captures[label] = {"problem": str(e)}
                continue
            found, moved = [], []
            for fr, view in zip(frames, self.views):
                name = frame_file(label, fr.camera)
                cv2.imwrite(str(Path(run_dir) / name), fr.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                entry.setdefault("frames", {})[fr.camera] = name
                found.append(find_balls(fr.image))
                off = marker_offset_px(view, fr.image)
                entry.setdefault("bed_marker_px", {})[fr.camera] = None if off is None else round(off, 3)
                if off is not None and off > MOVED_PX:
                    moved.append(f"{fr.camera} ({off:.1f} px)")
            m = measure_tip(self.views, found, tip_local, axis_local, self.config.pixel_sigma)
            if moved:  # its frames are not where the calibration says they are taken from: no tip
                m = Measurement(pixels=m.pixels, problem=(
                    f"camera moved since its calibration: the bed marker is off where the calibration "
                    f"puts it in {', '.join(moved)}, more than {MOVED_PX:g} px; calibrate again"))
            entry.update({"time_s": frames[0].time, "problem": m.problem, "balls": m.balls,
                          "pixels": m.pixels})
            if m.ok:
                entry.update({"tip_m": m.tip.tolist(), "direction": m.direction.tolist(),
                              "covariance_m2": m.covariance.tolist(), "fit_rms_m": m.fit_rms})
            captures[label] = entry
        self._spent(began)
        return {"source": self.source, "views": [v.name for v in self.views],
                "pixel_sigma": self.config.pixel_sigma, "captures": captures,
                "wall_s": round(self.wall_s, 4), "cpu_s": round(self.cpu_s, 4)}

    def close(self) -> None:
        for c in self._cams:
            c.close()
        if self._threads is not None:
            self._threads.shutdown(wait=True)
        if self._scene is not None:
            self._scene.close()
