"""`hilbench export RUN_DIR --mcap FILE`: a trial as ROS 2 messages in MCAP, read back exactly."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from cli_in_process import invoke as _invoke
from bench.scene.contact import GantryClearance
from bench.trial.record import load_record

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    done = _invoke("trial", str(SIM), "--out", str(out), "--json")
    assert done.exit_code == 0, done.stderr
    return Path(json.loads(done.stdout)["run_dir"])


def _read(path: Path):
    """Every message by topic (schema name, decoded message, log time) and the metadata records."""
    topics, meta = defaultdict(list), {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            topics[channel.topic].append((schema.name, decoded, message.log_time))
        for record in reader.iter_metadata():
            meta[record.name] = record.metadata
    assert summary.statistics.message_count == sum(len(v) for v in topics.values())
    return topics, meta


def test_the_mcap_file_holds_the_trial_log_exactly(run_dir, tmp_path):
    path = tmp_path / "trial.mcap"  # written by the installed command
    done = subprocess.run([HILBENCH, "export", str(run_dir), "--mcap", str(path), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["mcap"] == str(path)
    log, prep = load_record(run_dir)
    topics, meta = _read(path)

    states = topics["/joint_states"]
    assert {s for s, _, _ in states} == {"sensor_msgs/msg/JointState"}
    assert len(states) == len(log)
    assert all(list(m.name) == log.joint_names for _, m, _ in states)
    for field, series in (("position", log.q), ("velocity", log.qd), ("effort", log.effort)):
        np.testing.assert_array_equal(np.array([getattr(m, field) for _, m, _ in states]), series)
    commands = topics["/joint_commands"]
    np.testing.assert_array_equal(np.array([m.position for _, m, _ in commands]), log.q_cmd)
    np.testing.assert_array_equal(np.array([m.velocity for _, m, _ in commands]), log.qd_cmd)

    # One clock: the header stamp is the log time, both the trial's start plus the log's time.
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m, _ in states])
    log_times = np.array([t for _, _, t in states], dtype=np.int64)
    np.testing.assert_allclose(stamps - stamps[0], log.time - log.time[0], atol=1e-6)
    np.testing.assert_array_equal(np.diff(log_times) > 0, np.diff(log.time) > 0)

    # Margins: what the trial's interlocks had, as configured (SI; negative would trip).
    s = prep.config.safety
    gantry = np.array([m.data for _, m, _ in topics["/interlock_margins/gantry"]])
    check = GantryClearance(prep.robot, s.gantry_margin_mm * 1e-3)
    for i in (0, len(log) // 2, len(log) - 1):
        assert gantry[i] == pytest.approx(check.check(log.q[i]).distance - s.gantry_margin_mm * 1e-3)
    assert (gantry > 0).all()  # the trial passed: never inside the margin
    tracking = np.array([m.position for _, m, _ in topics["/interlock_margins/tracking"]])
    error = np.array([m.position for _, m, _ in topics["/tracking_error"]])
    np.testing.assert_allclose(error, log.q - log.q_cmd)
    revolute = [r.kind == "revolute" for r in prep.robot.chain.rows]
    bound = np.where(revolute, np.radians(s.tracking_error_deg), s.tracking_error_mm * 1e-3)
    np.testing.assert_allclose(tracking, bound - np.abs(log.q - log.q_cmd))
    limits = np.array([m.position for _, m, _ in topics["/interlock_margins/joint_limits"]])
    assert limits.shape == log.q.shape and (limits >= 0).all()

    assert [m.data for _, m, _ in topics["/phase"]] == log.segment_names
    rosout = [m for _, m, _ in topics["/rosout"]]
    assert [r.msg for r in rosout] == [f"{e.kind}: {e.message}" for e in log.events]
    # What the cameras measured: their tip at each capture (entry, end of the insertion), and at the
    # end of the insertion its distance from the encoders' tip, SI, as the result gives them in mm.
    result = json.loads((run_dir / "result.json").read_text())
    tips = topics["/camera/tip"]
    assert [s for s, _, _ in tips] == ["geometry_msgs/msg/PointStamped"] * 2
    assert all(m.header.frame_id == "base_link" for _, m, _ in tips)
    last = tips[-1][1].point
    np.testing.assert_allclose([last.x, last.y, last.z], np.array(result["camera"]["tip_mm"]) * 1e-3, atol=1e-7)
    (gap,) = [m.data for _, m, _ in topics["/camera/encoder_gap"]]
    assert gap == pytest.approx(result["camera"]["encoder_gap_mm"] * 1e-3, abs=1e-7)
    assert {"trial", "config", "result"} <= set(meta)
    assert json.loads(meta["config"]["json"]) == log.metadata["config"]
    assert meta["trial"]["robot"] == "arc-train"
    assert json.loads(meta["result"]["passed"]) is True


def test_export_refuses_in_one_line(run_dir, tmp_path):
    import shutil

    tampered = tmp_path / "tampered"
    shutil.copytree(run_dir, tampered)
    record = json.loads((tampered / "record.json").read_text())
    (tampered / "record.json").write_text(json.dumps(record | {"log": "../../../../etc/passwd"}))
    for args, words in (([str(tmp_path / "nowhere"), "--mcap", str(tmp_path / "a.mcap")], "no such run directory"),
                        ([str(tampered), "--mcap", str(tmp_path / "a.mcap")], "not a plain file name"),
                        ([str(run_dir), "--mcap", str(tmp_path / "no" / "a.mcap")], "does not exist"),
                        ([str(run_dir), "--mcap", str(tmp_path)], "is a directory")):
        done = _invoke("export", *args)
        assert done.exit_code == 2 and words in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
