"""Calibrating the two cameras (``hilbench cameras calibrate CONFIG [--emulate]``).

1. **Intrinsics** from views of a ChArUco board held in front of each camera (OpenCV's
   ``CharucoDetector`` and ``calibrateCamera``): focal lengths, principal point, distortion, and
   the views' reprojection error.
2. **Pose** in the robot's (bed's) frame from the same board at a known place (:data:`PLACES`):
   flat on the phantom's top for a camera looking down, or standing on the bed in front of the
   phantom, facing its foot, for a camera looking along the bed; each camera takes the place it
   sees most squarely, with the robot parked out of the picture (``solvePnP``).

The result is a dated file (JSON) with each camera's intrinsics, pose and reprojection errors; a
camera whose error is beyond ``max_reprojection_px`` is refused and no file is written. With
``--emulate`` the views are the emulated cameras' (the board drawn into the rendered scene, through
the lens), and the file also says how far the calibration is from the cameras as configured.
"""

from __future__ import annotations

import datetime as dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from bench.cameras.measure import View
from drivers.camera import CameraError, CameraPose, Intrinsics

__all__ = ["PLACES", "CameraCalibration", "board_overlay", "calibrate_views", "charuco_board", "held_poses", "laid_pose",
           "place_for", "read_calibration",
           "write_calibration"]

#: The board: 7 × 5 squares of 25 mm, markers of 18 mm (ArUco 5×5, 100), 175 × 125 mm.
SQUARES, SQUARE_M, MARKER_M = (7, 5), 0.025, 0.018
#: Where the board is put for the poses (m, bed frame): its first corner, and its axes in the bed's
#: frame (the columns of board -> bed: x along its rows of squares, y down its columns, z into it).
#: "flat": on the phantom's top, face up; "upright": standing on the bed 15 mm in front of the
#: phantom (X = 90 mm), facing +X (the foot of the bed).
PLACES = {
    "flat": (np.array([-0.0625, 0.0125, 0.066]),
             np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])),
    "upright": (np.array([0.09, 0.0125, 0.125]),
                np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])),
}
#: Fewest ChArUco corners a view must show to be used.
MIN_CORNERS = 8


def charuco_board():
    import cv2  # heavy: OpenCV, only when cameras are calibrated

    return cv2.aruco.CharucoBoard(SQUARES, SQUARE_M, MARKER_M,
                                  cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100))


@dataclass
class CameraCalibration:
    """One camera's calibration: its intrinsics and pose, the reprojection errors (pixels, rms)
    of the intrinsics' views and of the pose's, and the views used."""

    name: str
    intrinsics: Intrinsics
    pose: CameraPose
    intrinsics_rms_px: float
    pose_rms_px: float
    views: int
    place: str

    def as_dict(self) -> dict:
        i = self.intrinsics
        return {"name": self.name, "resolution": [i.width, i.height],
                "intrinsics": {"fx_px": i.fx, "fy_px": i.fy, "cx_px": i.cx, "cy_px": i.cy,
                               "distortion": list(i.distortion)},
                "pose": {"rotation": self.pose.rotation.tolist(), "translation_m": self.pose.translation.tolist(),
                         "centre_mm": (self.pose.centre * 1e3).tolist()},
                "intrinsics_rms_px": self.intrinsics_rms_px, "pose_rms_px": self.pose_rms_px,
                "views": self.views, "board_place": self.place}


def _detect(board, image: np.ndarray):
    """The board's object points (m) and image points (px) seen in ``image``, or None."""
    import cv2  # heavy: OpenCV, only when cameras are calibrated

    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    obj, img = board.matchImagePoints(corners, ids)
    return obj.reshape(-1, 3).astype(np.float32), img.reshape(-1, 2).astype(np.float32)


def place_for(view: View) -> str:
    """The place (:data:`PLACES`) whose board faces a camera at ``view``'s pose most squarely."""
    def facing(place: str) -> float:
        origin, axes = PLACES[place]
        to_camera = view.pose.centre - origin
        return float(-axes[:, 2] @ to_camera / np.linalg.norm(to_camera))
    return max(PLACES, key=facing)


def calibrate_views(name: str, size: tuple[int, int], held: list[np.ndarray], laid: np.ndarray,
                    max_reprojection_px: float, place: str = "flat") -> CameraCalibration:
    """One camera from its frames: ``held`` (the board in front of it), ``laid`` (at ``place``)."""
    import cv2  # heavy: OpenCV, only when cameras are calibrated

    board = charuco_board()
    seen = [d for d in (_detect(board, im) for im in held) if d is not None]
    if len(seen) < 4:
        raise CameraError(f"camera {name!r}: the board was found in {len(seen)} of {len(held)} views; "
                          f"four are needed for its intrinsics")
    rms, K, dist, _, _ = cv2.calibrateCamera([o for o, _ in seen], [i for _, i in seen], size, None, None)
    if rms > max_reprojection_px:
        raise CameraError(f"camera {name!r}: the intrinsics reproject {rms:.2f} px rms, beyond "
                          f"{max_reprojection_px:g} px: refused (more views, a flatter board, focus)")
    on_bed = _detect(board, laid)
    if on_bed is None:
        raise CameraError(f"camera {name!r}: the board on the bed was not found (at least "
                          f"{MIN_CORNERS} corners are needed)")
    obj, img = on_bed
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CameraError(f"camera {name!r}: no pose from the board on the bed")
    back, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    pose_rms = float(np.sqrt(np.mean(np.sum((back.reshape(-1, 2) - img) ** 2, axis=1))))
    if pose_rms > max_reprojection_px:
        raise CameraError(f"camera {name!r}: the board on the bed reprojects {pose_rms:.2f} px rms, "
                          f"beyond {max_reprojection_px:g} px: refused")
    R_board = cv2.Rodrigues(rvec)[0]
    origin, axes = PLACES[place]
    # x_cam = R_board x_board + t; x_bed = B x_board + o  =>  x_cam = R_board B^T (x_bed - o) + t
    rot = R_board @ axes.T
    pose = CameraPose(rot, tvec.ravel() - rot @ origin)
    intr = Intrinsics(size[0], size[1], float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                      tuple(float(c) for c in dist.ravel()))
    return CameraCalibration(name, intr, pose, float(rms), pose_rms, len(seen), place)


