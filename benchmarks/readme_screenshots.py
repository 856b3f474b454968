"""The README's pictures of the live view, the register view and an export, each from a real run,
photographed with headless Chromium.

* ``live-view.png``: ``hilbench trial hil_configs/lab_real.yaml --emulate --live`` opened in
  Chromium (playwright) and taken during the insertion.
* ``registers.png``: ``hilbench registers --port PTY --baud B --id 3 --watch`` run in a
  pseudo-terminal against the lab's emulated rig while θ4 is jogged 300 ticks, its last frame
  rendered as the terminal shows it (Rich's SVG export of the ANSI output).
* ``live-twin.png``: the live page of a monitored servo-model sim trial with a contact on θ5
  (``monitor: {model: datasheet}``, ``contact`` 0.3 N·m from 2 s), at its end.
* ``export.png``: ``hilbench export RUN --mcap FILE`` of a sim trial, read back with the ``mcap``
  reader: every topic with its ROS 2 type, message count and last message, and the metadata.

Needs Debian's ``chromium`` and the test extra (``playwright``, ``pexpect``). Writes into
``--out`` (default ``runs/screenshots``); the README's copies live in ``docs/``.

    python benchmarks/readme_screenshots.py [--out DIR] [--only live,registers,export,twin]
"""

from __future__ import annotations

import argparse
import html
import io
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from report_screenshots import HILBENCH, REPO, _chromium, screenshot
from rich.console import Console
from rich.text import Text

from bench.config.models import load_trial_config
from bench.rig.emulated import EmulatedRig
from drivers.dynamixel.control_table import XM430_W350, model_spec

LAB = REPO / "hil_configs" / "lab_real.yaml"
SIM = REPO / "hil_configs" / "sim_target1.yaml"
#: A terminal's control sequences other than colours (cursor moves, line erases, cursor shown/hidden).
_CONTROL = re.compile(r"\x1b\[(?:\?25[lh]|\d*[ABCDGKJ]|2K)|\r")


