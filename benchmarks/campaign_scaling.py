"""Campaign throughput with 1 and 2 local workers on the same small campaign, and the ratio.

    python benchmarks/campaign_scaling.py [--trials 40] [--workers 1 2]

Each run is a fresh campaign of the same spec (the tolerance sweep's
deadband at Target 1, fast base config) on a fresh pool. Two rates are
printed: over the whole run (forking the workers included) and in steady
state (from each run's ``workers``-th finished trial to its last, from the
database's timestamps). The forkserver, which imports the trial code once
per campaign process whatever the number of workers, is started before
either run and its time printed apart. One BLAS/OpenMP thread per process,
so workers do not oversubscribe the cores.
"""

from __future__ import annotations

import os

for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_k, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def spec_file(directory: Path, trials: int) -> Path:
    spec = {"name": "scaling", "base": str(REPO / "hil_configs" / "sim_target1_fast.yaml"),
            "seed": 1, "samples": trials,
            "faults": [{"name": "deadband", "joints": "all", "tol_deg": 0.29}]}
    path = directory / "scaling.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def measure(spec: Path, directory: Path, workers: int) -> tuple[float, float, int, float]:
    """(whole-run trials/min, steady-state trials/min, trials, the workers' CPU share) for one
    fresh campaign; the CPU share (CPU time / wall time of the trials) falls below 1 when other
    processes take the cores."""
    from bench.campaign.run import create_campaign, run_campaign
    from bench.campaign.store import CampaignStore

    d = create_campaign(spec, directory / f"w{workers}")
    t0 = time.perf_counter()
    summary = run_campaign(d, workers=workers, report=False)
    wall = time.perf_counter() - t0
    with CampaignStore(d / "campaign.db") as store:
        trials = store.trials()
    finished = sorted(r["finished_at"] for r in trials)
    steady = (len(finished) - workers) / (finished[-1] - finished[workers - 1]) * 60.0
    share = sum(r["cpu_s"] for r in trials) / sum(r["duration_s"] for r in trials)
    return summary.completed / wall * 60.0, steady, summary.completed, share


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--workers", type=int, nargs=2, default=(1, 2))
    args = ap.parse_args()
    from bench.campaign.execute import start_forkserver

    load = os.getloadavg()[0]
    print(f"cores: {os.cpu_count()}, load average before: {load:.2f}"
          + ("  (other processes are busy: the ratio will understate the scaling)" if load > 0.5 else ""))

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        spec = spec_file(tmp, args.trials)
        print(f"forkserver start (trial code imported once per campaign, not timed below): "
              f"{start_forkserver():.2f} s")
        rates = {}
        for w in args.workers:
            rates[w] = measure(spec, tmp, w)
            whole, steady, n, share = rates[w]
            print(f"{w} worker{'s' if w > 1 else ' '}: {n} trials, {whole:6.1f} trials/min overall, "
                  f"{steady:6.1f} trials/min steady state, workers' CPU share {share:.2f}")
        a, b = args.workers
        print(f"ratio {b} vs {a} workers: {rates[b][0] / rates[a][0]:.2f} overall, "
              f"{rates[b][1] / rates[a][1]:.2f} steady state  (load average after: {os.getloadavg()[0]:.2f})")
        # The same ratio per CPU-second the workers actually got: what idle cores would give.
        print(f"ratio with other processes' share of the cores taken out: "
              f"{rates[b][0] / rates[a][0] * rates[a][3] / rates[b][3]:.2f} overall")


if __name__ == "__main__":
    main()
