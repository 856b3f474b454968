"""The fixed marker on the bed: an ArUco marker (4×4, id 7, 60 mm) taped flat on the bed beside the
phantom (X −30 to 30 mm, Y 250 to 310 mm), where the needle never goes. Found in each view at every
capture and compared with where the calibration puts it: a camera moved since its calibration (a
bumped tripod) shows it off by more than :data:`MOVED_PX`, and its frames are not measured (no tip
rather than a wrong one).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from bench.cameras.measure import View
from drivers.camera.emulated import Decal

__all__ = ["MARKER_CORNERS_M", "MOVED_PX", "bed_marker_decal", "marker_offset_px"]

MARKER_ID, MARKER_M = 7, 0.060
_ORIGIN = np.array([-0.03, 0.25, 0.0005])  # its top-left corner, just above the bed's top
_X, _Y = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])  # its rows along +Y, columns down +X
#: Its four corners (m, bed frame) in ArUco's order: top-left, top-right, bottom-right, bottom-left.
MARKER_CORNERS_M = np.array([_ORIGIN, _ORIGIN + MARKER_M * _X, _ORIGIN + MARKER_M * (_X + _Y),
                             _ORIGIN + MARKER_M * _Y])
#: Farther than this (pixels, mean over its corners) from where the calibration puts it: moved.
MOVED_PX = 2.0


def _dictionary():
    import cv2  # heavy: OpenCV, only when frames are measured

    return cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)


def bed_marker_decal() -> Decal:
    """The marker as the emulated cameras' room shows it (a white border of one cell around it)."""
    import cv2  # heavy: OpenCV, only when frames are measured

    cells, px = 6, 60  # 4 × 4 bits, the black border: 6 cells; and a white border of one more
    inner = cv2.aruco.generateImageMarker(_dictionary(), MARKER_ID, cells * px)
    art = cv2.copyMakeBorder(inner, px, px, px, px, cv2.BORDER_CONSTANT, value=255)
    edge = MARKER_M * (cells + 2) / cells
    origin = _ORIGIN - (edge - MARKER_M) / 2 * (_X + _Y)
    return Decal(art, tuple(origin), tuple(_X), tuple(_Y), edge)


def marker_offset_px(view: View, image: np.ndarray) -> Optional[float]:
    """How far (pixels, mean over its corners) the marker is from where ``view`` puts it; None
    when it is not seen."""
    import cv2  # heavy: OpenCV, only when frames are measured

    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(_dictionary(), params).detectMarkers(gray)
    if ids is None or MARKER_ID not in ids.ravel():
        return None
    seen = corners[list(ids.ravel()).index(MARKER_ID)].reshape(4, 2)
    expected, _ = cv2.projectPoints(MARKER_CORNERS_M, cv2.Rodrigues(view.pose.rotation)[0], view.pose.translation,
                                    view.intrinsics.matrix, view.intrinsics.dist)
    return float(np.mean(np.linalg.norm(seen - expected.reshape(4, 2), axis=1)))
