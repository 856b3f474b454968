"""Does the bench's identified servo model predict real XL330 logs it was not fitted on, better
than BAM's published models?

Leave-one-trajectory-kind-out cross-validation on the twelve test-stand logs (BAM's XL330 on
its pendulum, ``tests/data/bam-xl330/`` or ``--logs``): for each of the four trajectory kinds,
``hilbench identify``'s fit on the nine logs of the other three kinds, then the three held-out
logs predicted open loop (BAM's score: MAE over every 5 ms sample). Prints each fold, the mean
over the twelve held-out predictions beside BAM's m1–m6 and the ideal servo on the same logs,
and the fit's time. BAM's best (m3) scores 0.060 rad there, fitted on all twelve.

    python benchmarks/stand_cross_validation.py [--logs DIR] [--generations 40] [--workers 0] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.stand.fit import fit_stand, init_worker, stand_maes  # noqa: E402
from bench.stand.logs import read_stand_logs  # noqa: E402
from bench.stand.predict import predict  # noqa: E402
from drivers.servo import ServoParams  # noqa: E402

DATA = REPO / "tests" / "data" / "bam-xl330"  # BAM's logs and models, shipped with the tests


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=Path, default=DATA / "logs")
    ap.add_argument("--bam", type=Path, default=DATA / "params")
    ap.add_argument("--generations", type=int, default=40)
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    logs = read_stand_logs([args.logs])
    kinds = sorted({g.trajectory for g in logs})
    datasheet = ServoParams.datasheet([logs[0].model_number])
    workers = args.workers or min(os.cpu_count() or 1, 2)
    folds, held = [], np.full(len(logs), np.nan)
    for kind in kinds:
        train = [g for g in logs if g.trajectory != kind]
        test = [i for i, g in enumerate(logs) if g.trajectory == kind]
        started = time.monotonic()
        with ProcessPoolExecutor(workers, initializer=init_worker, initargs=(train, datasheet)) as pool:
            fit = fit_stand(train, datasheet, generations=args.generations, pool=pool, workers=workers)
        seconds = time.monotonic() - started
        maes = stand_maes([logs[i] for i in test], datasheet, fit.values)[0]
        held[test] = maes
        folds.append({"held_out": kind, "train_mae": float(fit.mae_after.mean()), "test_mae": float(maes.mean()),
                      "test_logs": [logs[i].name for i in test], "fit_seconds": round(seconds, 1)})
        if not args.json:
            print(f"held out {kind:16s}: fit on {len(train)} logs (MAE {fit.mae_after.mean():.4f} rad, "
                  f"{seconds:.0f} s); held-out MAE {maes.mean():.4f} rad  ({', '.join(f'{m:.4f}' for m in maes)})",
                  flush=True)
    baselines = {}
    for spec in ["ideal", "datasheet"] + sorted(str(p) for p in args.bam.glob("m*.json")):
        baselines[Path(spec).stem] = predict(spec, [args.logs]).mean_mae
    result = {"cross_validated_mae_rad": float(held.mean()), "per_log": dict(zip([g.name for g in logs], held.tolist())),
              "folds": folds, "baselines_mae_rad": baselines}
    if args.json:
        print(json.dumps(result))
        return
    print(f"\nleave-one-kind-out mean MAE over the {len(logs)} held-out predictions: {held.mean():.4f} rad")
    for name, value in baselines.items():
        print(f"  {name:10s} on the same logs (BAM's models fitted on all of them): {value:.4f} rad")


if __name__ == "__main__":
    main()
