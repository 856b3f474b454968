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
               yaw: float = -50.0, pitch: float = -30.0, size: tuple[int, int] = (960, 720),
               fov_deg: float = 45.0, ambient: float = 0.6, ortho_half: float | None = None) -> Path:
    """Render the world of a PyBullet client to ``path`` (PNG) with TinyRenderer."""
    from PIL import Image  # heavy: only when a picture is drawn

    pb = quiet_pybullet()

    w, h = size
    view = pb.computeViewMatrixFromYawPitchRoll(target, distance, yaw, pitch, 0.0, 2,
                                                physicsClientId=client)
    if ortho_half is None:
        proj = pb.computeProjectionMatrixFOV(fov_deg, w / h, 0.02, 10.0, physicsClientId=client)
    else:  # nearly orthographic: a narrow view from far off, so a side is seen square and the
        fov = float(np.degrees(2 * np.arctan(ortho_half / distance)))  # bed does not recede
        proj = pb.computeProjectionMatrixFOV(fov, w / h, distance / 4, distance * 2, physicsClientId=client)
    _, _, rgba, _, _ = pb.getCameraImage(w, h, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         lightDirection=[0.4, -0.6, 1.0], lightAmbientCoeff=ambient,
                                         physicsClientId=client)
    img = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(img)).save(path)  # RGB: the render has no transparency
    return path


#: RGBA of the planned insertion (target entry to target tip), of its approach (the 30 mm the
#: needle travels above the entry point) and of the needle as placed (its entry point and tip).
TARGET_RGBA = (0.85, 0.1, 0.1, 1.0)
APPROACH_RGBA = (1.0, 0.62, 0.1, 1.0)
NEEDLE_RGBA = (0.1, 0.7, 0.2, 1.0)
#: The side the picture is taken from: looking along the bed's X axis, from its +X end, the
#: needle's plane (Y-Z) square to the camera, so the insertion angle shows true.
SIDE_VIEW = "from the foot of the bed, along its axis"
_SIDE_YAW = 90.0
_APPROACH_M = 0.03
#: The scene's bodies a side view leaves out: the needle's path is inside the one, the other rings
#: the frame.
_LEFT_OUT = ("phantom", "ct_gantry")




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


def _framing(points: np.ndarray, aspect: float) -> tuple[tuple[float, float, float], float]:
    """The camera's target and the half-height of an orthographic view along X that fits
    ``points`` (m, world) with a margin."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    half = max((hi[1] - lo[1]) / 2 / aspect, (hi[2] - lo[2]) / 2) * 1.12 + 0.01
    return (float(centre[0]), float(centre[1]), float(centre[2])), float(half)


def render_robot(robot: str, q: np.ndarray, path: Path, target=None) -> Path:
    """A picture of the robot at ``q`` in the CT room; with ``target`` (a NeedleTarget), framed on
    the robot and the target, seen from the side (:data:`SIDE_VIEW`), without the phantom and the
    gantry (the needle's path is inside the one, the other rings the frame): the planned insertion
    in red (entry point to tip, a ball at the entry), its approach above the entry in orange, and
    the needle as placed at ``q``, green balls at its entry point and tip."""
    model = get_robot(robot)
    scene = [o for o in default_scene() if target is None or Path(o.urdf).stem not in _LEFT_OUT]
    settings = PyBulletSettings(robot_urdf(robot), model.joint_names, scene, initial_position=q)
    with PyBulletActuators(settings) as sim:
        if target is None:
            return render_png(sim.client, path)
        pb = quiet_pybullet()
        placed = model.needle(np.asarray(q, dtype=float))
        entry, tip = np.asarray(target.entry, dtype=float), np.asarray(target.tip, dtype=float)
        above = entry - _APPROACH_M * np.asarray(target.direction, dtype=float)
        _segment(pb, sim.client, above, entry, 0.0012, APPROACH_RGBA)
        _segment(pb, sim.client, entry, tip, 0.0012, TARGET_RGBA)
        _ball(pb, sim.client, entry, 0.0025, TARGET_RGBA)
        for at in (placed.entry, placed.tip):
            _ball(pb, sim.client, at, 0.003, NEEDLE_RGBA)
        links = [pb.getLinkState(sim.robot, j, physicsClientId=sim.client)[4]
                 for j in range(pb.getNumJoints(sim.robot, physicsClientId=sim.client))]
        points = [*links, pb.getBasePositionAndOrientation(sim.robot, physicsClientId=sim.client)[0],
                  entry, tip, above]
        bed = sim.scene_bodies.get("ct_bed")
        if bed is not None:  # the bed's cross-section whole, under the robot
            lo, hi = pb.getAABB(bed, -1, physicsClientId=sim.client)
            points += [(0.0, lo[1], lo[2]), (0.0, hi[1], hi[2])]
        centre, half = _framing(np.asarray(points, dtype=float), 960 / 720)
        return render_png(sim.client, path, target=centre, distance=12.0, yaw=_SIDE_YAW, pitch=0.0,
                          ambient=0.75, ortho_half=half)
