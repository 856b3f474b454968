"""Emulated cameras: PyBullet's software renderer of the robot and its room, as a lens would see it.

:class:`RenderedScene` is a private PyBullet world (``DIRECT``: no display, no physics stepped)
holding the robot's URDF, the room's static bodies and the fiducials (small coloured balls fixed
to a link at a known offset). It is posed on demand at the joint positions it is given and
rendered with TinyRenderer from any camera's pose and intrinsics. :class:`EmulatedCamera` is one
camera on that scene: each :meth:`~EmulatedCamera.grab` poses the scene where ``state`` says the
joints are (a simulator's true joints, not its encoders'), renders the ideal pinhole image and
gives it the lens's distortion (OpenCV's model), a Gaussian blur and the sensor's noise (one
Gaussian draw per pixel, on all three channels), seeded.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from drivers.camera import CameraError, CameraPose, Frame, Intrinsics
from drivers.quiet import quiet_pybullet

__all__ = ["Decal", "EmulatedCamera", "Fiducial", "RenderedScene", "forget_rooms", "gl_matrices"]

#: Clipping planes of the renderer (m): the room is within a few metres of any camera.
NEAR_M, FAR_M = 0.05, 5.0
_LIGHT = [0.3, -0.5, 1.0]
#: The room's resolution against the camera's (it is rendered once, and enlarged).
ROOM_SCALE = 0.5
#: Pixels between the points where the lens's inverse is solved (interpolated between).
_MAP_STEP = 8


@dataclass(frozen=True)
class Fiducial:
    """A ball of ``radius`` (m) and colour ``rgba`` whose centre is at ``offset`` (m) in ``link``'s frame."""

    name: str
    link: str
    offset: tuple[float, float, float]
    radius: float
    rgba: tuple[float, float, float, float]


#: The room's pictures (colour and depth) by room and camera, kept for this process's next cameras
#: (a campaign's or a test run's trials share the room): the oldest goes beyond ``_ROOMS_KEPT``.
_ROOMS: dict = {}
_ROOMS_KEPT = 8


def forget_rooms() -> None:
    """Drop the room pictures kept (the next camera renders its room again)."""
    _ROOMS.clear()


def _file_key(path) -> tuple:
    st = Path(path).stat()
    return str(Path(path).resolve()), st.st_mtime_ns, st.st_size


