"""`--live`: the page follows an emulated-rig trial in headless Chromium, its Stop button stops the
trial safely, and the server refuses every request that is not the page's own."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.request
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.live.follow import RunFollower, decimate
from bench.live.server import LiveServer
from bench.trial.margins import margins_of
from bench.trial.plan import prepare
from bench.trial.record import load_record

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

#: The share of deadlines an emulated trial with its page drawing may miss on two cores of its own ...
MISSED_SHARE = 0.01
#: ... and, where it missed more, what the page may add to the same trial without it on this machine
#: (other work on it, or a hypervisor taking its cores, costs the loop its deadlines page or no page).
PAGE_MISSED_SHARE = 0.01
#: How long an emulated trial may take to connect, home and draw its first rows (ms): a wait for the
#: trial to start, not a bound on how fast it starts (beside two CPU hogs and the suite's other worker
#: it has taken over 30 s).
STARTED_MS = 120_000

needs_chromium = pytest.mark.skipif(
    CHROMIUM is None and not os.environ.get("CI"),
    reason="Debian's chromium is not installed (apt-get install chromium); CI installs it")


def _start_live_trial(out: Path) -> tuple[subprocess.Popen, str]:
    """An emulated-rig trial with --live; its URL from the one stderr line that gives it."""
    proc = subprocess.Popen([HILBENCH, "trial", str(LAB), "--emulate", "--live", "--out", str(out), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        found = re.fullmatch(r"live view: (http://127\.0\.0\.1:\d+/\?token=[\w-]+)\n", line)
        if found:
            return proc, found.group(1)
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise AssertionError(f"no live view line; stderr: {line!r}")


def _trial_without_page(out: Path) -> dict:
    """The loop timing of the same emulated-rig trial with no live view."""
    done = subprocess.run([HILBENCH, "trial", str(LAB), "--emulate", "--out", str(out / "no-page"), "--json"],
                          capture_output=True, text=True, timeout=300)
    return json.loads(done.stdout)["loop_timing"]


@pytest.fixture()
def browser():
    playwright = pytest.importorskip("playwright.sync_api")
    assert CHROMIUM is not None, "CI must install Debian's chromium"
    with playwright.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield b
        b.close()


def _points(page) -> int:
    return int(page.evaluate("document.body.dataset.points"))


@needs_chromium
@pytest.mark.alone
def test_the_page_follows_the_trial_and_ends_with_the_logs_verdict_and_margins(tmp_path, browser):
    proc, url = _start_live_trial(tmp_path)
    page = browser.new_page(viewport={"width": 1300, "height": 1000}, bypass_csp=True)  # for the probes
    page.goto(url)
    page.wait_for_function("Number(document.body.dataset.points) > 0", timeout=STARTED_MS)
    # A second client, connected late, gets the run so far. (An HTTP client, not a second page:
    # a browser starting a renderer takes this computer's cores and its kernel's pty service
    # for ~0.1 s, the very hiccup the trial waits for its first page to avoid.)
    base, token = url.split("?")
    with urllib.request.urlopen(f"{base}data?{token}&since=0", timeout=10) as r:
        so_far = json.loads(r.read())
    assert so_far["first"] == 0 and so_far["count"] > 0 and so_far["run"]
    running = []  # the points the page showed, sampled while the trial ran
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and page.evaluate("document.body.dataset.verdict") is None:
        if page.evaluate("document.body.dataset.phase") in ("approach", "insert", "retract"):
            running.append(_points(page))
        time.sleep(0.1)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    result = json.loads(out)
    assert result["live_url"] == url

    log, prep = load_record(Path(result["run_dir"]))
    if log.time[-1] - log.time[0] > 3.0:  # (a trial that lost its bus at once shows little)
        assert len(set(running)) >= 3, running  # the traces advanced as the trial ran
    assert page.evaluate("document.body.dataset.verdict") == ("passed" if result["passed"] else "failed")
    m = margins_of(log, prep)
    gantry_mm = float(m.gantry[-1]) * 1e3
    assert page.inner_text("#gantry") == f"{gantry_mm:.1f} mm"
    worst = int(np.argmin(m.joint_limits[-1]))
    assert page.inner_text("#limit-detail") == log.joint_names[worst]
    share = 1 - m.tracking[-1] / (m.tracking[-1] + np.abs(log.q[-1] - log.q_cmd[-1]))
    assert page.inner_text("#track") == f"{100 * share.max():.1f} %"
    assert ("PASSED" if result["passed"] else f"NOT PASSED: {result['reason']}") in page.inner_text("#verdict")
    cam = result["camera"]  # lab_real.yaml's two cameras: their tip beside the encoders'
    assert f"cameras: tip {cam['encoder_gap_mm']:.2f} mm from the encoders'" in page.inner_text("#verdict")
    assert page.get_attribute("#report-link", "href").startswith("report?token=")
    assert "safe-stop" in page.inner_text("#events")
    tm = result["loop_timing"]  # the loop's timing line ends with the saved log's count
    assert f"{tm['missed']} of {tm['cycles']} deadlines missed" in page.inner_text("#loop")
    # The page drew the whole log, decimated to at most 50 points a second.
    assert _points(page) == len(decimate(log.time, -np.inf)[0])
    # The page drew as it went, and cost the loop nothing it could not afford: the trial waited
    # for the page to open, its server ran in a process of its own, and the loop kept time.
    assert int(page.evaluate("document.body.dataset.draws")) >= 3
    # No other test runs beside this one (it is marked alone). Before the page had its own process
    # and waited to open, 22-27 % were missed and the bus could be lost.
    bound = MISSED_SHARE * tm["cycles"]
    if tm["missed"] > bound:
        # Over the bound: the same trial without the page says what this machine (other work on it,
        # a hypervisor taking its cores) costs the loop by itself; the page may add 1 % to that, and
        # no more. (A machine that misses 7 of 840 alone, 0.8 %, leaves the page 0.2 % under a fixed
        # 1 % bound, a bound the page does not set.)
        alone = _trial_without_page(tmp_path)
        added = tm["missed"] - alone["missed"]
        assert added <= PAGE_MISSED_SHARE * tm["cycles"], (
            f"the page made the loop miss {tm['missed']} of {tm['cycles']} deadlines; without it "
            f"{alone['missed']} of {alone['cycles']}")
        warnings.warn(f"this machine missed {alone['missed']} of {alone['cycles']} deadlines without the "
                      f"page, {tm['missed']} with it: the page added {max(added, 0)}, held to "
                      f"{PAGE_MISSED_SHARE:.0%}")
    assert result["loop_timing"]["priority"].startswith("nice -10") or "refused" in result["loop_timing"]["priority"]
    times = [float(line.split(" s ")[0]) for line in page.inner_text("#events").splitlines()]
    assert times == sorted(times)  # the events in time order


@needs_chromium
def test_stop_in_the_page_stops_the_trial_safely_with_its_log_and_reason(tmp_path, browser):
    proc, url = _start_live_trial(tmp_path)
    page = browser.new_page(bypass_csp=True)
    page.goto(url)
    page.wait_for_function("Number(document.body.dataset.points) > 20", timeout=STARTED_MS)
    page.click("#stop")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    result = json.loads(out)
    assert "live view" in result["reason"] and result["completed"] is False
    assert "torque off" in result["safe_stop"]
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Stop pressed in the live view" in lines[0]  # after the URL line
    log = TrialLog.load(Path(result["run_dir"]) / "trial.npz")
    aborts = [e.message for e in log.events if e.kind == "abort"]
    assert aborts == ["interrupted by SIGINT (Stop pressed in the live view)"]
    assert any(e.kind == "safe-stop" and "confirmed" in e.message for e in log.events)
    # The safe stop the abort caused comes after it, on the page, in the log and in the report.
    kinds = [e.kind for e in log.events]
    assert kinds.index("abort") < kinds.index("safe-stop")
    assert [e.time for e in log.events] == sorted(e.time for e in log.events)
    page.wait_for_function("document.body.dataset.verdict !== undefined", timeout=30_000)
    shown = page.inner_text("#events").splitlines()
    assert [float(line.split(" s ")[0]) for line in shown] == sorted(float(line.split(" s ")[0]) for line in shown)
    assert [i for i, line in enumerate(shown) if "abort:" in line][0] < \
        [i for i, line in enumerate(shown) if "safe-stop:" in line][0]


@pytest.fixture()
def server(tmp_path):
    stops = []
    srv = LiveServer(RunFollower(tmp_path, lambda: prepare(load_trial_config(SIM))), on_stop=lambda: stops.append(1)).start()
    srv.stops = stops
    yield srv
    srv.close(linger=False)


def _request(url: str, method: str = "GET", host: str | None = None) -> int:
    req = urllib.request.Request(url, method=method, headers={"Host": host} if host else {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status
    except urllib.error.HTTPError as e:
        return e.code


def test_the_server_refuses_what_is_not_the_pages_own(server):
    base = server.url.split("?")[0]
    token = server.token
    assert _request(server.url) == 200
    assert _request(f"{base}data?token={token}") == 200
    assert _request(base) == 403  # no token
    wrong = token[:-1] + ("y" if token[-1] == "x" else "x")
    assert _request(f"{base}?token={wrong}") == 403  # a wrong one
    assert _request(f"{base}data") == 403
    for path in ("favicon.ico", "etc/passwd", "../record.json", "report.html", "data/"):
        assert _request(f"{base}{path}?token={token}") == 404, path
    assert _request(server.url, host="evil.example:80") == 403  # a name rebound to the loopback
    assert _request(f"{base}stop?token={token}") == 405  # a link or a prefetch never stops
    assert _request(f"{base}stop", method="POST") == 403 and server.stops == []
    assert _request(f"{base}stop?token={token}", method="POST") == 202 and server.stops == [1]
    assert _request(f"{base}report?token={token}") == 404  # no run yet


def test_a_request_from_another_machine_is_refused(server):
    ok = SimpleNamespace(client_address=("127.0.0.1", 5000), headers={"Host": "127.0.0.1:1"},
                         path=f"/?token={server.token}")
    assert server._allowed(ok) is None
    remote = SimpleNamespace(client_address=("192.0.2.7", 5000), headers={"Host": "127.0.0.1:1"},
                             path=f"/?token={server.token}")
    assert server._allowed(remote) is not None


def _live_trial_on_sim(out: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([HILBENCH, "trial", str(SIM), "--live", "--out", str(out), "--json", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    found = re.fullmatch(r"live view: (http://127\.0\.0\.1:\d+/\?token=[\w-]+)\n", line)
    assert found, line
    return proc, found.group(1)


def test_nothing_moves_until_a_page_opens_and_the_server_is_a_process_of_its_own(tmp_path):
    """--live waits for the page (the browser's costly start comes before the loop does), and the
    page's server runs in a child process at the priority the trial had, never in the trial's."""
    proc, url = _live_trial_on_sim(tmp_path)
    time.sleep(2.0)
    assert proc.poll() is None and not any(tmp_path.iterdir())  # no run directory: nothing moved
    children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
    servers = [int(c) for c in children
               if b"bench.live.process" in Path(f"/proc/{c}/cmdline").read_bytes()]
    assert len(servers) == 1
    assert os.getpriority(os.PRIO_PROCESS, servers[0]) >= os.getpriority(os.PRIO_PROCESS, proc.pid)
    base, token = url.split("?")
    assert _request(f"{base}data?{token}") == 200  # a page's first poll: the trial starts
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert json.loads(out)["passed"] is True
    assert not Path(f"/proc/{servers[0]}").exists()  # the server ended with the trial


def test_without_a_page_the_trial_starts_when_the_wait_is_over(tmp_path):
    began = time.monotonic()
    proc, _ = _live_trial_on_sim(tmp_path, "--live-wait", "1")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert json.loads(out)["passed"] is True and time.monotonic() - began >= 1.0
    assert err.strip() == ""  # a wait that is not on a terminal says nothing: the URL line is the only one


@needs_chromium
def test_the_page_shows_the_twin_and_its_alarm(tmp_path, browser):
    """A monitored trial with a contact on theta5: the page's twin card names the joint nearest its
    threshold and counts the alarm, which the events list shows as it came."""
    data = yaml.safe_load((REPO / "hil_configs" / "sim_target1_servo.yaml").read_text())
    data.update(monitor={"model": "datasheet"},
                faults=[{"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 2.0}])
    config = tmp_path / "touched.yaml"
    config.write_text(yaml.safe_dump(data))
    proc = subprocess.Popen([HILBENCH, "trial", str(config), "--live", "--out", str(tmp_path / "runs"), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url = None
    while url is None:
        line = proc.stderr.readline()
        found = re.fullmatch(r"live view: (http://127\.0\.0\.1:\d+/\?token=[\w-]+)\n", line)
        url = found.group(1) if found else (None if line else pytest.fail("no live view line"))
    page = browser.new_page(viewport={"width": 1300, "height": 1000}, bypass_csp=True)  # for the probes
    page.goto(url)
    page.wait_for_function("document.body.dataset.verdict !== undefined", timeout=60_000)
    out, _ = proc.communicate(timeout=60)
    result = json.loads(out)
    assert [a["joint"] for a in result["monitor"]["alarms"]] == ["theta5"]
    assert page.is_visible("#twin-card")
    t = result["monitor"]["first_alarm_s"]
    assert page.inner_text("#twin") == "theta5 alarm"
    assert page.inner_text("#twin-detail") == f"unlike its model at {t:.2f} s; 1 alarm on 8 joints"
    assert "monitor: theta5 behaves unlike its model" in page.inner_text("#events")
    # the residual panel: every watched joint's detector sum, theta5's crossing the threshold where it alarmed
    assert page.is_visible("#twinplot") and int(page.evaluate("document.body.dataset.twinPoints")) > 100
    drawn = page.evaluate("({labels: twinPlot.series.slice(1).map(s => s.label), data: twinPlot.data})")
    assert drawn["labels"] == [*result["monitor"]["joints"], "alarm threshold"]
    t_drawn = np.array(drawn["data"][0])
    sums = {name: np.array([np.nan if v is None else v for v in drawn["data"][1 + i]], dtype=float)
            for i, name in enumerate(result["monitor"]["joints"])}
    threshold = result["monitor"]["cusum"]["threshold_sigma"]
    assert set(drawn["data"][-1]) == {threshold}
    crossed = t_drawn[np.nan_to_num(sums["theta5"]) >= threshold]
    assert crossed.size and abs(crossed[0] - t) < 0.1, (crossed[:3], t)  # drawn where the alarm came
    assert all(np.nanmax(v) < threshold for name, v in sums.items() if name != "theta5")


def test_a_monitored_runs_rows_carry_each_joints_detector_sum_and_an_unwatched_joint_none(tmp_path):
    """The follower's rows of a finished monitored trial (the page's increments): the detector's sums
    beside the positions, the train (read by its sensor, not watched) NaN, the contacted joint's
    crossing the threshold at the alarm; a trial without a monitor sends the positions only."""
    import base64

    data = yaml.safe_load((REPO / "hil_configs" / "sim_target1_servo.yaml").read_text())
    data.update(monitor={"model": "datasheet"},
                faults=[{"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 2.0}])
    config = tmp_path / "touched.yaml"
    config.write_text(yaml.safe_dump(data))
    follower = RunFollower(tmp_path / "runs", lambda: prepare(load_trial_config(config)))
    res = subprocess.run([HILBENCH, "trial", str(config), "--out", str(tmp_path / "runs"), "--json"],
                         capture_output=True, text=True, timeout=300)
    result = json.loads(res.stdout)
    snap = follower.poll().since(0)
    n = len(snap["joints"])
    assert snap["twin_columns"] is True and snap["twin"]["threshold"] == 12.0
    rows = np.frombuffer(base64.b64decode(snap["rows"]), dtype="<f8").reshape(snap["count"], 1 + 3 * n)
    sums = rows[:, 1 + 2 * n:]
    watched = [snap["joints"].index(j) for j in result["monitor"]["joints"]]
    assert np.isfinite(sums[:, watched]).all() and np.isnan(np.delete(sums, watched, axis=1)).all()
    j5 = snap["joints"].index("theta5")
    first = rows[np.argmax(sums[:, j5] >= 12.0), 0]
    assert abs(first - result["monitor"]["first_alarm_s"]) < 0.05
    plain = RunFollower(tmp_path / "plain", lambda: prepare(load_trial_config(SIM)))
    subprocess.run([HILBENCH, "trial", str(SIM), "--out", str(tmp_path / "plain"), "--json"],
                   capture_output=True, text=True, timeout=300, check=True)
    snap = plain.poll().since(0)
    assert snap["twin_columns"] is False
    assert len(base64.b64decode(snap["rows"])) == 8 * snap["count"] * (1 + 2 * len(snap["joints"]))
