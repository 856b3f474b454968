"""Falsification: search a spec's bounded axes for a trial that violates a requirement.

The axes are the spec's fault parameters and override values (a target's entry point, a servo's
physics) alike. The search runs in the unit cube of the spec's axes (:func:`decode` maps a point to axis values:
uniform and loguniform bounds, integers, a normal's ±3σ, the choices of a grid or a choice) and
minimises the trial's *score*, the lowest of its requirements' robustness each divided by its
``scale`` (a trial with no value for one, stopped before its placement, scores −∞). It stops at
the first trial whose score is negative — a requirement violated — or at the budget.

Optimisers (:data:`OPTIMIZERS`): ``random`` draws points uniformly (the baseline); ``cma`` is
CMA-ES (the ``cma`` package) over the cube, started at its centre with σ0 = 0.3 and a population
of 4 + ⌊3 ln d⌋, points outside the cube clipped onto its faces (where a fault is largest).

The trials are a campaign's: planned by the spec's :class:`bench.campaign.spec.Planner` at the
points asked for (trial k's seed is the spec's seed at grid 0, sample k), written to the same
``campaign.db`` and run by :func:`bench.campaign.run.run_campaign` on its pools (local processes, a
Dask cluster, the real bus one at a time). A search is deterministic given its seed, so it resumes
by replaying itself: the trials already in the database are read back, not run again.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import yaml

from bench.campaign.checked import DB_NAME
from bench.campaign.lock import CampaignLock
from bench.campaign.run import CampaignError, default_out, open_store, run_campaign
from bench.campaign.spec import Axis, CampaignSpec, Planner, load_campaign_spec, resolve_base
from bench.campaign.store import CampaignStore

__all__ = ["OPTIMIZERS", "DEFAULT_OPTIMIZER", "FalsifyResult", "decode", "falsify", "make_optimizer",
           "trials_to_violation",
           "open_search", "row_score", "score_of", "trial_config_yaml"]

OPTIMIZERS = ("corners-cma", "cma", "random")
#: The default, chosen on benchmarks/falsify.py's measurements (docs/figures.md).
DEFAULT_OPTIMIZER = "corners-cma"
#: corners-cma visits the box's corners first where there are at most this many (five axes)
MAX_CORNERS = 32
_NORMAL_SPAN = 3.0  # a normal axis is searched over mean ± 3σ


# ---------------------------------------------------------------------------
# The search space
# ---------------------------------------------------------------------------


def decode(axes: Sequence[Axis], u: Sequence[float]) -> dict[str, Any]:
    """Axis values at a point of the unit cube (one coordinate per axis, clipped into [0, 1])."""
    out: dict[str, Any] = {}
    for a, x in zip(axes, u):
        x = min(1.0, max(0.0, float(x)))
        lo, hi = (a.args[0], a.args[1]) if len(a.args) == 2 else (None, None)
        if a.kind == "uniform":
            out[a.label] = float(lo + x * (hi - lo))
        elif a.kind == "loguniform":
            out[a.label] = float(math.exp(math.log(lo) + x * (math.log(hi) - math.log(lo))))
        elif a.kind == "normal":
            out[a.label] = float(lo + hi * _NORMAL_SPAN * (2 * x - 1))
        elif a.kind == "integers":
            out[a.label] = int(min(int(hi), int(lo) + math.floor(x * (int(hi) - int(lo) + 1))))
        else:  # grid, choice: the values in order
            out[a.label] = a.args[min(len(a.args) - 1, int(x * len(a.args)))]
    return out


def score_of(requirements: Sequence[dict]) -> float:
    """The lowest robustness / scale of a trial's requirements (−∞ when one has no value)."""
    scores = [(-math.inf if r.get("robustness") is None else r["robustness"] / float(r.get("scale") or 1.0))
              for r in requirements]
    return min(scores) if scores else math.inf


# ---------------------------------------------------------------------------
# Optimisers: ask for a batch of points, told their scores
# ---------------------------------------------------------------------------


class RandomSearch:
    """Uniform draws, point k from its own stream of the seed (a batch of any size asks the same
    sequence)."""

    def __init__(self, dim: int, seed: int) -> None:
        self.dim, self.seed, self.k = dim, seed, 0

    def ask(self, n: int) -> list[np.ndarray]:
        out = []
        for _ in range(n):
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(2, self.k)))
            out.append(rng.uniform(0.0, 1.0, self.dim))
            self.k += 1
        return out

    def tell(self, points: list[np.ndarray], scores: list[float]) -> None:
        pass


