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


def render_robot(robot: str, q: np.ndarray, path: Path) -> Path:
    """A picture of the robot at ``q`` in the CT room."""
    settings = PyBulletSettings(robot_urdf(robot), get_robot(robot).joint_names, default_scene(),
                                initial_position=q)
    with PyBulletActuators(settings) as sim:
        return render_png(sim.client, path)
