"""Tolerance boundaries against a dense reference: each axis's boundary, its error and its trials.

``hilbench campaign boundary`` on the shipped ``hil_configs/campaigns/boundary_bias.yaml`` (encoder
bias on θ5, and on θ6, 0 to 2°, sim trials at Target 1), against a dense grid of the same axis
through the needle's kinematics (each bias moves its joint by −bias from the commanded pose; 2001
values, the crossing refined by bisection): the boundary's error as a share of the axis's range
(target within 2 %), and the trials it took (target at most 12; a dense grid of trials takes 100).

    python benchmarks/boundary.py [--write-table]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench.campaign.boundary import find_boundaries  # noqa: E402
from bench.campaign.falsify import decode  # noqa: E402
from bench.campaign.spec import Planner, load_campaign_spec  # noqa: E402
from bench.config.models import TrialConfig  # noqa: E402
from bench.core.outcome import needle_outcome  # noqa: E402
from bench.trial.plan import prepare  # noqa: E402

SPEC = ROOT / "hil_configs" / "campaigns" / "boundary_bias.yaml"


def reference() -> dict[str, float]:
    """Each axis's crossing through the kinematics: a 2001-value grid, then bisection."""
    spec = load_campaign_spec(SPEC)
    planner = Planner(spec)
    prep = prepare(TrialConfig.model_validate(planner.trial(0, 0, 0, 0, decode(planner.axes, [0.0] * 2)).config))
    out = {}
    for a, fault in zip(planner.axes, spec.faults):
        j = prep.robot.joint_names.index(fault["joints"][0])

        def score(b: float) -> float:
            q = np.array(prep.q_insert, dtype=float)
            q[j] -= np.radians(b)
            o = needle_outcome(prep.robot, q, prep.target)
            lin = max(*map(abs, o.tip_deviation_mm), *map(abs, o.entry_deviation_mm), abs(o.depth_deviation_mm))
            return min((5 - lin) / 5, 1 - abs(o.angle_deviation_deg))

        lo, hi = a.args
        xs = np.linspace(lo, hi, 2001)
        s = np.array([score(x) for x in xs])
        k = int(np.argmax(s < 0))
        a0, a1 = xs[k - 1], xs[k]
        for _ in range(40):
            m = 0.5 * (a0 + a1)
            a0, a1 = (m, a1) if score(m) >= 0 else (a0, m)
        out[a.label] = 0.5 * (a0 + a1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json")
    args = ap.parse_args()
    ref = reference()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        _, bounds, _ = find_boundaries(SPEC, Path(tmp) / "b", workers=args.workers)
    figures = {}
    for b in bounds:
        lo, hi = load_campaign_spec(SPEC).faults[0]["bias_deg"]["uniform"]
        err = abs(b["value"] - ref[b["axis"]]) / (hi - lo) * 100
        print(f"{b['axis']}: {b['value']:.4f} ({b['requirement']}), reference {ref[b['axis']]:.4f}, "
              f"error {err:.2f} % of the range, {b['trials']} trials")
        figures[f"boundary.{b['axis']}"] = (
            f"boundary_bias.yaml: {b['axis']}, boundary vs a dense kinematic grid (targets: within 2 % of "
            "the range, at most 12 trials)",
            f"{b['value']:.3f}° ({b['requirement']}) vs {ref[b['axis']]:.3f}°: {err:.2f} % of the range, "
            f"{b['trials']} trials")
    print(f"{time.perf_counter() - t0:.0f} s")
    if args.write_table:
        from figures import record

        record("benchmarks/boundary.py", figures, note="sim trials, one worker")


if __name__ == "__main__":
    main()
