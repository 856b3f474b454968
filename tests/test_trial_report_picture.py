"""The trial report's robot picture shows the planned needle path and the placed needle, with a
caption saying which is which; the placement table names the entry point its columns hold."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from bench.scene.render import NEEDLE_RGBA, TARGET_RGBA

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
    assert _pixels_near(img, TARGET_RGBA) > 200  # the red path, a rod some 60 mm long
    assert _pixels_near(img, NEEDLE_RGBA) > 20  # the green entry point and tip
    md = (run / "report.md").read_text()
    assert "Red: the planned needle path" in md and "green: the entry point and tip" in md
    assert "| | entry point X (mm) | entry point Y (mm) | entry point Z (mm) |" in md
    html = (run / "report.html").read_text()
    assert "<em>The robot at the end of the insertion" in html
