"""Trials to the first violation: the bench's falsifier against uniform random, a grid and PSY-TaLiRo.

The problem is the shipped ``hil_configs/campaigns/falsify_bias.yaml``: encoder biases of up to
±0.55° on θ3, θ5, θ6 and θ8 at Target 1 (the fast sim config), judged on the true placement. Its
known answer comes from the needle's kinematics at the biased joints (each bias moves its joint by
−bias from the commanded pose; 20 000 uniform draws): about 1.6 % of the box fails, in two pairs of
opposite corners (the biases add in the needle's tilt and in its in-plane angle).

Every method drives the same trial function, the campaign worker's (:func:`execute_trial`, a full
sim trial with its requirements), one trial at a time, and stops at its first violation or after
``--budget`` trials (100): the bench's default (``corners-cma``), ``cma`` and ``random`` optimisers,
a 3-level grid
(81 points, corners included) visited in a random order per seed, and PSY-TaLiRo's (``psy-taliro``:
``pip install 'needle-hil-bench[falsify-bench]'``) UniformRandom and DualAnnealing, each told to stop
below a cost of 0. Per method: the falsification rate within the budget and the median over the
seeds of the trials it took (an unfalsified seed counted as above the budget).

    python benchmarks/falsify.py [--seeds 10] [--budget 100] [--workers 2] [--write-table]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench.campaign.execute import execute_trial  # noqa: E402
from bench.campaign.falsify import decode, score_of, trials_to_violation  # noqa: E402
from bench.campaign.spec import Planner, load_campaign_spec  # noqa: E402

SPEC = ROOT / "hil_configs" / "campaigns" / "falsify_bias.yaml"
METHODS = ("corners-cma", "cma", "random", "grid", "psy-taliro UniformRandom", "psy-taliro DualAnnealing")


class Trials:
    """The trial function: a point of the unit cube -> a full sim trial -> its score."""

    def __init__(self) -> None:
        self.spec = load_campaign_spec(SPEC)
        self.planner = Planner(self.spec)
        self.scores: list[float] = []
        self.stage = Path(tempfile.mkdtemp(prefix="falsify-bench-"))

    def __call__(self, u) -> float:
        k = len(self.scores)
        t = self.planner.trial(k, 0, k, 0, decode(self.planner.axes, u))
        r = execute_trial({"id": k, "name": t.name, "config": t.config, "stage": str(self.stage / t.name)})
        shutil.rmtree(self.stage / t.name, ignore_errors=True)
        if r["status"] != "done":
            raise RuntimeError(r.get("error"))
        s = score_of(r["metrics"]["requirements"]) if r["completed"] else -math.inf
        self.scores.append(s)
        return s

    def first(self) -> int | None:
        return next((i + 1 for i, s in enumerate(self.scores) if s < 0), None)


def run(job: tuple[str, int, int]) -> dict:
    method, seed, budget = job
    f = Trials()
    t0 = time.process_time()
    try:
        if method in ("corners-cma", "cma", "random"):
            trials_to_violation(method, len(f.planner.axes), seed, f, budget)  # f keeps every score
        elif method == "grid":
            points = list(itertools.product((0.0, 0.5, 1.0), repeat=len(f.planner.axes)))
            order = np.random.default_rng(seed).permutation(len(points))
            for i in order[:budget]:
                if f(points[i]) < 0:
                    break
        else:
            import staliro  # the benchmark's own dependency (the falsify-bench extra)
            from staliro.optimizers import DualAnnealing, UniformRandom  # the benchmark's own dependency

            cls = UniformRandom if method.endswith("UniformRandom") else DualAnnealing
            n = len(f.planner.axes)

            @staliro.costfunc
            def cost(inputs):
                if len(f.scores) >= budget or f.first() is not None:
                    return 0.0 if f.first() is None else -1.0  # past the budget: nothing more is run
                s = f([inputs.static[f"u{i}"] for i in range(n)])
                return s if math.isfinite(s) else -1e6

            opts = staliro.TestOptions(static_inputs={f"u{i}": (0.0, 1.0) for i in range(n)},
                                       iterations=budget, runs=1, seed=seed + 1)
            staliro.staliro(cost, cls(min_cost=0.0), opts)
    finally:
        shutil.rmtree(f.stage, ignore_errors=True)
    return {"method": method, "seed": seed, "first": f.first(), "trials": len(f.scores),
            "cpu_s": time.process_time() - t0}


def failing_share(draws: int = 20000) -> float:
    """The share of the box that fails, from the needle's kinematics at the biased joints."""
    from bench.config.models import TrialConfig
    from bench.core.outcome import needle_outcome
    from bench.trial.plan import prepare

    spec = load_campaign_spec(SPEC)
    planner = Planner(spec)
    t = planner.trial(0, 0, 0, 0, decode(planner.axes, [0.5] * len(planner.axes)))
    prep = prepare(TrialConfig.model_validate(t.config))
    joints = [f["joints"][0] for f in spec.faults]
    idx = [prep.robot.joint_names.index(j) for j in joints]
    lo, hi = spec.faults[0]["bias_deg"]["uniform"]
    rng = np.random.default_rng(0)
    fails = 0
    for b in rng.uniform(lo, hi, (draws, len(idx))):
        q = np.array(prep.q_insert, dtype=float)
        q[idx] -= np.radians(b)
        o = needle_outcome(prep.robot, q, prep.target, prep.config.acceptance.position_mm,
                           prep.config.acceptance.angle_deg)
        fails += not o.passed
    return fails / draws


