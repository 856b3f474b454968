"""The control loop never waits for the live view: a page whose poll is stuck, and browsers that
connect and never finish a request, leave a trial to run to its end with its whole log."""

from __future__ import annotations

import base64
import json
import socket
import threading
import urllib.request
from pathlib import Path

import numpy as np

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.live.follow import RunFollower
from bench.live.server import LiveServer
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"


class _StuckFollower(RunFollower):
    """A follower whose every poll blocks (holding its lock) until the test lets it go."""

    def __init__(self, *args, release: threading.Event, entered: threading.Event) -> None:
        super().__init__(*args)
        self.release, self.entered = release, entered

    def poll(self):
        with self._lock:
            self.entered.set()
            self.release.wait(120)
        return super().poll()


def test_a_stuck_page_and_half_open_connections_never_hold_the_trial(tmp_path, capfd):
    prep = prepare(load_trial_config(FAST))
    release, entered = threading.Event(), threading.Event()
    server = LiveServer(_StuckFollower(tmp_path, lambda: prep, release=release, entered=entered),
                        on_stop=lambda: None).start()
    host, port = server.url.split("//")[1].split("/")[0].split(":")
    half_open = [socket.create_connection((host, int(port))) for _ in range(3)]
    for s in half_open:  # a request line and no end of headers, ever
        s.sendall(b"GET /data?token=" + server.token.encode() + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    answers: list[bytes] = []
    page = threading.Thread(target=lambda: answers.append(urllib.request.urlopen(
        server.url.replace("/?", "/data?"), timeout=120).read()), daemon=True)
    page.start()
    try:
        assert entered.wait(30)  # the page's poll is in, and stuck
        result: list = []
        trial = threading.Thread(target=lambda: result.append(
            run_trial(prep, tmp_path, TrialHooks(report=False))), daemon=True)
        trial.start()
        trial.join(120)
        assert not trial.is_alive(), "the trial waited for the page"
        assert page.is_alive() and not answers  # the page is still waiting for its answer
        (res,) = result
        assert res.completed and res.passed, res.reason
        log = TrialLog.load(res.run_dir / "trial.npz")
        assert len(log) > 1000 and log.segment[-1] == len(log.segment_names) - 1  # to its last segment
    finally:
        release.set()
        page.join(30)
        for s in half_open:
            s.close()
        server.close(linger=False)
    # once let go, the page gets its answer: the finished run, its joints read from its saved log
    (answer,) = answers
    data = json.loads(answer)
    assert data["result"]["passed"] is True and data["joints"] == list(prep.robot.joint_names)
    assert data["count"] > 100 and data["phase"] == "done"
    rows = np.frombuffer(base64.b64decode(data["rows"]), dtype="<f8").reshape(data["count"], -1)
    assert rows.shape[1] == 1 + 2 * len(data["joints"]) and np.all(np.diff(rows[:, 0]) > 0)
    assert np.isfinite(rows).all()
    # browsers that went away mid-request print nothing on the operator's console
    assert capfd.readouterr().err == ""