@dataclass(frozen=True)
class Decal:
    """A flat picture on a surface of the room (a marker taped to the bed): ``image`` (grey or
    BGR), its top-left corner at ``origin`` (m, world), its rows along ``x_axis`` and its columns
    down ``y_axis`` (unit vectors), ``size`` (m) a side."""

    image: np.ndarray
    origin: tuple[float, float, float]
    x_axis: tuple[float, float, float]
    y_axis: tuple[float, float, float]
    size: float

    @property
    def key(self) -> tuple:
        """What the decal's picture in a room depends on."""
        return (hash(self.image.tobytes()), self.origin, self.x_axis, self.y_axis, self.size)

    def draw(self, rgb: np.ndarray, intrinsics: Intrinsics, pose: CameraPose,
             depth: Optional[np.ndarray] = None) -> np.ndarray:
        """The decal drawn into an RGB image of the ideal (undistorted) camera; with the image's
        ``depth`` (the renderer's buffer), only where nothing of the room stands in front of it."""
        import cv2  # heavy: OpenCV, only when a camera is used

        art = self.image if self.image.ndim == 3 else cv2.cvtColor(self.image, cv2.COLOR_GRAY2RGB)
        s = art.shape[1] / self.size  # pixels of the picture per metre
        A = np.array([[1 / s, 0, 0.5 / s], [0, 1 / s, 0.5 / s], [0, 0, 1]])  # picture pixel -> plane (m)
        x, y, o = (np.asarray(v, dtype=float) for v in (self.x_axis, self.y_axis, self.origin))
        H = intrinsics.matrix @ np.column_stack([pose.rotation @ x, pose.rotation @ y,
                                                 pose.rotation @ o + pose.translation]) @ A
        # only the window the decal covers is drawn (its corners projected, a pixel of margin)
        h_art, w_art = art.shape[:2]
        ends = H @ np.array([[-0.5, -0.5, 1], [w_art - 0.5, -0.5, 1], [w_art - 0.5, h_art - 0.5, 1],
                             [-0.5, h_art - 0.5, 1]], dtype=float).T
        if np.any(ends[2] <= 0):  # behind the camera
            return rgb
        us, vs = ends[0] / ends[2], ends[1] / ends[2]
        x0, y0 = max(0, int(np.floor(us.min())) - 1), max(0, int(np.floor(vs.min())) - 1)
        x1, y1 = min(rgb.shape[1], int(np.ceil(us.max())) + 2), min(rgb.shape[0], int(np.ceil(vs.max())) + 2)
        if x1 <= x0 or y1 <= y0:
            return rgb
        Hw = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]]) @ H
        size = (x1 - x0, y1 - y0)
        warped = cv2.warpPerspective(art, Hw, size, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.full(art.shape[:2], 255, np.uint8), Hw, size, flags=cv2.INTER_LINEAR)
        a = mask.astype(np.float32) / 255.0
        if depth is not None:  # the decal's distance along the view at each pixel, against the room's
            normal = pose.rotation @ np.cross(x, y)
            c = float(normal @ (pose.rotation @ o + pose.translation))
            u, v = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
            rays = normal[0] * (u - intrinsics.cx) / intrinsics.fx + normal[1] * (v - intrinsics.cy) / intrinsics.fy + normal[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                z_decal = c / rays
            n, f = NEAR_M, FAR_M
            z_room = 2 * f * n / ((f + n) - (2 * depth[y0:y1, x0:x1] - 1) * (f - n))
            a[~(z_decal <= z_room + 0.002)] = 0.0  # 2 mm: the decal lies on the surface it is taped to
        a = a[..., None]
        out = rgb.copy()
        out[y0:y1, x0:x1] = (rgb[y0:y1, x0:x1] * (1 - a) + warped * a).astype(np.uint8)
        return out


def gl_matrices(intrinsics: Intrinsics, pose: CameraPose) -> tuple[list[float], list[float]]:
    """PyBullet's (OpenGL's) view and projection matrices, column-major, for an OpenCV camera whose
    pixel centres are at integer coordinates. TinyRenderer's rows come out one pixel off the
    OpenGL convention (measured: a ball's centroid lands 0.5 px right of and 0.5 px above where an
    OpenCV projection with the half-pixel shift on both axes puts it), hence the shifts below."""
    w, h = intrinsics.width, intrinsics.height
    view = np.eye(4)
    view[:3, :3], view[:3, 3] = pose.rotation, pose.translation
    view = np.diag([1.0, -1.0, -1.0, 1.0]) @ view  # OpenCV's camera (y down, z ahead) to OpenGL's
    n, f = NEAR_M, FAR_M
    proj = np.array([
        [2 * intrinsics.fx / w, 0.0, 1 - 2 * intrinsics.cx / w, 0.0],
        [0.0, 2 * intrinsics.fy / h, 2 * (intrinsics.cy + 1.0) / h - 1, 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0]])
    return view.T.reshape(-1).tolist(), proj.T.reshape(-1).tolist()


class RenderedScene:
    """The robot, its room and its fiducials in a PyBullet world of their own, posed on demand.

    ``scene`` holds the room's static bodies, each with ``urdf``, ``position`` and ``rpy``
    attributes (as ``drivers.pybullet.backend.SceneObject``)."""

    def __init__(self, robot_urdf: Path, joint_names: Sequence[str], scene: Sequence = (),
                 fiducials: Sequence[Fiducial] = (), decals: Sequence["Decal"] = ()) -> None:
        pb = self._pb = quiet_pybullet()
        self.decals = list(decals)
        # what the room's picture depends on, beside the camera: its files as they are now, the decals
        self._room_key = (tuple(_file_key(p) for p in [robot_urdf, *(obj.urdf for obj in scene)]),
                          tuple((tuple(obj.position), tuple(obj.rpy)) for obj in scene),
                          tuple(d.key for d in self.decals))
        # Two worlds: the room, which never moves (rendered once per camera and kept with its depth),
        # and the robot with its fiducials (rendered at each grab and laid over the room by depth).
        self.room, self.client = pb.connect(pb.DIRECT), pb.connect(pb.DIRECT)
        if self.room < 0 or self.client < 0:
            self.close()
            raise CameraError("could not start a PyBullet client for the emulated cameras")
        c = self.client
        try:
            self.robot = pb.loadURDF(str(robot_urdf), useFixedBase=True, physicsClientId=c)
            # the robot's base never moves: it is drawn with the room, its moving links without it
            fixed = pb.loadURDF(str(robot_urdf), useFixedBase=True, physicsClientId=self.room)
            for j in range(pb.getNumJoints(fixed, physicsClientId=self.room)):
                pb.changeVisualShape(fixed, j, rgbaColor=[0, 0, 0, 0], physicsClientId=self.room)
            pb.changeVisualShape(self.robot, -1, rgbaColor=[0, 0, 0, 0], physicsClientId=c)
            for obj in scene:
                pb.loadURDF(str(obj.urdf), list(obj.position), pb.getQuaternionFromEuler(list(obj.rpy)),
                            useFixedBase=True, physicsClientId=self.room)
            joints, links = {}, {}
            for j in range(pb.getNumJoints(self.robot, physicsClientId=c)):
                info = pb.getJointInfo(self.robot, j, physicsClientId=c)
                joints[info[1].decode()], links[info[12].decode()] = j, j
            missing = [n for n in joint_names if n not in joints]
            if missing:
                raise CameraError(f"joints {missing} are not in {Path(robot_urdf).name}")
            self._joints = [joints[n] for n in joint_names]
            self._links = links
            self.fiducials = list(fiducials)
            self._balls = []
            for fid in self.fiducials:
                if fid.link not in links:
                    raise CameraError(f"fiducial {fid.name!r}: no link {fid.link!r} in "
                                      f"{Path(robot_urdf).name}; it has {sorted(links)}")
                shape = pb.createVisualShape(pb.GEOM_SPHERE, radius=fid.radius, rgbaColor=list(fid.rgba),
                                             physicsClientId=c)
                self._balls.append((links[fid.link], pb.createMultiBody(
                    baseVisualShapeIndex=shape, physicsClientId=c)))
        except Exception:
            self.close()
            raise
        self._posed: Optional[np.ndarray] = None

    def pose(self, q: np.ndarray) -> None:
        """Put the joints at ``q`` (rad or m) and the fiducials on their links."""
        q = np.asarray(q, dtype=float)
        if self._posed is not None and np.array_equal(q, self._posed):
            return
        pb, c = self._pb, self.client
        for j, v in zip(self._joints, q):
            pb.resetJointState(self.robot, j, float(v), 0.0, physicsClientId=c)
        for fid, (link, ball) in zip(self.fiducials, self._balls):
            pos, orn = pb.getLinkState(self.robot, link, computeForwardKinematics=True,
                                       physicsClientId=c)[4:6]
            rot = np.asarray(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
            at = np.asarray(pos) + rot @ np.asarray(fid.offset, dtype=float)
            pb.resetBasePositionAndOrientation(ball, at.tolist(), [0, 0, 0, 1], physicsClientId=c)
        self._posed = q.copy()

    def fiducial_positions(self) -> dict[str, np.ndarray]:
        """Where the fiducials' centres are now (m, world)."""
        pb, c = self._pb, self.client
        return {fid.name: np.asarray(pb.getBasePositionAndOrientation(ball, physicsClientId=c)[0])
                for fid, (_, ball) in zip(self.fiducials, self._balls)}

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """A link's frame now: its origin (m) and rotation (3 × 3), in the world."""
        if link not in self._links:
            raise CameraError(f"no link {link!r}")
        pos, orn = self._pb.getLinkState(self.robot, self._links[link], computeForwardKinematics=True,
                                         physicsClientId=self.client)[4:6]
        return np.asarray(pos), np.asarray(self._pb.getMatrixFromQuaternion(orn)).reshape(3, 3)

    def _window(self, intrinsics: Intrinsics, pose: CameraPose) -> tuple[int, int, int, int]:
        """The part of the image the moving links and the fiducials can cover (x0, y0, x1, y1):
        their bounding boxes' corners projected, with a margin."""
        pb, c = self._pb, self.client
        boxes = [pb.getAABB(self.robot, j, physicsClientId=c) for j in range(pb.getNumJoints(self.robot, physicsClientId=c))]
        boxes += [pb.getAABB(ball, -1, physicsClientId=c) for _, ball in self._balls]
        lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        cam = corners @ pose.rotation.T + pose.translation
        w, h = intrinsics.width, intrinsics.height
        if np.any(cam[:, 2] <= NEAR_M):  # part of the robot behind or at the lens: the whole image
            return 0, 0, w, h
        u = intrinsics.fx * cam[:, 0] / cam[:, 2] + intrinsics.cx
        v = intrinsics.fy * cam[:, 1] / cam[:, 2] + intrinsics.cy
        m = 4
        x0, x1 = int(np.clip(np.floor(u.min()) - m, 0, w)), int(np.clip(np.ceil(u.max()) + m, 0, w))
        y0, y1 = int(np.clip(np.floor(v.min()) - m, 0, h)), int(np.clip(np.ceil(v.max()) + m, 0, h))
        return x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)

    def _image(self, client: int, intrinsics: Intrinsics, pose: CameraPose) -> tuple[np.ndarray, np.ndarray]:
        view, proj = gl_matrices(intrinsics, pose)
        w, h = intrinsics.width, intrinsics.height
        _, _, rgba, depth, _ = self._pb.getCameraImage(
            w, h, view, proj, renderer=self._pb.ER_TINY_RENDERER, shadow=0, lightDirection=_LIGHT,
            lightAmbientCoeff=0.55, lightDiffuseCoeff=0.5, lightSpecularCoeff=0.0,
            flags=self._pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
        return (np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3],
                np.asarray(depth, dtype=np.float32).reshape(h, w))

    def _room(self, intrinsics: Intrinsics, pose: CameraPose) -> tuple[np.ndarray, np.ndarray]:
        """The room from ``pose`` at ``ROOM_SCALE`` of the resolution, enlarged to the camera's
        (the colour linearly, the depth to the nearest pixel): it never moves and no fiducial is on
        it, and a quarter of the pixels is a quarter of the renderer's time."""
        import cv2  # heavy: OpenCV, only when a camera is used

        w, h = intrinsics.width, intrinsics.height
        sw, sh = max(1, round(w * ROOM_SCALE)), max(1, round(h * ROOM_SCALE))
        kx, ky = sw / w, sh / h
        small = Intrinsics(sw, sh, intrinsics.fx * kx, intrinsics.fy * ky, (intrinsics.cx + 0.5) * kx - 0.5,
                           (intrinsics.cy + 0.5) * ky - 0.5)  # the same view, pixels k times larger
        rgb, depth = self._image(self.room, small, pose)
        rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
        depth = cv2.resize(depth, (w, h), interpolation=cv2.INTER_NEAREST)
        for decal in self.decals:  # printed on the room's surfaces: the robot passes in front of them
            rgb = decal.draw(rgb, intrinsics, pose, depth)
        return rgb, depth

    def render(self, intrinsics: Intrinsics, pose: CameraPose, robot: bool = True) -> np.ndarray:
        """The ideal pinhole image (H × W × 3, uint8, RGB) from ``pose``: the robot where it was
        last posed over the room, each pixel the nearer of the two (the renderer's own depth test).
        The room (with the robot's fixed base) is rendered once per camera and process, at half the
        resolution;
        the moving links and the fiducials at the full resolution, in the window they can cover."""
        key = (self._room_key, intrinsics, pose.rotation.tobytes(), pose.translation.tobytes())
        if key not in _ROOMS:  # the room never moves: rendered once per camera in this process
            if len(_ROOMS) >= _ROOMS_KEPT:
                _ROOMS.pop(next(iter(_ROOMS)))
            _ROOMS[key] = self._room(intrinsics, pose)
        room, room_depth = _ROOMS[key]
        if not robot:  # the room alone (the robot parked out of the picture)
            return room.copy()
        x0, y0, x1, y1 = self._window(intrinsics, pose)
        part = Intrinsics(x1 - x0, y1 - y0, intrinsics.fx, intrinsics.fy, intrinsics.cx - x0,
                          intrinsics.cy - y0)  # the same lens, the image cut to the window
        robot, depth = self._image(self.client, part, pose)
        image = room.copy()
        window = image[y0:y1, x0:x1]
        nearer = depth < room_depth[y0:y1, x0:x1]
        window[nearer] = robot[nearer]
        return image

    def close(self) -> None:
        for client in (self.room, self.client):
            if client >= 0:
                self._pb.disconnect(physicsClientId=client)
        self.room = self.client = -1


class EmulatedCamera:
    """One camera on a :class:`RenderedScene`: ``grab()`` renders the scene where ``state()`` says
    the joints are (``state`` returns the joint positions and the time they hold, s), with the
    lens's distortion (``intrinsics.distortion``), a Gaussian blur of ``blur_px`` (σ, pixels) and
    Gaussian noise of ``noise`` (σ, grey levels), drawn from ``seed``."""

    def __init__(self, name: str, scene: RenderedScene, state: Callable[[], tuple[np.ndarray, float]],
                 intrinsics: Intrinsics, pose: CameraPose, noise: float = 0.0, blur_px: float = 0.0,
                 seed: int = 0) -> None:
        self.name, self.scene, self.state = name, scene, state
        self.intrinsics, self.pose = intrinsics, pose
        self.noise, self.blur_px = float(noise), float(blur_px)
        self._rng = np.random.default_rng(seed)
        self._maps = None
        #: Drawn on the ideal image before the lens (a calibration board held up, laid down):
        #: ``overlay(image, intrinsics, pose) -> image``; None: the scene alone, robot included.
        self.overlay: Optional[Callable[[np.ndarray, Intrinsics, CameraPose], np.ndarray]] = None

    def _lens_maps(self):
        """For each pixel of the distorted image, where the ideal image holds it (cv2.remap's maps):
        OpenCV's inverse of the lens model on a grid every ``_MAP_STEP`` pixels, interpolated between
        (the model is smooth: a thousandth of a pixel from the exact inverse)."""
        import cv2  # heavy: OpenCV, only when a camera is used

        if self._maps is None:
            i, s = self.intrinsics, _MAP_STEP
            # grid point k at pixel (k - 1) * s + (s - 1) / 2: where cv2.resize, enlarging s times,
            # puts the centre of its k-th source pixel; one point beyond each edge
            gw, gh = -(-i.width // s) + 2, -(-i.height // s) + 2
            u, v = np.meshgrid((np.arange(gw) - 1) * s + (s - 1) / 2, (np.arange(gh) - 1) * s + (s - 1) / 2)
            pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
            ideal = cv2.undistortPoints(pts, i.matrix, i.dist, R=None, P=i.matrix,
                                        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9))
            ideal = ideal.reshape(gh, gw, 2).astype(np.float32)
            self._maps = tuple(np.ascontiguousarray(cv2.resize(
                ideal[..., c], (gw * s, gh * s), interpolation=cv2.INTER_LINEAR)[s:s + i.height, s:s + i.width])
                for c in range(2))
        return self._maps

    def grab(self) -> Frame:
        import cv2  # heavy: OpenCV, only when a camera is used

        q, t = self.state()
        self.scene.pose(q)
        img = cv2.cvtColor(self.scene.render(self.intrinsics, self.pose, robot=self.overlay is None),
                           cv2.COLOR_RGB2BGR)
        if self.overlay is not None:
            img = self.overlay(img, self.intrinsics, self.pose)
        if np.any(self.intrinsics.dist != 0.0):
            mx, my = self._lens_maps()
            img = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self.blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur_px)
        if self.noise > 0:
            # one draw per pixel, on all three channels (a sensor's luminance noise)
            noise = self._rng.standard_normal(img.shape[:2], dtype=np.float32)
            noise *= self.noise
            img = cv2.add(img, cv2.cvtColor(noise, cv2.COLOR_GRAY2BGR), dtype=cv2.CV_8U)  # rounded, 0-255
        return Frame(self.name, img, float(t))

    def close(self) -> None:
        """The scene is the caller's (cameras share one); nothing of the camera's own to free."""
