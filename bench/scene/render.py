"""Pictures of the scene from PyBullet's software renderer (no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.kinematics.registry import get_robot
from bench.paths import robot_urdf
from bench.scene.room import default_scene
from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings
from drivers.quiet import quiet_pybullet


def render_png(client: int, path: Path, target=(-0.22, 0.2, 0.12), distance: float = 0.95,
               yaw: float = -50.0, pitch: float = -30.0, size: tuple[int, int] = (960, 720)) -> Path:
    """Render the world of a PyBullet client to ``path`` (PNG) with TinyRenderer."""
    import matplotlib  # heavy: matplotlib, only when a plot is drawn

    matplotlib.use("Agg")
    import matplotlib.image as mpimg  # heavy: matplotlib, only when a plot is drawn

    pb = quiet_pybullet()

    w, h = size
    view = pb.computeViewMatrixFromYawPitchRoll(target, distance, yaw, pitch, 0.0, 2,
                                                physicsClientId=client)
    proj = pb.computeProjectionMatrixFOV(45.0, w / h, 0.02, 10.0, physicsClientId=client)
    _, _, rgba, _, _ = pb.getCameraImage(w, h, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         lightDirection=[0.4, -0.6, 1.0],
                                         physicsClientId=client)
    img = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mpimg.imsave(path, img)
    return path


#: RGBA of the planned needle path (target entry to target tip) and of the needle as placed.
TARGET_RGBA = (0.85, 0.1, 0.1, 1.0)
NEEDLE_RGBA = (0.1, 0.7, 0.2, 1.0)




def _ball(pb, client: int, at: np.ndarray, radius: float, rgba) -> None:
    ball = pb.createVisualShape(pb.GEOM_SPHERE, radius=radius, rgbaColor=rgba, physicsClientId=client)
    pb.createMultiBody(baseVisualShapeIndex=ball, basePosition=np.asarray(at, dtype=float).tolist(),
                       physicsClientId=client)


def _segment(pb, client: int, a: np.ndarray, b: np.ndarray, radius: float, rgba) -> None:
    """A visual-only rod from ``a`` to ``b`` (m, world frame)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    if length > 1e-9:
        z = axis / length
        rot = np.cross([0.0, 0.0, 1.0], z)
        s, c = float(np.linalg.norm(rot)), float(z[2])
        quat = ([0.0, 0.0, 0.0, 1.0] if s < 1e-12 else
                [*(rot / s * np.sin(np.arctan2(s, c) / 2)), float(np.cos(np.arctan2(s, c) / 2))])
        rod = pb.createVisualShape(pb.GEOM_CYLINDER, radius=radius, length=length, rgbaColor=rgba,
                                   physicsClientId=client)
        pb.createMultiBody(baseVisualShapeIndex=rod, basePosition=((a + b) / 2).tolist(),
                           baseOrientation=quat, physicsClientId=client)


def render_robot(robot: str, q: np.ndarray, path: Path, target=None) -> Path:
    """A picture of the robot at ``q`` in the CT room; with ``target`` (a NeedleTarget), framed
    close from the side, without the phantom (the needle's path is inside it and the renderer
    draws no glass): the planned path in red (a rod from 30 mm above the entry point to the tip,
    a ball at the entry point) and the needle as placed at ``q``, green balls at its entry point
    and tip."""
    model = get_robot(robot)
    settings = PyBulletSettings(robot_urdf(robot), model.joint_names, default_scene(),
                                initial_position=q)
    with PyBulletActuators(settings) as sim:
        if target is None:
            return render_png(sim.client, path)
        pb = quiet_pybullet()
        phantom = sim.scene_bodies.get("phantom")
        if phantom is not None:  # the needle's path is inside it, and the renderer draws no glass
            pb.removeBody(phantom, physicsClientId=sim.client)
        placed = model.needle(np.asarray(q, dtype=float))
        _segment(pb, sim.client, target.entry - 0.03 * target.direction, target.tip, 0.0009, TARGET_RGBA)
        _ball(pb, sim.client, target.entry, 0.002, TARGET_RGBA)
        for at in (placed.entry, placed.tip):
            _ball(pb, sim.client, at, 0.003, NEEDLE_RGBA)
        centre = (np.asarray(target.entry, dtype=float) + np.asarray(target.tip, dtype=float)) / 2
        return render_png(sim.client, path, target=tuple(centre), distance=0.32, yaw=60.0, pitch=-12.0)
