"""Every kind of HTML report, built small and photographed with headless Chromium at 1280 px.

Builds a passed trial, a trial stopped by an interlock, a sim-vs-sim compare of two
runs, a compare of the emulated rig with the servo-model sim's prediction, a 12-trial
tolerance campaign and the arc-train accuracy budget, then writes
one full-page PNG per report into ``--out`` (default ``runs/screenshots``) so a
person can look at what a technician will see. Needs Debian's ``chromium``.

Each page is also checked in the browser at the same width, and the script exits 1
naming every problem: blocks (headings, paragraphs, tables, figures, captions) that
overlap, a page or a table cell wider than the window, an image that did not load or
shows nothing (one flat colour), a figure without its picture.

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
    hilbench("compare", str(REPO / "hil_configs" / "lab_real.yaml"), "--emulate", "--repeats", "2",
             "--sim-model", "datasheet", "--out", str(work / "prediction"))
    spec = yaml.safe_load((REPO / "hil_configs" / "campaigns" / "tolerance_sweep.yaml").read_text())
    spec.update(samples=12, base=str(REPO / "hil_configs" / "sim_target1_fast.yaml"))
    (work / "campaign.yaml").write_text(yaml.safe_dump(spec))
    hilbench("campaign", str(work / "campaign.yaml"), "--out", str(work / "campaign"), "--workers", "2")
    hilbench("accuracy", "arc-train", "--out", str(work / "accuracy"))
    return {"trial-passed": run_a / "report.html",
            "trial-stopped": only_dir(work / "stopped") / "report.html",
            "compare": next((work / "compare").rglob("report.html")),
            "compare-prediction": next((work / "prediction").glob("*/report.html")),
            "campaign": work / "campaign" / "report.html",
            "accuracy": next((work / "accuracy").rglob("*.html"))}


def screenshot(html: Path, png: Path, width: int, height: int = 6000) -> Path:
    """A full-height PNG of the page at ``width`` px (the empty space below is trimmed)."""
    subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--window-size={width},{height}", f"--screenshot={png}", html.as_uri()],
                   capture_output=True, timeout=120, check=True)
    _trim(png)
    return png


#: Run in the page once it has loaded; leaves its findings as JSON in <pre id="layout-check">.
LAYOUT_CHECK = r"""
<script>
window.addEventListener('load', () => {
  const W = document.documentElement.clientWidth, problems = [];
  const name = (el) => el.tagName.toLowerCase() + (el.id ? '#' + el.id : '') +
      ' "' + (el.getAttribute('alt') || el.textContent || '').trim().slice(0, 40) + '"';
  if (document.documentElement.scrollWidth > W + 1)
    problems.push(`the page is ${document.documentElement.scrollWidth} px wide in a ${W} px window`);
  for (const img of document.images) {
    const r = img.getBoundingClientRect();
    if (!img.complete || img.naturalWidth === 0) problems.push(`${name(img)} did not load`);
    else if (r.right > W + 1) problems.push(`${name(img)} runs ${Math.round(r.right - W)} px past the window`);
  }
  for (const fig of document.querySelectorAll('figure'))
    if (!fig.querySelector('img, svg, canvas')) problems.push(`${name(fig)} has no picture`);
  for (const cell of document.querySelectorAll('td, th, pre, code'))
    if (cell.scrollWidth > cell.clientWidth + 1 && getComputedStyle(cell).overflowX === 'visible')
      problems.push(`${name(cell)} overflows its box by ${cell.scrollWidth - cell.clientWidth} px`);
  const blocks = [...document.querySelectorAll('h1,h2,h3,h4,p,li,table,img,figure,figcaption,pre,svg,dl')]
      .filter((el) => el.getClientRects().length);
  for (let i = 0; i < blocks.length; i++)
    for (let j = i + 1; j < blocks.length; j++) {
      const a = blocks[i], b = blocks[j];
      if (a.contains(b) || b.contains(a)) continue;
      const p = a.getBoundingClientRect(), q = b.getBoundingClientRect();
      const w = Math.min(p.right, q.right) - Math.max(p.left, q.left);
      const h = Math.min(p.bottom, q.bottom) - Math.max(p.top, q.top);
      if (w > 2 && h > 2) problems.push(`${name(a)} and ${name(b)} overlap (${Math.round(w)}×${Math.round(h)} px)`);
    }
  const out = document.createElement('pre');
  out.id = 'layout-check';
  out.textContent = JSON.stringify(problems);
  document.body.appendChild(out);
});
</script>
"""


def layout_problems(html: Path, width: int, height: int = 6000) -> list[str]:
    """What a person would see wrong on the page at ``width`` px (see :data:`LAYOUT_CHECK`)."""
    import base64
    import html as html_lib
    import json
    import re

    import matplotlib.image as mpimg
    import numpy as np

    probe = html.with_name(f".layout-check-{html.name}")
    text = html.read_text()
    probe.write_text(text.replace("</body>", LAYOUT_CHECK + "</body>") if "</body>" in text
                     else text + LAYOUT_CHECK)
    try:
        res = subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu",
                              "--hide-scrollbars", "--virtual-time-budget=10000",
                              f"--window-size={width},{height}", "--dump-dom", probe.as_uri()],
                             capture_output=True, text=True, timeout=120, check=True)
    finally:
        probe.unlink(missing_ok=True)
    found = re.search(r'<pre id="layout-check">(.*?)</pre>', res.stdout, flags=re.S)
    if found is None:
        return ["the layout check did not run (the page never finished loading)"]
    problems = json.loads(html_lib.unescape(found.group(1)))
    # An image that loaded but shows nothing: one flat colour (an empty plot saved as a PNG).
    for src in re.findall(r'<img[^>]*src="([^"]+)"', text):
        try:
            if src.startswith("data:image/png;base64,"):
                import io

                img = mpimg.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])), format="png")
            elif src.endswith(".png"):
                img = mpimg.imread(html.parent / src)
            else:
                continue
        except (OSError, ValueError):
            continue  # a missing file is reported by the browser above
        if float(np.asarray(img)[..., :3].std()) < 1e-3:
            problems.append(f"image {src[:40]} is one flat colour")
    return problems


def _chromium() -> str:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    return chromium


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
    failed = False
    with tempfile.TemporaryDirectory() as tmp:
        for kind, html in build_reports(Path(tmp)).items():
            png = screenshot(html, args.out / f"{kind}.png", args.width)
            problems = layout_problems(html, args.width)
            failed |= bool(problems)
            print(f"{kind:>18}: {png}  " + ("layout ok" if not problems else f"{len(problems)} problem(s)"))
            for p in problems:
                print(f"{'':>20}- {p}")
    raise SystemExit(1 if failed else 0)


if __name__ == "__main__":
    main()
