"""The floor under a prediction's tracking gap: what no servo model can take out of it.

``compare --sim-model`` scores a model by the gap between the sim's and the rig's measured joint
profiles, relative to the ideal sim's gap. Both profiles are readings: encoder ticks and the
train's whole millimetres of ultrasonic distance. Two things in them are not the servos' doing
and no model can predict: where within its tick each shaft starts (a reading says which tick,
not where in it), and the ultrasonic sensor's noise on the rig.

This runs ``compare CONFIG --emulate --sim-model MODEL`` once, then the model sim a second time
per repeat, the same in everything (plan, model, start tick) except those two: each encoder joint
starts at a random point of its start tick, and the train's sensor gets the emulator's noise (with
another seed). The gap between the two runs of the very same sim, divided by the ideal sim's gap
to the rig, is the ratio a perfect model would score: the floor. It prints the model's ratio
beside it, ``--runs`` times (the machine is shared: the median beside each run).

    python benchmarks/prediction_floor.py [--config hil_configs/lab_real.yaml] [--model datasheet]
                                          [--repeats 3] [--runs 3]
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

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.compare.analysis import compare_logs  # noqa: E402
from bench.compare.prediction import tracking_gap  # noqa: E402
from bench.compare.session import _plan_start_of, _starting_at, sim_counterpart  # noqa: E402
from bench.config.models import load_trial_config  # noqa: E402
from bench.core.log import TrialLog  # noqa: E402
from bench.trial.plan import prepare  # noqa: E402
from bench.trial.run import TrialHooks, run_trial  # noqa: E402
from drivers.dynamixel.units import RAD_PER_TICK  # noqa: E402
from figures import record

HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _logs(run: Path, side: str) -> list[TrialLog]:
    return [TrialLog.load(d / "trial.npz") for d in sorted((run / side).iterdir())]


def floor_once(config: Path, model: str, repeats: int, tmp: Path, seed: int) -> tuple[float, float]:
    """(the model's tracking-gap ratio, the floor's) from one comparison."""
    out = subprocess.run([HILBENCH, "compare", str(config), "--emulate", "--repeats", str(repeats),
                          "--sim-model", model, "--json", "--out", str(tmp)], capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else out.returncode)
    res = json.loads(out.stdout)
    run = Path(res["report"]).parent
    real, ideal, first = _logs(run, "real"), _logs(run, "sim"), _logs(run, "model")
    rig_cfg = load_trial_config(config)
    base = sim_counterpart(rig_cfg, model)
    noisy = base.backend.ultrasonic.model_copy(update={"noise_mm": rig_cfg.emulator.ultrasonic_noise_mm})
    rng = np.random.default_rng(seed)
    table = base.backend.servos
    second = []
    for i, (rig, sim) in enumerate(zip(real, first)):
        cfg = base.model_copy(update={"backend": base.backend.model_copy(update={"ultrasonic": noisy}),
                                      "seed": seed + 1 + i})
        start = dict(sim.metadata["config"]["backend"]["start"])
        for name, value in start.items():
            if name != noisy.joint:  # an encoder joint: anywhere in its tick
                start[name] = value + rng.uniform(-0.5, 0.5) * RAD_PER_TICK * table[name].ratio
        res2 = run_trial(prepare(_starting_at(cfg, start), plan_start=_plan_start_of(rig)), tmp / "again",
                         TrialHooks(report=False))
        second.append(TrialLog.load(res2.run_dir / "trial.npz"))
    ideal_gap = tracking_gap(compare_logs(ideal, real))
    return res["prediction"]["tracking_gap_ratio"], tracking_gap(compare_logs(first, second)) / ideal_gap


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=REPO / "hil_configs" / "lab_real.yaml")
    ap.add_argument("--model", default="datasheet", help="datasheet or a servo model file")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    model = args.model if args.model == "datasheet" else str(Path(args.model).resolve())
    ratios, floors = [], []
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.runs):
            ratio, floor = floor_once(args.config.resolve(), model, args.repeats, Path(d) / f"run{k}", 1000 * k)
            ratios.append(ratio)
            floors.append(floor)
            print(f"run {k + 1}: model {ratio:.3f}   floor {floor:.3f}", flush=True)
    print(f"median of {args.runs}: model {statistics.median(ratios):.3f} (best {min(ratios):.3f})   "
          f"floor {statistics.median(floors):.3f} (lowest {min(floors):.3f})")
    if args.write_table:
        record("benchmarks/prediction_floor.py", {"prediction.floor": (
            f"tracking-gap ratio of the {args.model} model beside the measure's floor (default emulated rig)",
            f"{statistics.median(ratios):.3f} beside {min(floors):.3f}–{max(floors):.3f}")}, f"{args.runs} runs")


if __name__ == "__main__":
    main()
