"""What the twin beside a trial costs and what it says on clean and faulty trials, measured in one run.

The trial is Target 1 on the servo-model sim (``hil_configs/sim_target1_servo.yaml``, 500 Hz, the
interlocks on), as configured, run ``--repeats`` times plain and, interleaved, with ``--monitor
datasheet``: the loop's wall time of each (median and best), and their ratio; the same for the worn
rig's identified model (dry friction, stepped by its implicit law) on the sim it describes. Then, from the same
monitored logs and from ``--rig-repeats`` emulated-rig trials (``hil_configs/lab_real.yaml
--emulate --monitor datasheet``, 100 Hz on the wall clock), the highest the detector's sum rose on
any watched joint of a clean trial, against the alarm threshold; and a weak joint (``torque_limit``
0.3 on theta4, servo-model sim): when the monitor named it, against when an interlock stopped the
trial. Last, contacts (``contact`` from 2 s, servo-model sim): 0.3 N·m on each wrist joint, the time
to the alarm; on theta5 the smallest flagged and the smallest that trips an interlock or fails the
placement.

    python benchmarks/monitor_cost.py [--repeats 5] [--rig-repeats 2] [--write-table]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from figures import record

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SERVO_SIM = ROOT / "hil_configs" / "sim_target1_servo.yaml"
LAB = ROOT / "hil_configs" / "lab_real.yaml"
IDENTIFIED_SIM = ROOT / "hil_configs" / "sim_target1_identified.yaml"
WORN_MODEL = ROOT / "hil_configs" / "servo_models" / "emulated_worn_rig.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _trial(config: Path, *extra: str) -> dict:
    out = Path(tempfile.mkdtemp(prefix="monitor-bench-"))
    res = subprocess.run([HILBENCH, "trial", str(config), "--json", "--out", str(out), *extra],
                         capture_output=True, text=True, timeout=600)
    if res.returncode not in (0, 1):
        raise SystemExit(f"trial failed to run ({res.returncode}): {res.stderr.strip()}")
    return json.loads(res.stdout)


def _peak(result: dict) -> float:
    """The highest the detector's sum rose on a watched joint, recomputed from the log's residuals."""
    from bench.monitor.detector import Cusum, CusumParams
    from bench.trial.record import load_record

    log, _ = load_record(Path(result["run_dir"]))
    c = result["monitor"]["cusum"]
    params = CusumParams(c["drift_sigma"], c["threshold_sigma"])
    z = log.twin_columns  # position and current, as the detector ran them
    return float(np.nanmax(Cusum(z.shape[1], params).sums(z)))


def _contact(joint: str, torque: float) -> dict:
    """The servo-model sim's Target 1 with a contact on ``joint`` from 2 s, watched (warn)."""
    data = yaml.safe_load(SERVO_SIM.read_text())
    data.update(faults=[{"name": "contact", "joints": [joint], "torque_nm": torque, "from_s": 2.0}],
                monitor={"model": "datasheet", "action": "warn"})
    path = Path(tempfile.mkdtemp(prefix="monitor-bench-")) / "contact.yaml"
    path.write_text(yaml.safe_dump(data))
    return _trial(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rig-repeats", type=int, default=2)
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json")
    args = ap.parse_args()
    plain, watched, peaks, alarms = [], [], [], 0
    for _ in range(args.repeats):
        plain.append(_trial(SERVO_SIM)["loop_timing"]["wall_s"])
        r = _trial(SERVO_SIM, "--monitor", "datasheet")
        watched.append(r["loop_timing"]["wall_s"])
        peaks.append(_peak(r))
        alarms += len(r["monitor"]["alarms"])
    ratio = statistics.median(watched) / statistics.median(plain)
    # a model with dry friction (the worn rig's, identified), on the sim it describes (its servo model)
    worn_plain, worn_watched = [], []
    for _ in range(args.repeats):
        worn_plain.append(_trial(IDENTIFIED_SIM)["loop_timing"]["wall_s"])
        r = _trial(IDENTIFIED_SIM, "--monitor", str(WORN_MODEL))
        worn_watched.append(r["loop_timing"]["wall_s"])
        alarms += len(r["monitor"]["alarms"])
    worn_ratio = statistics.median(worn_watched) / statistics.median(worn_plain)
    rig_peaks = []
    for _ in range(args.rig_repeats):
        r = _trial(LAB, "--emulate", "--monitor", "datasheet")
        rig_peaks.append(_peak(r))
        alarms += len(r["monitor"]["alarms"])
    weak = yaml.safe_load(SERVO_SIM.read_text())
    weak.update(faults=[{"name": "torque_limit", "joints": ["theta4"], "scale": 0.3}],
                monitor={"model": "datasheet", "action": "warn"})
    path = Path(tempfile.mkdtemp(prefix="monitor-bench-")) / "weak.yaml"
    path.write_text(yaml.safe_dump(weak))
    r = _trial(path)
    from bench.trial.record import load_record

    log, _ = load_record(Path(r["run_dir"]))
    trips = [e.time - log.time[0] for e in log.events if e.kind == "interlock"]
    named = ", ".join(f"{a['joint']} at {a['t_s']:.3f} s" for a in r["monitor"]["alarms"])
    threshold = r["monitor"]["cusum"]["threshold_sigma"]
    print(f"servo-model sim, Target 1, {args.repeats} runs each: loop {statistics.median(plain):.3f} s plain "
          f"(best {min(plain):.3f}), {statistics.median(watched):.3f} s monitored (best {min(watched):.3f}): "
          f"×{ratio:.2f} (best against best ×{min(watched) / min(plain):.2f})")
    print(f"the worn model (dry friction) on its sim: loop {statistics.median(worn_plain):.3f} s plain "
          f"(best {min(worn_plain):.3f}), {statistics.median(worn_watched):.3f} s monitored "
          f"(best {min(worn_watched):.3f}): ×{worn_ratio:.2f} (best against best "
          f"×{min(worn_watched) / min(worn_plain):.2f})")
    print(f"clean trials: {alarms} alarms; detector peak {max(peaks):.1f} σ (sim), "
          f"{max(rig_peaks, default=float('nan')):.1f} σ (emulated rig), threshold {threshold:g} σ")
    print(f"weak theta4: alarms {named or 'none'}; interlock at {trips[0]:.3f} s" if trips else
          f"weak theta4: alarms {named or 'none'}; no interlock")
    wrist = {}
    for joint in ("theta5", "theta6", "theta7", "theta8"):
        a = _contact(joint, 0.3)["monitor"]["alarms"]
        wrist[joint] = a[0]["t_s"] - 2.0 if a and a[0]["joint"] == joint else None
    smallest = None
    for torque in (0.2, 0.15, 0.1, 0.075, 0.05, 0.03):
        a = _contact("theta5", torque)["monitor"]["alarms"]
        if not (a and a[0]["joint"] == "theta5"):
            break
        smallest = torque
    costly = None
    for torque in (0.5, 1.0, 1.5, 2.0, 3.0, 4.0):
        if not _contact("theta5", torque)["passed"]:
            costly = torque
            break
    told = ", ".join(f"{j} {'missed' if d is None else f'{1e3 * d:.0f} ms'}" for j, d in wrist.items())
    print(f"contact 0.3 N·m from 2 s: time to the alarm {told}; theta5's smallest flagged {smallest} N·m, "
          f"smallest that fails the trial {costly} N·m")
    if args.write_table:
        record("benchmarks/monitor_cost.py", {
            "monitor.cost": ("Twin beside the servo-model sim's Target 1 trial: loop wall time, monitored "
                             "against plain (median of runs)",
                             f"×{ratio:.2f} ({statistics.median(watched):.3f} s against "
                             f"{statistics.median(plain):.3f} s, {args.repeats} runs each; best against best "
                             f"×{min(watched) / min(plain):.2f})"),
            "monitor.cost_friction": ("Twin with a model that has dry friction (the worn rig's) beside the sim "
                                      "it describes, Target 1: loop wall time, monitored against plain "
                                      "(median of runs)",
                                      f"×{worn_ratio:.2f} ({statistics.median(worn_watched):.3f} s against "
                                      f"{statistics.median(worn_plain):.3f} s, {args.repeats} runs each; best "
                                      f"against best ×{min(worn_watched) / min(worn_plain):.2f})"),
            "monitor.clean_peak": ("Twin on clean trials: alarms, and the highest its detector rose on any "
                                   "watched joint, against the threshold",
                                   f"{alarms} alarms; {max(peaks):.1f} σ servo-model sim ({args.repeats} runs), "
                                   f"{max(rig_peaks, default=float('nan')):.1f} σ emulated rig "
                                   f"({args.rig_repeats} runs); threshold {threshold:g} σ"),
            "monitor.weak_joint": ("Twin on a weak theta4 (torque_limit 0.3, servo-model sim): the joints "
                                   "named, against the interlock that stopped the trial",
                                   f"{named or 'none'}; interlock at {trips[0]:.3f} s" if trips
                                   else f"{named or 'none'}; no interlock"),
            "monitor.contact": ("Twin and a contact from 2 s (servo-model sim): the time to the alarm at "
                                "0.3 N·m on each wrist joint; on theta5 the smallest contact flagged, and the "
                                "smallest that fails the trial (an interlock, the placement)",
                                f"{told}; smallest flagged {smallest} N·m, smallest failing {costly} N·m"),
        })


if __name__ == "__main__":
    main()
