"""A real camera through OpenCV's ``VideoCapture``: a device index (``/dev/videoN``) or a URL (an IP
camera's stream, MJPEG over HTTP, RTSP), its resolution and exposure set from the config.

The frame returned is the newest: frames a stream buffered while nobody read are dropped first
(``flush`` grabs), so a frame taken when the robot has settled shows it settled.
"""

from __future__ import annotations

import time
from typing import Optional, Union

import numpy as np

from drivers.camera import CameraError, Frame, Intrinsics

__all__ = ["CaptureCamera"]


class CaptureCamera:
    """``cv2.VideoCapture(source)``; refuses a camera that does not open or gives frames of
    another size than its intrinsics say."""

    def __init__(self, name: str, source: Union[int, str], intrinsics: Intrinsics,
                 exposure: Optional[float] = None, flush: int = 2, timeout_s: float = 10.0) -> None:
        import cv2  # heavy: OpenCV, only when a camera is used

        self.name, self.intrinsics, self.flush = name, intrinsics, int(flush)
        self._cv2 = cv2
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(timeout_s * 1000),
                  cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(timeout_s * 1000)]
        backend = cv2.CAP_FFMPEG if isinstance(source, str) else cv2.CAP_ANY
        self._cap = cv2.VideoCapture(source, backend, params)
        if not self._cap.isOpened():
            raise CameraError(f"camera {name!r}: could not open {source!r}")
        if isinstance(source, int):  # a device takes its size and exposure; a stream has its own
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, intrinsics.width)
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, intrinsics.height)
            if exposure is not None:
                self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # manual (V4L2's value)
                self._cap.set(cv2.CAP_PROP_EXPOSURE, float(exposure))
        self.source = source

    def grab(self) -> Frame:
        for _ in range(self.flush):
            self._cap.grab()
        ok, image = self._cap.read()
        t = time.monotonic()
        if not ok or image is None:
            raise CameraError(f"camera {self.name!r}: no frame from {self.source!r}")
        h, w = image.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise CameraError(f"camera {self.name!r}: frames are {w}x{h}, its calibration is for "
                              f"{self.intrinsics.width}x{self.intrinsics.height}")
        return Frame(self.name, np.ascontiguousarray(image), t)

    def close(self) -> None:
        self._cap.release()