def _live_page(png: Path, args: list[str], work: Path, ready: str, settle_s: float) -> Path:
    """``hilbench trial ARGS --live`` opened in Chromium, photographed once ``ready`` (a selector)
    matches and ``settle_s`` more have been drawn."""
    from playwright.sync_api import sync_playwright  # the test extra

    trial = subprocess.Popen([HILBENCH, "trial", *args, "--live", "--out", str(work)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        url = ""
        while not url:
            line = trial.stderr.readline()
            if not line:
                raise SystemExit("the trial ended before its live view started")
            url = line.split("live view: ", 1)[1].strip() if "live view: " in line else ""
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=_chromium(), args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(url)
            page.wait_for_selector(ready, timeout=300_000)
            time.sleep(settle_s)
            page.screenshot(path=str(png))
            browser.close()
    finally:
        trial.wait(timeout=300)
    return png


def live_view(png: Path, work: Path) -> Path:
    """The live page of an emulated-rig trial, taken once the insertion has drawn a while (a few of
    its polls)."""
    return _live_page(png, [str(LAB), "--emulate"], work, 'body[data-phase="insert"]', 1.2)


def twin_view(png: Path, work: Path) -> Path:
    """The live page of a monitored servo-model sim trial with a 0.3 N·m contact on θ5 from 2 s, at
    its end (the final rows drawn): the twin's card and residual panel with the alarm."""
    data = yaml.safe_load((REPO / "hil_configs" / "sim_target1_servo.yaml").read_text())
    data.update(monitor={"model": "datasheet"},
                faults=[{"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 2.0}])
    config = work / "contact.yaml"
    config.write_text(yaml.safe_dump(data))
    return _live_page(png, [str(config), "--live-wait", "1"], work, "body[data-verdict]", 0.8)


def registers_view(png: Path, work: Path) -> Path:
    """``registers --watch`` in a terminal while another master jogs θ4, its last frame pictured."""
    import pexpect  # the test extra

    cfg = load_trial_config(LAB)
    table = model_spec(XM430_W350).table
    with EmulatedRig(cfg) as rig:
        rig_cfg = rig.retarget(cfg)
        sid = rig_cfg.backend.servos["theta4"].id
        child = pexpect.spawn(HILBENCH, ["registers", "--port", rig_cfg.backend.port, "--baud",
                                         str(rig_cfg.backend.baud), "--id", str(sid), "--watch"],
                              env={**os.environ, "LINES": "200", "COLUMNS": "96"}, encoding="utf-8",
                              dimensions=(200, 96), timeout=60)
        child.logfile_read = shown = io.StringIO()
        row = r"Present Position\W+%d\W+4\W+R\W+(-?\d+)" % table["Present Position"].address
        child.expect(row)
        goal = int(child.match.group(1)) + 300
        servo = rig.bus.servo(sid)
        slow = int(table["Profile Velocity"].from_si(0.4))
        with rig.bus.lock:  # the jog, as the servo applies `hilbench jog`'s writes
            servo.write(table["Profile Velocity"].address, slow.to_bytes(4, "little"))
            servo.write(table["Torque Enable"].address, bytes([1]))
            servo.write(table["Goal Position"].address, goal.to_bytes(4, "little", signed=True))
        for _ in range(3):  # halfway there: a few refreshes after the jog began
            child.expect(row)
        child.expect("┘")  # that frame drawn whole
        child.sendintr()
        child.expect(pexpect.EOF)
    frames = _CONTROL.sub("", shown.getvalue()).split("servo ID")
    frame = "servo ID" + next(f for f in reversed(frames) if "┘" in f).split("┘")[0] + "┘"
    console = Console(record=True, width=96, file=io.StringIO(), force_terminal=True, color_system="truecolor")
    console.print(Text.from_ansi(frame), end="")
    svg = work / "registers.svg"
    svg.write_text(console.export_svg(title=f"hilbench registers --port {rig_cfg.backend.port} --baud "
                                            f"{rig_cfg.backend.baud} --id {sid} --watch"))
    page = work / "registers.html"
    page.write_text(f"<!doctype html><body style='margin:0;background:#fff'>"
                    f"<img src='{svg.name}' style='width:880px;display:block'></body>")
    return screenshot(page, png, 880, 1400)


def export_view(png: Path, work: Path) -> Path:
    """A sim trial exported to MCAP and read back: topics, types, counts, last messages, metadata."""
    done = subprocess.run([HILBENCH, "trial", str(SIM), "--out", str(work), "--json"],
                          capture_output=True, text=True, timeout=600, cwd=REPO)
    run_dir = Path(json.loads(done.stdout)["run_dir"])
    mcap = work / "trial.mcap"
    subprocess.run([HILBENCH, "export", str(run_dir), "--mcap", str(mcap)], check=True, capture_output=True,
                   timeout=300, cwd=REPO)
    topics: dict[str, dict] = {}
    with open(mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            t = topics.setdefault(channel.topic, {"type": schema.name, "count": 0, "t0": message.log_time})
            t["count"] += 1
            t["t1"], t["last"] = message.log_time, decoded
        meta = {r.name: sorted(r.metadata) for r in reader.iter_metadata()}
    rows = "".join(
        f"<tr><td><code>{html.escape(name)}</code></td><td>{html.escape(t['type'])}</td>"
        f"<td class=n>{t['count']}</td><td class=n>{(t['t1'] - t['t0']) * 1e-9:.2f}</td>"
        f"<td class=m>{html.escape(_gist(t['last']))}</td></tr>" for name, t in topics.items())
    records = "".join(f"<li><code>{html.escape(k)}</code>: {html.escape(', '.join(v))}</li>" for k, v in meta.items())
    page = work / "export.html"
    page.write_text(f"""<!doctype html><meta charset=utf-8><style>
body {{ font: 14px system-ui, sans-serif; margin: 18px; color: #1d2430; }}
h1 {{ font-size: 17px; margin: 0 0 4px; }} p {{ margin: 0 0 10px; color: #5a6474; }}
table {{ border-collapse: collapse; width: 100%; }} td, th {{ border-bottom: 1px solid #dde2ea; padding: 5px 8px;
text-align: left; vertical-align: top; }} th {{ background: #f4f6f9; white-space: nowrap; }} .n {{ text-align: right; }}
.m {{ font: 12px ui-monospace, monospace; color: #3a4456; }} ul {{ margin: 6px 0; }}</style>
<h1>{html.escape(mcap.name)}, read back with the <code>mcap</code> reader ({mcap.stat().st_size // 1024} kB)</h1>
<p><code>hilbench export {html.escape(run_dir.name)} --mcap {html.escape(mcap.name)}</code>:
a sim trial of hil_configs/{SIM.name}, as Foxglove and PlotJuggler open it; values in SI (rad, m)</p>
<table><tr><th>topic</th><th>ROS 2 type</th><th class=n>messages</th><th class=n>span (s)</th>
<th>last message</th></tr>{rows}</table>
<p style="margin-top:12px">Metadata records (name: keys)</p><ul>{records}</ul>""")
    return screenshot(page, png, 1100, 1400)


def _gist(msg) -> str:
    """A message's gist in one line: joint names and positions, a number, a text."""
    if hasattr(msg, "position"):
        return " ".join(f"{n}={v:.4g}" for n, v in zip(msg.name, msg.position))
    if hasattr(msg, "point"):
        return f"x={msg.point.x:.4g} y={msg.point.y:.4g} z={msg.point.z:.4g} ({msg.header.frame_id})"
    if hasattr(msg, "msg"):
        return msg.msg[:110]
    return f"{msg.data:.4g}" if isinstance(msg.data, float) else str(msg.data)[:110]


def _palette(png: Path, colours: int = 96) -> Path:
    """The picture in at most ``colours`` colours (text and plots lose nothing seen; a third the bytes)."""
    from PIL import Image  # matplotlib's own dependency

    with Image.open(png) as img:
        small = img.convert("RGB").quantize(colors=colours, method=Image.Quantize.MEDIANCUT)
    small.save(png, optimize=True)
    return png


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "screenshots")
    ap.add_argument("--only", default="live,registers,export,twin", help="Which pictures, comma-separated.")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    makers = {"live": (live_view, "live-view.png"), "registers": (registers_view, "registers.png"),
              "export": (export_view, "export.png"), "twin": (twin_view, "live-twin.png")}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only.split(","):
            make, file = makers[name]
            work = Path(tmp) / name
            work.mkdir()
            png = _palette(make(args.out / file, work))
            print(f"{name:>10}: {png} ({png.stat().st_size // 1024} kB)", flush=True)
    sys.exit(0)


if __name__ == "__main__":
    main()
