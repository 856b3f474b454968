"""A trial's log as an MCAP file that Foxglove and PlotJuggler open as they open a ROS 2 bag.

Topics (ROS 2 message types, SI units, one message per control cycle unless said):

* ``/joint_states`` (``sensor_msgs/JointState``): measured position, velocity, effort.
* ``/joint_commands`` (``sensor_msgs/JointState``): commanded position and velocity.
* ``/tracking_error`` (``sensor_msgs/JointState``): measured − commanded position.
* ``/interlock_margins/joint_limits``, ``/interlock_margins/tracking``
  (``sensor_msgs/JointState``, per joint in ``position``): how far each joint is
  from tripping that interlock (its limit, its tracking bound); negative trips.
* ``/interlock_margins/gantry`` (``std_msgs/Float64``): the gantry-clearance bound
  the interlock checks, less its margin (m); negative trips.
* ``/loop_timing/late`` and ``/loop_timing/bus`` (``std_msgs/Float64``, s), a paced
  trial's only, per timed cycle: how late the cycle's work ended against its deadline
  (positive: it missed it) and how long its bus transactions took.
* ``/twin/residual`` (``sensor_msgs/JointState``, per watched joint in ``position``), a monitored
  trial's only: the twin's residual over σ at each reading it predicted (every 10 ms,
  ``bench.monitor``), NaN where not watched;
  ``/twin/alarm`` (``std_msgs/String``): each alarm, at its time, naming the joint.
* ``/phase`` (``std_msgs/String``): the segment, at each change.
* ``/rosout`` (``rcl_interfaces/Log``): the trial's events (interlock trips, aborts,
  safe stop as errors and warnings).

The trial's metadata (config, target, versions, verdict) goes in MCAP metadata
records, so nothing a report shows is lost. Times are the trial's start (UTC)
plus the log's time.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Iterator

import numpy as np
from mcap_ros2.writer import Writer

from bench.core.log import TrialLog
from bench.core.result import PreparedTrial
from bench.export import ros2_messages as msgs
from bench.trial.margins import margins_of

__all__ = ["write_mcap", "CAMERA_TOPICS", "TIMING_TOPICS", "TOPICS", "TWIN_TOPICS"]

TOPICS = ("/joint_states", "/joint_commands", "/tracking_error", "/interlock_margins/joint_limits",
          "/interlock_margins/tracking", "/interlock_margins/gantry", "/phase", "/rosout")
#: A paced trial's loop timing, per timed cycle (s): lateness against the deadline, bus time.
TIMING_TOPICS = ("/loop_timing/late", "/loop_timing/bus")
#: A monitored trial's (bench.monitor): the twin's residuals, and its alarms.
TWIN_TOPICS = ("/twin/residual", "/twin/alarm")
#: What the cameras measured, at each capture: the needle's tip (m, robot frame), and at the end of
#: the insertion its distance from the encoders' tip (m).
CAMERA_TOPICS = ("/camera/tip", "/camera/encoder_gap")
#: The frame the cameras' tip is given in (the robot's, as the encoders' forward kinematics).
ROBOT_FRAME = "base_link"


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _start_ns(log: TrialLog) -> int:
    """The trial's start as nanoseconds since the epoch (0 when the log does not say)."""
    start = log.metadata.get("start_time")
    try:
        when = dt.datetime.fromisoformat(str(start))
    except ValueError:
        return 0
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return int(when.timestamp()) * 1_000_000_000


def _joint_state(names: list[str], stamp: dict, position, velocity=(), effort=()) -> dict:
    return {"header": {"stamp": stamp, "frame_id": ""}, "name": names,
            "position": [float(v) for v in position], "velocity": [float(v) for v in velocity],
            "effort": [float(v) for v in effort]}


def _metadata(log: TrialLog, result: dict | None) -> Iterator[tuple[str, dict[str, str]]]:
    """MCAP metadata records: string → string maps (nested values as JSON)."""
    meta = log.metadata

    def flat(d: dict) -> dict[str, str]:
        return {k: v if isinstance(v, str) else json.dumps(v) for k, v in d.items()}

    yield "trial", flat({k: v for k, v in meta.items() if k != "config"}
                        | {"joint_names": log.joint_names, "segment_names": log.segment_names})
    if "config" in meta:
        yield "config", {"json": json.dumps(meta["config"])}
    if result is not None:
        yield "result", flat(result)