def board_overlay(board_pose: CameraPose) -> Callable[[np.ndarray, Intrinsics, CameraPose], np.ndarray]:
    """An emulated camera's overlay: the board drawn where ``board_pose`` (board to camera) puts it."""
    import cv2  # heavy: OpenCV, only when cameras are calibrated

    px_per_m = 8000.0
    w, h = (round(n * SQUARE_M * px_per_m) for n in SQUARES)
    art = cv2.cvtColor(charuco_board().generateImage((w, h), marginSize=0), cv2.COLOR_GRAY2BGR)

    def draw(image: np.ndarray, intrinsics: Intrinsics, _pose: CameraPose) -> np.ndarray:
        # board pixel (u, v) is the point ((u + 0.5) / s, (v + 0.5) / s, 0) of the board
        A = np.array([[1 / px_per_m, 0, 0.5 / px_per_m], [0, 1 / px_per_m, 0.5 / px_per_m], [0, 0, 1]])
        Rt = np.column_stack([board_pose.rotation[:, 0], board_pose.rotation[:, 1], board_pose.translation])
        H = intrinsics.matrix @ Rt @ A
        size = (image.shape[1], image.shape[0])
        warped = cv2.warpPerspective(art, H, size, flags=cv2.INTER_AREA)
        mask = cv2.warpPerspective(np.full(art.shape[:2], 255, np.uint8), H, size, flags=cv2.INTER_LINEAR)
        a = (mask.astype(np.float32) / 255.0)[..., None]
        return (image * (1 - a) + warped * a).astype(np.uint8)
    return draw


def held_poses(view: View, n: int, rng: np.random.Generator) -> list[CameraPose]:
    """``n`` poses (board to camera) of the board held in front of a camera: 0.3-0.55 m away,
    across the image, tilted up to 35°."""
    import cv2  # heavy: OpenCV, only when cameras are calibrated

    size = np.array([SQUARES[0], SQUARES[1], 0.0]) * SQUARE_M
    out = []
    for k in range(n):
        z = rng.uniform(0.3, 0.55)
        u = rng.uniform(0.25, 0.75) * view.intrinsics.width
        v = rng.uniform(0.25, 0.75) * view.intrinsics.height
        centre = np.array([(u - view.intrinsics.cx) / view.intrinsics.fx * z,
                           (v - view.intrinsics.cy) / view.intrinsics.fy * z, z])
        tilt = np.radians([rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-20, 20)])
        R = cv2.Rodrigues(tilt)[0]
        out.append(CameraPose(R, centre - R @ (size / 2)))
    return out


def laid_pose(view: View, place: str) -> CameraPose:
    """The board at ``place``, seen from a camera at ``view``'s pose (board to camera)."""
    origin, axes = PLACES[place]
    return CameraPose(view.pose.rotation @ axes, view.pose.rotation @ origin + view.pose.translation)


def write_calibration(cals: list[CameraCalibration], folder: Path, config: str, emulated: bool,
                      truth: Optional[list[View]] = None, when: Optional[dt.datetime] = None) -> Path:
    """The dated calibration file (``cameras-YYYYmmdd-HHMMSS.json``) in ``folder``."""
    when = when or dt.datetime.now(dt.timezone.utc)
    record = {"kind": "cameras", "date": when.isoformat(timespec="seconds"), "config": config,
              "emulated": emulated, "board": {"squares": list(SQUARES), "square_m": SQUARE_M,
                                              "marker_m": MARKER_M, "dictionary": "DICT_5X5_100",
                                              "places": {k: {"origin_m": o.tolist(), "axes": a.tolist()}
                                                         for k, (o, a) in PLACES.items()}},
              "cameras": [c.as_dict() for c in cals]}
    if truth is not None:  # the emulation knows where its cameras are: how far the calibration is
        for c, v in zip(record["cameras"], truth):
            cal = next(x for x in cals if x.name == v.name)
            d_rot = cal.pose.rotation @ v.pose.rotation.T
            c["against_config"] = {
                "position_mm": float(np.linalg.norm(cal.pose.centre - v.pose.centre) * 1e3),
                "angle_deg": float(np.degrees(np.arccos(np.clip((np.trace(d_rot) - 1) / 2, -1, 1)))),
                "focal_px": float(abs(cal.intrinsics.fx - v.intrinsics.fx))}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"cameras-{when.strftime('%Y%m%d-%H%M%S')}.json"
    path.write_text(json.dumps(record, indent=2) + "\n")
    return path


def read_calibration(path: Path) -> dict[str, View]:
    """The views a calibration file holds, by camera name."""
    try:
        data = json.loads(Path(path).read_text())
        views = {}
        for c in data["cameras"]:
            i = c["intrinsics"]
            views[c["name"]] = View(c["name"], Intrinsics(int(c["resolution"][0]), int(c["resolution"][1]),
                                                          float(i["fx_px"]), float(i["fy_px"]), float(i["cx_px"]),
                                                          float(i["cy_px"]), tuple(i["distortion"])),
                                    CameraPose(np.asarray(c["pose"]["rotation"], dtype=float),
                                               np.asarray(c["pose"]["translation_m"], dtype=float)))
        return views
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise CameraError(f"{path}: not a camera calibration file ({e})") from None