class CmaSearch:
    """CMA-ES over the unit cube (the ``cma`` package), a generation per batch."""

    def __init__(self, dim: int, seed: int, start: Optional[np.ndarray] = None) -> None:
        import cma  # deferred: only a cma search needs it

        self.dim = dim
        self._pad = dim < 2  # cma needs two dimensions: a 1-axis search carries a dummy one
        n = max(2, dim)
        opts = {"seed": int(seed % (2 ** 31 - 1)) + 1, "verbose": -9, "popsize": 4 + int(3 * math.log(n)),
                "bounds": [0.0, 1.0], "CMA_stds": None, "tolfun": 0, "tolx": 0}
        x0 = [0.5] * n if start is None else [*np.clip(start, 0.05, 0.95), *([0.5] * (n - dim))]
        self._es = cma.CMAEvolutionStrategy(list(x0), 0.3, opts)
        self.popsize = int(self._es.popsize)
        self._asked: list[np.ndarray] = []

    def ask(self, n: int) -> list[np.ndarray]:
        self._asked = [np.asarray(x, dtype=float) for x in self._es.ask()]
        return [np.clip(x[: self.dim], 0.0, 1.0) for x in self._asked]

    def tell(self, points: list[np.ndarray], scores: list[float]) -> None:
        finite = [s if math.isfinite(s) else -1e6 for s in scores]
        self._es.tell(self._asked, finite)


class CornersThenCma:
    """The box's corners first, in an order drawn from the seed (a fault is usually worst at its
    extremes, and faults add up where they are all extreme: Breach starts its searches at the
    corners too), then CMA-ES started at the best point seen. Beyond :data:`MAX_CORNERS` corners,
    CMA-ES alone."""

    def __init__(self, dim: int, seed: int) -> None:
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3,)))
        n = 2 ** dim if 2 ** dim <= MAX_CORNERS else 0
        self._corners = [np.array([(c >> i) & 1 for i in range(dim)], dtype=float) for c in rng.permutation(n)]
        self.dim, self.seed = dim, seed
        self.popsize = 4 if self._corners else None
        self._cma: Optional[CmaSearch] = None if self._corners else CmaSearch(dim, seed)
        self._best: tuple[float, Optional[np.ndarray]] = (math.inf, None)
        if self._cma is not None:
            self.popsize = self._cma.popsize

    def ask(self, n: int) -> list[np.ndarray]:
        if self._corners:
            batch, self._corners = self._corners[:n], self._corners[n:]
            return batch
        if self._cma is None:
            self._cma = CmaSearch(self.dim, self.seed, start=self._best[1])
        self.popsize = self._cma.popsize
        return self._cma.ask(n)

    def tell(self, points: list[np.ndarray], scores: list[float]) -> None:
        for p, s in zip(points, scores):
            if s < self._best[0]:
                self._best = (s, np.asarray(p, dtype=float))
        if self._cma is not None and len(points) == self._cma.popsize:
            self._cma.tell(points, scores)


def make_optimizer(name: str, dim: int, seed: int):
    if name == "corners-cma":
        return CornersThenCma(dim, seed)
    if name == "random":
        return RandomSearch(dim, seed)
    if name == "cma":
        return CmaSearch(dim, seed)
    raise CampaignError(f"--optimizer {name!r}: unknown; valid: {', '.join(OPTIMIZERS)}")


def trials_to_violation(name: str, dim: int, seed: int, score: Callable[[np.ndarray], float],
                        budget: int) -> float:
    """The trials optimiser ``name`` takes to a negative ``score`` on the unit cube, one point at a
    time (inf when none within ``budget``): a search against a plain function, for measuring the
    optimisers (a kinematic stand-in, or a benchmark's trial function) apart from the store."""
    opt, k = make_optimizer(name, dim, seed), 0
    while k < budget:
        asked = opt.ask(getattr(opt, "popsize", None) or 1)
        points = asked[: budget - k]  # the last generation is cut at the budget (and never told)
        scores = []
        for p in points:
            scores.append(score(p))
            k += 1
            if scores[-1] < 0:
                return k
        if len(points) == len(asked):
            opt.tell(points, scores)
    return math.inf