def write_mcap(log: TrialLog, prep: PreparedTrial, path: Path, result: dict | None = None) -> Path:
    """Write the trial as an MCAP file of ROS 2 messages at ``path`` (atomically)."""
    path = Path(path)
    margins = margins_of(log, prep)
    names = list(log.joint_names)
    t0 = _start_ns(log)
    stamps = [t0 + int(round(t * 1e9)) for t in log.time]
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        w = Writer(f)
        schema = {key: w.register_msgdef(*definition) for key, definition in
                  (("joint", msgs.JOINT_STATE), ("float", msgs.FLOAT64), ("string", msgs.STRING),
                   ("log", msgs.LOG), ("point", msgs.POINT_STAMPED))}
        last_segment = None
        timing = zip(TIMING_TOPICS, (log.loop_late, log.bus_s)) if log.timed else ()
        timing = [(topic, series, np.isfinite(log.loop_late)) for topic, series in timing]
        twin, current = log.twin_z, log.twin_current_z  # the current's in the effort field
        monitor = log.metadata.get("monitor") or {}
        watched = [log.joint(n) for n in monitor.get("joints", [])] if twin is not None else []
        for i, ns in enumerate(stamps):
            stamp = _stamp(ns)
            w.write_message("/joint_states", schema["joint"],
                            _joint_state(names, stamp, log.q[i], log.qd[i], log.effort[i]), ns, ns, i)
            w.write_message("/joint_commands", schema["joint"],
                            _joint_state(names, stamp, log.q_cmd[i], log.qd_cmd[i]), ns, ns, i)
            w.write_message("/tracking_error", schema["joint"],
                            _joint_state(names, stamp, log.q[i] - log.q_cmd[i]), ns, ns, i)
            w.write_message("/interlock_margins/joint_limits", schema["joint"],
                            _joint_state(names, stamp, margins.joint_limits[i]), ns, ns, i)
            w.write_message("/interlock_margins/tracking", schema["joint"],
                            _joint_state(names, stamp, margins.tracking[i]), ns, ns, i)
            if margins.gantry is not None:
                w.write_message("/interlock_margins/gantry", schema["float"],
                                {"data": float(margins.gantry[i])}, ns, ns, i)
            if watched and np.isfinite(twin[i, watched]).any():  # a reading the twin predicted
                w.write_message(TWIN_TOPICS[0], schema["joint"],
                                _joint_state([names[j] for j in watched], stamp, twin[i, watched], (),
                                             () if current is None else current[i, watched]), ns, ns, i)
            for topic, series, timed in timing:
                if timed[i]:
                    w.write_message(topic, schema["float"], {"data": float(series[i])}, ns, ns, i)
            segment = int(log.segment[i])
            if segment != last_segment and 0 <= segment < len(log.segment_names):
                w.write_message("/phase", schema["string"], {"data": log.segment_names[segment]}, ns, ns)
                last_segment = segment
        for k, event in enumerate(log.events):
            ns = t0 + int(round(event.time * 1e9))
            w.write_message("/rosout", schema["log"],
                            {"stamp": _stamp(ns), "level": msgs.LOG_LEVEL.get(event.kind, 20),
                             "name": "hilbench", "msg": f"{event.kind}: {event.message}",
                             "file": "", "function": event.kind, "line": 0}, ns, ns, k)
        for k, alarm in enumerate(monitor.get("alarms", []) if twin is not None and len(log) else []):
            ns = t0 + int(round((log.time[0] + alarm["t_s"]) * 1e9))
            w.write_message(TWIN_TOPICS[1], schema["string"],
                            {"data": f"{alarm['joint']} behaves unlike its model ({alarm['signal']} CUSUM "
                                     f"{alarm['score']:.1f} σ at {alarm['t_s']:.3f} s)"}, ns, ns, k)
        _write_camera(w, schema, log, result, t0)
        for name, data in _metadata(log, result):
            w.add_metadata(name, data)
        w.finish()
    tmp.replace(path)
    return path


def _write_camera(w: Writer, schema: dict, log: TrialLog, result: dict | None, t0: int) -> None:
    """The cameras' tip at each capture that measured one, and the gap to the encoders' at the end
    of the insertion (from the result, where it was worked out)."""
    captures = sorted(((c.get("time_s"), label, c) for label, c in
                       ((log.metadata.get("camera") or {}).get("captures") or {}).items()
                       if c.get("tip_m") is not None and c.get("time_s") is not None), key=lambda x: x[0])
    for k, (t, label, capture) in enumerate(captures):
        ns = t0 + int(round(float(t) * 1e9))
        x, y, z = (float(v) for v in capture["tip_m"])
        w.write_message(CAMERA_TOPICS[0], schema["point"],
                        {"header": {"stamp": _stamp(ns), "frame_id": ROBOT_FRAME}, "point": {"x": x, "y": y, "z": z}},
                        ns, ns, k)
        gap = ((result or {}).get("camera") or {}).get("encoder_gap_mm")
        if label == "insert" and gap is not None:
            w.write_message(CAMERA_TOPICS[1], schema["float"], {"data": float(gap) * 1e-3}, ns, ns, k)
