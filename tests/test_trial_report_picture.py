"""The trial report's robot picture shows the planned needle path and the placed needle, with a
caption saying which is which; the placement table names the entry point its columns hold."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.scene.render import APPROACH_RGBA, NEEDLE_RGBA, SIDE_VIEW, TARGET_RGBA

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _pixels_near(img: np.ndarray, rgba, tol: float = 0.12) -> int:
    return int((np.abs(img[:, :, :3] - np.asarray(rgba[:3])) < tol).all(axis=2).sum())


def test_the_robot_picture_shows_target_and_needle_with_a_caption(tmp_path):
    import matplotlib.image as mpimg  # heavy: matplotlib, only to read the picture back

    done = subprocess.run([HILBENCH, "trial", str(SIM), "--out", str(tmp_path), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    run = Path(json.loads(done.stdout)["run_dir"])
    img = mpimg.imread(run / "robot.png")
    assert _pixels_near(img, TARGET_RGBA) > 60  # the red insertion, 30 mm
    assert _pixels_near(img, APPROACH_RGBA) > 60  # the orange approach above it, 30 mm
    assert _pixels_near(img, NEEDLE_RGBA) > 20  # the green entry point and tip
    md = (run / "report.md").read_text()
    assert f"seen {SIDE_VIEW}" in md
    assert "Red: the planned insertion" in md and "orange: the planned approach" in md
    assert "green: the entry point and tip" in md and "the bed in grey" in md
    assert "| | entry point X (mm) | entry point Y (mm) | entry point Z (mm) |" in md
    html = (run / "report.html").read_text()
    assert "<em>The robot at the end of the insertion" in html


def test_the_robot_picture_is_framed_on_the_robot_and_seen_from_the_side_it_names(tmp_path):
    """Seen along the bed's axis the insertion's angle shows true: the red rod in the picture lies
    at the target's angle; the robot fills the frame, and the bed is whole, cut by no edge."""
    import matplotlib.image as mpimg  # heavy: matplotlib, only to read the picture back

    from bench.config.models import load_trial_config
    from bench.scene.render import render_robot
    from bench.trial.plan import prepare

    prep = prepare(load_trial_config(SIM))
    img = mpimg.imread(render_robot("arc-train", prep.q_insert, tmp_path / "robot.png", target=prep.target))
    h, w = img.shape[:2]
    red = (np.abs(img[:, :, :3] - np.asarray(TARGET_RGBA[:3])) < 0.15).all(axis=2)
    rows, cols = np.nonzero(red)
    pts = np.stack([cols, rows]).astype(float)  # image rows grow downwards
    axis = np.linalg.eigh(np.cov(pts))[1][:, -1]  # the rod's long axis
    seen = np.degrees(np.arctan(abs(axis[1] / axis[0])))
    d = prep.target.direction
    assert seen == pytest.approx(np.degrees(np.arctan2(-d[2], d[1])), abs=4.0)
    drawn = (img[:, :, :3] < 0.9).any(axis=2)  # anything not the white background
    rows, cols = np.nonzero(drawn)
    assert (cols.max() - cols.min()) > 0.8 * w and (rows.max() - rows.min()) > 0.6 * h
    assert not drawn[:, 0].any() and not drawn[:, -1].any()  # nothing cut at the sides: the bed whole
