"""From two views of the holder's fiducial to the tip and the needle's direction (SI, robot frame).

Each ball is found by its colour (:func:`find_balls`: the hue within a window, strongly saturated,
the largest blob's centroid to a fraction of a pixel), its pixel freed of the lens's distortion
(``cv2.undistortPoints``) and triangulated from the two views (``cv2.triangulatePoints``). The
balls' layout is then fitted to the triangulated centres (a rigid fit, Kabsch): the holder's pose,
and through it the tip and the direction. The uncertainty is the calibration's pixel error carried
through the whole chain (its Jacobian, by finite differences): the tip's covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from bench.cameras.fiducial import BALLS, Ball
from drivers.camera import CameraPose, Intrinsics

__all__ = ["Measurement", "View", "find_balls", "measure_tip", "triangulate"]

#: A ball's pixels: within this many degrees of its hue, saturation and value above these (0-255).
HUE_WINDOW_DEG = 12.0
MIN_SATURATION = 150
MIN_VALUE = 30
#: Fewest pixels a ball's blob may have (a ball a few pixels wide is not measured).
MIN_PIXELS = 12
#: A fit whose balls sit further than this from their layout (m, rms) is refused: a wrong blob.
MAX_FIT_RMS_M = 0.0015
#: A ball whose blob covers less than this share of the disc its size and distance make is cut
#: by something in front of it, and its centroid is off: it is not used.
MIN_AREA_SHARE = 0.7


@dataclass(frozen=True)
class View:
    """One camera as the metrology knows it: intrinsics and pose (world to camera)."""

    name: str
    intrinsics: Intrinsics
    pose: CameraPose


@dataclass
class Measurement:
    """The tip and the needle's direction (m, unit vector, robot frame), the tip's covariance (m²),
    the balls used, their pixels per view, and the fit's residual (m, rms); or why there is none."""

    tip: Optional[np.ndarray] = None
    direction: Optional[np.ndarray] = None
    covariance: Optional[np.ndarray] = None
    balls: list[str] = field(default_factory=list)
    pixels: dict = field(default_factory=dict)
    fit_rms: float = float("nan")
    holder: Optional[tuple[np.ndarray, np.ndarray]] = None
    problem: str = ""

    @property
    def ok(self) -> bool:
        return self.tip is not None

    @property
    def sigma(self) -> float:
        """The tip's standard uncertainty (m): the root of the covariance's trace."""
        return float(np.sqrt(np.trace(self.covariance))) if self.covariance is not None else float("nan")


def find_balls(image: np.ndarray, balls: Sequence[Ball] = BALLS) -> dict[str, np.ndarray]:
    """Each ball's centroid (pixels, x right, y down; pixel centres at integers) and its blob's
    area (pixels) in a BGR image: ``{name: [u, v, area]}``; a ball not seen is left out.

    Found in the image shrunk four times (the whole frame is searched, fast), measured in the full
    image around where it was found."""
    import cv2  # heavy: OpenCV, only when frames are measured

    small = cv2.resize(image, None, fx=1 / _SHRINK, fy=1 / _SHRINK, interpolation=cv2.INTER_AREA)
    hsv_small = cv2.cvtColor(small, cv2.COLOR_BGR2HSV_FULL)
    found = {}
    for b in balls:
        blob = _largest_blob(cv2, _ball_mask(hsv_small, b), 2)
        if blob is None:
            continue
        x, y, w, h = (int(v) for v in blob[1][:4])
        m = 2 * _SHRINK
        x0, y0 = max(0, x * _SHRINK - m), max(0, y * _SHRINK - m)
        x1, y1 = min(image.shape[1], (x + w) * _SHRINK + m), min(image.shape[0], (y + h) * _SHRINK + m)
        roi = cv2.cvtColor(image[y0:y1, x0:x1], cv2.COLOR_BGR2HSV_FULL)
        fine = _largest_blob(cv2, _ball_mask(roi, b), MIN_PIXELS)
        if fine is not None:
            (u, v), area = fine[0], fine[1][4]
            found[b.name] = np.array([u + x0, v + y0, area], dtype=float)
    return found


_SHRINK = 4


def _ball_mask(hsv: np.ndarray, b: Ball) -> np.ndarray:
    h = hsv[..., 0].astype(np.int16)
    d = np.abs(((h - round(b.hue_deg * 256.0 / 360.0) + 128) % 256) - 128)
    return ((hsv[..., 1] >= MIN_SATURATION) & (hsv[..., 2] >= MIN_VALUE)
            & (d <= HUE_WINDOW_DEG * 256.0 / 360.0)).astype(np.uint8)


def _largest_blob(cv2, mask: np.ndarray, min_pixels: int):
    """(centroid, stats) of the mask's largest blob, or None below ``min_pixels``."""
    n, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < min_pixels:
        return None
    return centroids[k], stats[k]


