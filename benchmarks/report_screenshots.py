"""Every kind of HTML report, built small and photographed with headless Chromium at 1280 px.

Builds a passed trial, a trial stopped by an interlock, a sim-vs-sim compare of two
runs, a 12-trial tolerance campaign and the arc-train accuracy budget, then writes
one full-page PNG per report into ``--out`` (default ``runs/screenshots``) so a
person can look at what a technician will see. Needs Debian's ``chromium``.

    python benchmarks/report_screenshots.py [--out DIR] [--width 1280]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def hilbench(*args: str) -> None:
    res = subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=900, cwd=REPO)
    if res.returncode not in (0, 1):  # 1: a failed trial or campaign still writes its report
        raise SystemExit(f"hilbench {' '.join(args)} failed ({res.returncode}): {res.stderr}")


def only_dir(parent: Path) -> Path:
    return next(d for d in sorted(parent.iterdir()) if d.is_dir())


def build_reports(work: Path) -> dict[str, Path]:
    """Each report kind's HTML file, built in ``work``."""
    sim = REPO / "hil_configs" / "sim_target1.yaml"
    data = yaml.safe_load(sim.read_text())
    data.update(name="stopped-by-interlock")
    data["safety"] = {**data.get("safety", {}), "tracking_error_deg": 0.012}  # the sim tracks within ~0.015°
    stopped = work / "stopped.yaml"
    stopped.write_text(yaml.safe_dump(data))
    hilbench("trial", str(sim), "--out", str(work / "passed"))
    hilbench("trial", str(sim), "--out", str(work / "passed2"))
    hilbench("trial", str(stopped), "--out", str(work / "stopped"))
    run_a, run_b = only_dir(work / "passed"), only_dir(work / "passed2")
    hilbench("compare", str(run_a), str(run_b), "--out", str(work / "compare"))
    spec = yaml.safe_load((REPO / "hil_configs" / "campaigns" / "tolerance_sweep.yaml").read_text())
    spec.update(samples=12, base=str(REPO / "hil_configs" / "sim_target1_fast.yaml"))
    (work / "campaign.yaml").write_text(yaml.safe_dump(spec))
    hilbench("campaign", str(work / "campaign.yaml"), "--out", str(work / "campaign"), "--workers", "2")
    hilbench("accuracy", "arc-train", "--out", str(work / "accuracy"))
    return {"trial-passed": run_a / "report.html",
            "trial-stopped": only_dir(work / "stopped") / "report.html",
            "compare": next((work / "compare").rglob("report.html")),
            "campaign": work / "campaign" / "report.html",
            "accuracy": next((work / "accuracy").rglob("*.html"))}


def screenshot(html: Path, png: Path, width: int, height: int = 6000) -> Path:
    """A full-height PNG of the page at ``width`` px (the empty space below is trimmed)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--window-size={width},{height}", f"--screenshot={png}", html.as_uri()],
                   capture_output=True, timeout=120, check=True)
    _trim(png)
    return png


def _trim(png: Path) -> None:
    """Cut the white space under the page's last line."""
    import matplotlib.image as mpimg
    import numpy as np

    img = mpimg.imread(png)
    ink = np.flatnonzero((img[..., :3] < 0.97).any(axis=(1, 2)))
    if ink.size:
        mpimg.imsave(png, img[: min(ink[-1] + 40, img.shape[0])])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "screenshots")
    ap.add_argument("--width", type=int, default=1280)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for kind, html in build_reports(Path(tmp)).items():
            png = screenshot(html, args.out / f"{kind}.png", args.width)
            print(f"{kind:>14}: {png}")


if __name__ == "__main__":
    main()