# ---------------------------------------------------------------------------
# The search, on the campaign's store and pools
# ---------------------------------------------------------------------------


@dataclass
class FalsifyResult:
    """What a search came to: the falsifying trial (or the lowest), and the curve that led there."""

    campaign_dir: Path
    falsified: bool
    trials: int  # trials up to and including the falsifying one (all run, when none falsified)
    ran: int  # trials in the database (a batch runs whole)
    best: Optional[dict]  # the trial row with the lowest score
    score: float
    curve: list[float] = field(default_factory=list)  # the lowest score so far, trial by trial
    optimizer: str = DEFAULT_OPTIMIZER
    interrupted: bool = False

    def as_json(self) -> dict[str, Any]:
        row = self.best or {}
        worst = _worst_row(row)
        return {"falsified": self.falsified, "trials": self.trials,
                "robustness": None if worst is None else worst.get("robustness"),
                "requirement": None if worst is None else worst.get("name"),
                "score": self.score if math.isfinite(self.score) else None,
                "params": row.get("params"), "config": row.get("config_file"),
                "trial": row.get("id"), "seed": row.get("seed"), "optimizer": self.optimizer,
                "error": row.get("error") if row.get("status") == "error" else None,
                "ran": self.ran, "campaign": str(self.campaign_dir),
                "curve": [c if math.isfinite(c) else None for c in self.curve]}


def _requirements(row: dict) -> list[dict]:
    m = row.get("metrics")
    return list(m.get("requirements") or []) if isinstance(m, dict) else []


def _worst_row(row: dict) -> Optional[dict]:
    reqs = _requirements(row)
    if not reqs:
        return None
    return min(reqs, key=lambda r: -math.inf if r.get("robustness") is None
               else r["robustness"] / float(r.get("scale") or 1.0))


def row_score(row: dict) -> float:
    """A finished trial's score; a trial that errored or never completed scores −∞ (it failed)."""
    if row.get("status") != "done":
        return -math.inf
    s = score_of(_requirements(row))
    return s if row.get("completed") else min(s, -math.inf)