def _normalised(view: View, px: np.ndarray) -> np.ndarray:
    import cv2  # heavy: OpenCV, only when frames are measured

    i = view.intrinsics
    pts = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, i.matrix, i.dist, criteria=(
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)).reshape(-1, 2)


def triangulate(views: Sequence[View], pixels: Sequence[np.ndarray]) -> np.ndarray:
    """Points (N × 3, m) from their pixels (N × 2) in two views."""
    import cv2  # heavy: OpenCV, only when frames are measured

    a, b = views
    pa, pb = (np.hstack([v.pose.rotation, v.pose.translation.reshape(3, 1)]) for v in (a, b))
    xa, xb = _normalised(a, pixels[0]), _normalised(b, pixels[1])
    X = cv2.triangulatePoints(pa, pb, xa.T, xb.T)
    return (X[:3] / X[3]).T


def _whole(views: Sequence[View], found: Sequence[dict], both: list[Ball]) -> list[Ball]:
    """The balls seen whole in both views: a ball partly hidden has a centroid off its centre, so
    one whose blob is smaller than its triangulated size says (``MIN_AREA_SHARE``) is left out."""
    px = [np.array([f[b.name][:2] for b in both]) for f in found]
    centres = triangulate(views, px)
    keep = []
    for k, b in enumerate(both):
        ok = True
        for v, f in zip(views, found):
            z = float(v.pose.rotation[2] @ centres[k] + v.pose.translation[2])
            r_px = v.intrinsics.fx * b.radius / max(z, 1e-6)
            ok &= f[b.name][2] >= MIN_AREA_SHARE * np.pi * r_px ** 2
        if ok:
            keep.append(b)
    return keep


def _rigid_fit(model: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """R, t with world ≈ R @ model + t (Kabsch), and the residual (m, rms)."""
    cm, cw = model.mean(axis=0), world.mean(axis=0)
    u, _, vt = np.linalg.svd((model - cm).T @ (world - cw))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = cw - R @ cm
    res = world - (model @ R.T + t)
    return R, t, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))


def _tip(views, pixels, model, tip_local, axis_local):
    world = triangulate(views, pixels)
    R, t, rms = _rigid_fit(model, world)
    return R @ tip_local + t, R @ axis_local, rms, (R, t)


def measure_tip(views: Sequence[View], found: Sequence[dict[str, np.ndarray]], tip_local: np.ndarray,
                axis_local: np.ndarray, pixel_sigma: float, balls: Sequence[Ball] = BALLS) -> Measurement:
    """The tip from the balls found in two views (:func:`find_balls`); ``pixel_sigma`` is the
    calibration's pixel error (rms) carried into the tip's covariance."""
    if len(views) != 2 or len(found) != 2:
        return Measurement(problem=f"two views are needed, {len(found)} given")
    both = [b for b in balls if all(b.name in f for f in found)]
    seen = {v.name: {k: np.asarray(f[k])[:2].tolist() for k in sorted(f)} for v, f in zip(views, found)}  # drawn
    if len(both) < 3:
        return Measurement(pixels=seen, problem=(
            f"the fiducial is hidden: {len(both)} of {len(balls)} balls in both views "
            f"({', '.join(f'{k}: {len(v)}' for k, v in seen.items())}); three are needed"))
    whole = _whole(views, found, both)
    if len(whole) < 3:
        return Measurement(pixels=seen, problem=(
            f"the fiducial is hidden: {len(whole)} of {len(balls)} balls whole in both views "
            f"({len(both)} seen, the others cut by what stands in front); three are needed"))
    both = whole
    model = np.array([b.offset for b in both])
    px = [np.array([f[b.name][:2] for b in both]) for f in found]
    tip, direction, rms, holder = _tip(views, px, model, tip_local, axis_local)
    if rms > MAX_FIT_RMS_M:
        return Measurement(pixels=seen, fit_rms=rms, problem=(
            f"the balls found do not make the fiducial (they sit {rms * 1e3:.2f} mm rms from its "
            f"layout, more than {MAX_FIT_RMS_M * 1e3:g} mm): a wrong blob, or a moved camera"))
    # the pixel error carried through: one column per pixel coordinate of each ball in each view
    eps = 0.05
    cols = []
    for v in range(2):
        for k in range(len(both)):
            for c in range(2):
                moved = [p.copy() for p in px]
                moved[v][k, c] += eps
                cols.append((_tip(views, moved, model, tip_local, axis_local)[0] - tip) / eps)
    J = np.array(cols).T
    cov = pixel_sigma ** 2 * J @ J.T
    return Measurement(tip=tip, direction=direction / np.linalg.norm(direction), covariance=cov,
                       balls=[b.name for b in both],
                       pixels={v.name: {b.name: f[b.name][:2].tolist() for b in both} for v, f in zip(views, found)},
                       fit_rms=rms, holder=holder)