def summarise(results: list[dict], budget: int) -> dict[str, dict]:
    out = {}
    for m in METHODS:
        rs = [r for r in results if r["method"] == m]
        if not rs:
            continue
        firsts = [r["first"] if r["first"] is not None else budget + 1 for r in rs]
        found = sum(r["first"] is not None for r in rs)
        out[m] = {"seeds": len(rs), "falsified": found, "median": statistics.median(firsts),
                  "firsts": [r["first"] for r in rs]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json")
    args = ap.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    share = failing_share()
    print(f"failing share of the box (kinematics, 20000 draws): {100 * share:.2f} %", flush=True)
    jobs = [(m, s, args.budget) for s in range(args.seeds) for m in methods]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        results = []
        for r in ex.map(run, jobs):
            print(json.dumps(r), flush=True)
            results.append(r)
            seeds = sorted({x["seed"] for x in results})
            whole = [s for s in seeds if sum(x["seed"] == s for x in results) == len(methods)]
            if args.write_table and len(whole) == r["seed"] + 1 and sum(x["seed"] == r["seed"] for x in results) \
                    == len(methods):  # every seed so far complete: the table as it stands
                write(share, summarise(results, args.budget), args.budget, len(whole))
    stats = summarise(results, args.budget)
    for m, s in stats.items():
        print(f"{m:28s} falsified {s['falsified']}/{s['seeds']} within {args.budget}, median trials "
              f"{s['median']:g}  {s['firsts']}")
    print(f"{len(results)} runs, {sum(r['trials'] for r in results)} trials in {time.perf_counter() - t0:.0f} s")


def write(share: float, stats: dict, budget: int, seeds: int) -> None:
    from figures import record

    def cell(m: str) -> str:
        s = stats[m]
        return f"{s['falsified']}/{s['seeds']} seeds; median {s['median']:g} trials"

    figures = {"falsify.share": ("falsify_bias.yaml: share of the 4-axis box that fails (needle kinematics, "
                                 "20 000 draws; target < 2 %)", f"{100 * share:.2f} %")}
    for m in stats:
        key = "falsify." + m.replace("psy-taliro ", "psytaliro_").lower()
        figures[key] = (f"falsify_bias.yaml: {m}, falsified within {budget} trials; median trials to "
                        "the first violation (unfalsified counted above the budget)", cell(m))
    for m in ("corners-cma", "cma"):
        if m in stats and "random" in stats:
            figures[f"falsify.ratio_{m}"] = (
                f"falsify_bias.yaml: {m} median / uniform random median (target for the default ≤ 1/3)",
                f"{stats[m]['median'] / stats['random']['median']:.2f}")
    record("benchmarks/falsify.py", figures, note=f"{seeds} seeds, budget {budget}, sim trials")

if __name__ == "__main__":
    main()
