"""A calibration session: the board's views taken from the config's cameras, emulated (drawn into
the rendered scene through each lens) or real (the technician holds the board), then calibrated
(:mod:`bench.cameras.calibrate`)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from bench.cameras.calibrate import (CameraCalibration, board_overlay, calibrate_views, held_poses, laid_pose,
                                     place_for)
from bench.cameras.measure import View
from bench.cameras.rig import TrialCameras, view_of
from drivers.camera.capture import CaptureCamera

__all__ = ["calibrate_devices", "calibrate_emulated"]


def calibrate_emulated(cameras, urdf: Path, joint_names, urdf_dir: Path, held_views: int = 10,
                       max_reprojection_px: float = 1.0, seed: int = 0) -> tuple[list[CameraCalibration], list[View]]:
    """Calibrate the config's emulated cameras: the board held in ``held_views`` poses before each
    and laid at its place, drawn into the rendered room through each lens. Returns the calibrations
    and the cameras as configured (the emulation's truth)."""
    rig = TrialCameras(cameras, "emulated", urdf, joint_names, urdf_dir, lambda: np.zeros(len(joint_names)),
                       seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    try:
        rig.park()
        for cam, view in zip(rig.cameras, rig.true_views):
            held = []
            for pose in held_poses(view, held_views, rng):
                cam.overlay = board_overlay(pose)
                held.append(cam.grab().image)
            place = place_for(view)
            cam.overlay = board_overlay(laid_pose(view, place))
            laid = cam.grab().image
            cam.overlay = None
            out.append(calibrate_views(view.name, (view.intrinsics.width, view.intrinsics.height), held, laid,
                                       max_reprojection_px, place))
    finally:
        rig.close()
    return out, rig.true_views


def calibrate_devices(cameras, held_views: int, max_reprojection_px: float,
                      ask: Callable[[str], None]) -> list[CameraCalibration]:
    """Calibrate the config's real cameras: ``ask`` tells the technician what to do and waits."""
    out = []
    for c in cameras.views:
        view = view_of(c)
        cam = CaptureCamera(c.name, c.device, view.intrinsics, c.exposure)
        try:
            held = []
            for k in range(held_views):
                ask(f"camera {c.name}: hold the board in view ({k + 1} of {held_views}: another place, "
                    f"another tilt) and press Enter")
                held.append(cam.grab().image)
            place = place_for(view)
            ask(f"camera {c.name}: put the board {place} at its place on the bed "
                f"(docs/cameras.md), park the robot out of view, and press Enter")
            laid = cam.grab().image
        finally:
            cam.close()
        out.append(calibrate_views(c.name, c.resolution, held, laid, max_reprojection_px, place))
    return out
