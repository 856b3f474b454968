"""The cameras in a trial's report: both views of the end of the insertion with the fiducial's
balls found, the needle's axis and tip as the cameras measured them and the encoders' tip drawn
on them (cameras.png), and the cameras' figures beside the encoders' (a table)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from bench.cameras.rig import view_of
from bench.core.seen import COVERAGE

__all__ = ["camera_markdown", "draw_camera_views"]

#: Colours (BGR) drawn: the balls found, the cameras' needle and tip, the encoders' tip.
_BALL, _CAMERA, _ENCODERS = (255, 255, 255), (40, 200, 40), (40, 40, 230)
_HALF = (640, 360)  # each full view, shrunk; each close-up, cut at full resolution


def _project(view, points: np.ndarray) -> np.ndarray:
    import cv2  # heavy: OpenCV, only when a report is drawn

    px, _ = cv2.projectPoints(np.asarray(points, dtype=float).reshape(-1, 3),
                              cv2.Rodrigues(view.pose.rotation)[0], view.pose.translation,
                              view.intrinsics.matrix, view.intrinsics.dist)
    return px.reshape(-1, 2)


def draw_camera_views(run_dir: Path, cameras_config, measured: dict, encoder_tip: Optional[np.ndarray],
                      path: Path) -> Optional[Path]:
    """cameras.png: for each view, the whole frame (top) and a close-up around the needle at full
    resolution (bottom), with the balls found (white rings), the cameras' needle axis and tip
    (green) and the encoders' tip (red cross). None when there is no end-of-insertion capture."""
    import cv2  # heavy: OpenCV, only when a report is drawn

    cap = (measured or {}).get("captures", {}).get("insert") or {}
    if not cap.get("frames"):
        return None
    columns = []
    for cam in cameras_config.views:
        name = cap["frames"].get(cam.name)
        image = None if name is None else cv2.imread(str(Path(run_dir) / name))
        if image is None:
            continue
        view = view_of(cam)
        marks = []
        for u, v in (cap.get("pixels", {}).get(cam.name) or {}).values():
            marks.append(("ball", (u, v)))
        if cap.get("tip_m") is not None:
            tip = np.asarray(cap["tip_m"])
            back = tip - 0.12 * np.asarray(cap["direction"])
            (tu, tv), (bu, bv) = _project(view, np.array([tip, back]))
            marks += [("axis", (bu, bv, tu, tv)), ("tip", (tu, tv))]
        if encoder_tip is not None:
            marks.append(("encoders", tuple(_project(view, encoder_tip)[0])))
        centre = next((m[1] for m in marks if m[0] == "tip"), None) or next(
            (m[1] for m in marks if m[0] == "ball"), (image.shape[1] / 2, image.shape[0] / 2))
        full = _drawn(cv2, image.copy(), marks, 2)
        w, h = _HALF
        x0 = int(np.clip(centre[0] - w / 2, 0, image.shape[1] - w))
        y0 = int(np.clip(centre[1] - h / 2 - h / 6, 0, image.shape[0] - h))
        close = _drawn(cv2, image.copy(), marks, 1)[y0:y0 + h, x0:x0 + w]
        whole = cv2.resize(full, _HALF, interpolation=cv2.INTER_AREA)
        cv2.rectangle(whole, (x0 // 2, y0 // 2), ((x0 + w) // 2, (y0 + h) // 2), (255, 255, 255), 1)
        cv2.putText(whole, cam.name, (12, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 3)
        cv2.putText(whole, cam.name, (12, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (20, 20, 20), 1)
        columns.append(cv2.vconcat([whole, close]))
    if not columns:
        return None
    cv2.imwrite(str(path), cv2.hconcat(columns))
    return path


def _drawn(cv2, image: np.ndarray, marks: list, scale: int) -> np.ndarray:
    """The marks drawn, their lines ``scale`` pixels wide (the whole frame is shrunk after)."""
    s = 16  # sub-pixel positions: OpenCV's shift of 4 bits
    p = lambda u, v: (int(round(u * s)), int(round(v * s)))  # noqa: E731
    for kind, at in marks:
        if kind == "ball":
            cv2.circle(image, p(*at), 9 * s, _BALL, scale, cv2.LINE_AA, 4)
        elif kind == "axis":
            cv2.line(image, p(at[0], at[1]), p(at[2], at[3]), _CAMERA, scale, cv2.LINE_AA, 4)
        elif kind == "tip":
            cv2.circle(image, p(*at), 6 * s, _CAMERA, scale + 1, cv2.LINE_AA, 4)
        else:
            u, v = at
            cv2.line(image, p(u - 8, v - 8), p(u + 8, v + 8), _ENCODERS, scale + 1, cv2.LINE_AA, 4)
            cv2.line(image, p(u - 8, v + 8), p(u + 8, v - 8), _ENCODERS, scale + 1, cv2.LINE_AA, 4)
    return image


def camera_markdown(camera: dict, outcome, judged_by: str, figure: Optional[str]) -> str:
    """The cameras' tip beside the encoders', the gap, the uncertainty and the flag."""
    lines = []
    if camera.get("tip_deviation_mm") is None:
        lines += [f"The cameras did not measure the tip: {camera.get('problem') or 'no capture'}.", ""]
    else:
        enc = outcome.tip_deviation_mm if (outcome is not None and judged_by == "encoders") else None
        f = lambda v: "—" if v is None else f"{v:+.2f}"  # noqa: E731
        lines += ["| tip deviation from the target | X (mm) | Y (mm) | Z (mm) | angle (°) |",
                  "|---|---:|---:|---:|---:|"]
        if enc is not None:
            lines.append(f"| encoders (forward kinematics) | {f(enc[0])} | {f(enc[1])} | {f(enc[2])} | "
                         f"{f(outcome.angle_deviation_deg)} |")
        c = camera["tip_deviation_mm"]
        lines += [f"| cameras | {f(c[0])} | {f(c[1])} | {f(c[2])} | {f(camera['angle_deviation_deg'])} |", ""]
        gap = camera.get("encoder_gap_mm")
        flag = camera.get("flag")
        lines += [f"- gap between the encoders' tip and the cameras': "
                  f"{'—' if gap is None else f'{gap:.2f} mm'}; the cameras' uncertainty "
                  f"{camera['uncertainty_mm']:.2f} mm ({COVERAGE:g} σ)"
                  + (f", the encoders' {camera['encoder_uncertainty_mm']:.2f} mm"
                     if camera.get("encoder_uncertainty_mm") is not None else "")
                  + ("; **flagged: the encoders do not say where the needle is**" if flag else ""),
                  f"- judged by: {judged_by}", ""]
    if figure:
        lines += [f"![the two views at the end of the insertion]({figure})", "",
                  "*The front and top views at the end of the insertion: whole (top) and around the "
                  "needle at full resolution (bottom). White rings: the holder's balls found; green: "
                  "the needle's axis and tip as the cameras measured them; red cross: the tip where "
                  "the encoders put it.*", ""]
    return "\n".join(lines)
