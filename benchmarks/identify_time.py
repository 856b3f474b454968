"""How long identification takes: 9 joints from 3 logs (two excitations with the plan's friction sweeps).

Records three runs on the emulated lab rig given hidden servo physics, side by side: two
excitations (``hil_configs/identify.yaml``, four joints each) and a Target 1 trial
(``hil_configs/lab_real.yaml``: the only motion of the needle slide d10, which has no room to
move around the entry pose), then times ``hilbench identify`` over the three
logs ``--runs`` times (the machine is shared: median and best), with the wall time of its phases,
and prints the fitted joints' position error before and after. The issue's budget: 2 minutes on
two cores.

    python benchmarks/identify_time.py [--runs 3] [--workers 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from figures import record

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
GROUPS = (["train", "theta3", "theta4", "theta5"], ["theta6", "theta7", "theta8", "d9"])
HIDDEN = {"all": {"coulomb_nm": 0.08, "viscous_nms": 0.05, "stribeck_nm": 0.14, "stribeck_velocity_rads": 0.3},
          "theta4": {"armature_kgm2": 0.02, "kt_scale": 0.85, "coulomb_nm": 0.12}, "theta5": {"kt_scale": 0.8}}


def record(tmp: Path) -> list[Path]:
    """Two excitation runs (the lab plan's pieces, its sweeps, reversals and holds included, shorter
    chirps) and a Target 1 trial side by side."""
    configs = []
    for i, joints in enumerate(GROUPS):
        data = yaml.safe_load((REPO / "hil_configs" / "identify.yaml").read_text())
        data["name"] = f"excite-{i + 1}"
        data["excitation"].update(joints=joints, chirp_s=2.0, multisine_s=1.5, multisine_period_s=0.75,
                                  updown_s=1.0, pause_s=0.2)
        configs.append(data)
    configs.append(yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text()))
    procs = []
    for data in configs:
        data["emulator"]["servo_physics"] = HIDDEN
        cfg = tmp / f"{data['name']}.yaml"
        cfg.write_text(yaml.safe_dump(data))
        procs.append(subprocess.Popen([HILBENCH, "trial", str(cfg), "--emulate", "--json", "--out", str(tmp)],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    runs = []
    for p in procs:
        out, err = p.communicate()
        if not out.strip():
            raise SystemExit(f"a run failed: {err.strip().splitlines()[-1] if err.strip() else p.returncode}")
        runs.append(Path(json.loads(out)["run_dir"]))
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="identify runs to time")
    ap.add_argument("--workers", type=int, default=0, help="identify --workers (0: one per core)")
    ap.add_argument("--keep", type=Path, default=None, help="record the logs here and keep them")
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="identify-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    existing = sorted(p.parent for p in tmp.glob("*/trial.npz"))
    runs = existing[-3:] if len(existing) >= 3 else record(tmp)
    from bench.core.log import TrialLog  # deferred: the bench loads after the runs are recorded

    lengths = [float(TrialLog.load(r / "trial.npz").time[-1]) for r in runs]
    print(f"logs: {', '.join(f'{s:.1f} s' for s in lengths)} ({sum(lengths):.1f} s in all)")
    walls, last = [], {}
    for i in range(args.runs):
        t0 = time.perf_counter()
        res = subprocess.run([HILBENCH, "identify", *map(str, runs), "--out", str(tmp / f"model-{i}.yaml"),
                              "--json", "--workers", str(args.workers)], capture_output=True, text=True)
        walls.append(time.perf_counter() - t0)
        if res.returncode != 0:
            raise SystemExit(res.stderr.strip())
        last = json.loads(res.stdout)
        print(f"run {i + 1}: {walls[-1]:.1f} s wall ({last['seconds']:.1f} s inside identify)")
    print(f"identify, {len(last['joints'])} joints from {len(runs)} logs: median {statistics.median(walls):.1f} s, "
          f"best {min(walls):.1f} s (budget 120 s)")
    if args.write_table:
        record("benchmarks/identify_time.py", {"identify.time": (
            "identify's wall time on the excitation logs (budget 120 s)",
            f"median {statistics.median(walls):.1f} s over {sum(lengths):.0f} s of logs")}, f"{args.runs} runs")
    for name, j in last["joints"].items():
        print(f"  {name:7s} position MAE {j['mae_before']:.2e} -> {j['mae_after']:.2e}; not observable: "
              f"{', '.join(j['unobservable']) or '-'}")


if __name__ == "__main__":
    main()