def falsify(spec_path: Path | str, out: Path | str | None = None, budget: int = 100, seed: int = 0,
            optimizer: str = DEFAULT_OPTIMIZER, workers: Optional[int] = None, scheduler: Optional[str] = None,
            notify: Optional[Callable[[str], None]] = None,
            progress: Optional[Callable[[int, float], None]] = None) -> FalsifyResult:
    """Search ``spec_path``'s axes for a violation; resume the search already in ``out`` if any."""
    if budget < 1:
        raise CampaignError(f"--budget must be >= 1, got {budget}")
    if optimizer not in OPTIMIZERS:
        raise CampaignError(f"--optimizer {optimizer!r}: unknown; valid: {', '.join(OPTIMIZERS)}")
    spec = load_campaign_spec(spec_path)
    planner = Planner(spec)
    if not planner.axes:
        raise CampaignError(f"{spec_path}: the spec has no axis to search (write a fault parameter or a "
                            "value under overrides: as {uniform: [low, high]}, a grid or a choice)")
    out = Path(out) if out is not None else default_out(f"{spec.name}-falsify")
    settings = {"mode": "falsify", "optimizer": optimizer, "search_seed": seed}
    open_search(spec, spec_path, planner, out, settings)
    opt = make_optimizer(optimizer, len(planner.axes), seed)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    batch = max(1, workers or cores)
    say = notify or (lambda msg: None)
    curve: list[float] = []
    best, best_score, first = None, math.inf, None
    k = 0
    interrupted = False
    while k < budget and first is None:
        asked = opt.ask(opt.popsize if getattr(opt, "popsize", None) else min(batch, budget - k))
        points = asked[: budget - k]  # the last generation is cut at the budget (and never told)
        planned = [planner.trial(k + i, 0, k + i, 0, decode(planner.axes, u)) for i, u in enumerate(points)]
        with CampaignStore(out / DB_NAME) as store:
            have = {r["id"]: r for r in store.trials()}
            new = []
            for t in planned:
                if t.id in have:
                    if have[t.id]["params"] != _jsonable(t.params):
                        raise CampaignError(f"{out}: trial {t.id} was planned at {have[t.id]['params']}, the "
                                            f"search now asks for {t.params}: the spec changed; start "
                                            "another --out")
                else:
                    new.append(t)
            if new:
                store.add_trials(new, {})
        summary = run_campaign(out, workers=workers, scheduler=scheduler, report=False)
        with open_store(out) as store:
            rows = [store.trial(t.id) for t in planned]
        if summary.interrupted or any(r["status"] in ("pending", "running") for r in rows):
            interrupted = True
            break
        scores = [row_score(r) for r in rows]
        if len(points) == len(asked):
            opt.tell(points, scores)
        for r, s in zip(rows, scores):
            if s < best_score or best is None:
                best, best_score = r, s
            curve.append(best_score)
            if first is None and s < 0:
                first = r
        k += len(planned)
        if progress:
            progress(k, best_score)
        say(f"{k} trial(s): lowest score {best_score:+.3f}" if math.isfinite(best_score)
            else f"{k} trial(s): a trial failed without a margin")
    falsified = first is not None
    if falsified:
        best, best_score = first, row_score(first)
        trials = int(first["id"]) + 1
        curve = curve[:trials]
    else:
        trials = len(curve)
    if best is not None:
        best = {**best, "config_file": str(write_trial_config(out, best))}
    with open_store(out) as store:
        ran = store.counts()["done"]
        store.set_meta(search={"falsified": falsified, "trials": trials, "score": _finite(best_score),
                               "best": best["id"] if best else None, "budget": budget,
                               "ended": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")})
    return FalsifyResult(out, falsified, trials, ran, best, best_score, curve, optimizer, interrupted)


def _finite(v: float) -> Optional[float]:
    return v if math.isfinite(v) else None


def _jsonable(v: Any) -> Any:
    """As the database gives it back (JSON): compare like with like."""
    return json.loads(json.dumps(v))


def open_search(spec: CampaignSpec, spec_path: Path | str, planner: Planner, out: Path,
                settings: dict) -> None:
    """``out/campaign.db`` for a search (``settings["mode"]``: falsify or boundary), made with no
    trial in it; one that holds the same search already is left to be resumed."""
    db = out / DB_NAME
    if db.exists():
        with open_store(out) as store:
            meta = store.meta()
        if meta.get("mode") != settings["mode"]:
            what = f"a {meta['mode']} search" if meta.get("mode") else "a campaign"
            raise CampaignError(f"{out} holds {what}, not a {settings['mode']} search; choose another --out")
        for k, v in settings.items():
            if meta.get(k) != v:
                raise CampaignError(f"{out} holds a search with {k} {meta.get(k)!r}, not {v!r}; run it with "
                                    f"the same settings to resume it, or choose another --out")
        if meta.get("name") != spec.name:
            raise CampaignError(f"{out} holds the search of {meta.get('name')!r}, not {spec.name!r}")
        return
    first = planner.trial(0, 0, 0, 0, decode(planner.axes, [0.5] * len(planner.axes)))
    out.mkdir(parents=True, exist_ok=True)
    with CampaignLock(out):
        if db.exists():
            raise CampaignError(f"{out} already holds a campaign; choose another --out")
        meta = {
            "name": spec.name, "description": spec.description, "seed": spec.seed,
            "spec": spec.model_dump(mode="json"), "spec_file": str(Path(spec_path).resolve()),
            "spec_text": Path(spec_path).read_text(), "base_config": str(resolve_base(spec)),
            "axes": [{"label": a.label, "fault": a.fault, "param": a.param, "kind": a.kind,
                      "args": list(a.args)} for a in planner.axes],
            "backend": first.config["backend"]["kind"], "max_attempts": 1,
            "acceptance": first.config["acceptance"], "target": first.config["target"],
            "created": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"), **settings,
        }
        tmp = out / f".{DB_NAME}.part"
        tmp.unlink(missing_ok=True)
        with CampaignStore(tmp, create=True) as store:
            store.add_trials([], meta)
        tmp.replace(db)


def write_trial_config(out: Path, row: dict) -> Path:
    """The trial's config as a YAML file `hilbench trial` runs alone: ``<out>/<name>.yaml``."""
    path = Path(out) / f"{row['name']}.yaml"
    path.write_text(trial_config_yaml(row["config"]))
    return path


def trial_config_yaml(config: dict) -> str:
    head = ("# A trial a falsification found (its faults, seed and requirements as the search ran it):\n"
            "#   hilbench trial THIS_FILE\n")
    return head + yaml.safe_dump(config, sort_keys=False)
