"""Fitting each joint's servo physics to its logs: an inverse-dynamics regression for a start,
CMA-ES on the simulation error (:mod:`bench.identify.search`), then a few Levenberg–Marquardt
steps, all joints at once (their problems are independent, their simulations share one batch).

The residual of a joint is its simulated minus logged position and current over every log, each
channel divided by its own scale (how far the joint's logged position strays from its goals, how
much its current varies), plus a weak pull toward the datasheet so that what the logs cannot
tell stays where the datasheet put it. The Jacobian is a central difference with steps of a tenth
of each value: the firmware reads an integer encoder, so the error is a staircase at finer scale.

Each parameter gets a standard error — the cost's curvature at the optimum, inflated by how far
the other parameters can stand in for it, and at least the cluster-robust (per window) error —
and :mod:`bench.identify.observability` says which the logs tell and why not the others; those
are written as fitted (the prior held them near the datasheet) and listed as not observable.
The search starts from the best of several guesses (:func:`best_start`), and each log row's goal
reaches the simulated servo with the loop's latency (:func:`bench.identify.logs.loop_latency`).
A value the fit drove to the edge of its range is not observable
either, whatever its error: the logs pushed it out of what the servo can be (a train read through
its noisy ultrasonic sensor, barely moved, took a 2 N·m friction peak), and the model file takes
its peers' value instead (:attr:`JointFit.at_bound`).
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from bench.identify.coverage import steady_speeds
from bench.identify.logs import LoggedRun, RigSetup
from bench.identify.observability import (cluster_robust_stderr, not_observable, parameter_correlation,
                                          variance_inflation)
from bench.identify.search import cma_search
from bench.identify.simulate import PHYSICS, SlotPhysics, file_values, merge_runs, simulate_run
from drivers.dynamixel.control_table import x_series_table
from drivers.servo.friction import regressors

__all__ = ["FitResult", "JointFit", "fit_servos", "initial_physics"]

#: Typical size of each parameter (its unit for steps and for the pull to the datasheet).
SCALE = np.array([1.0, 0.01, 0.1, 0.2, 0.05, 0.1])
#: The Stribeck velocity's range: from half the slowest sweep's speed (slower, nothing the
#: excitation runs at tells it) to 1 rad/s (faster, a peak fading that slowly and a Coulomb level
#: near zero stand in for Coulomb and viscous friction over the speeds the joints move at).
LOWER = np.array([0.2, 1e-4, 0.0, 0.0, 0.0, 0.05])
UPPER = np.array([5.0, 1.0, 5.0, 2.0, 2.0, 1.0])
#: The rise of the fit's cost (a fraction) that defines a parameter's uncertainty: the step that
#: costs this much is one "standard error". The simulation error has no independent samples (the
#: encoder's steps make it a staircase in the parameters), so the noise floor is empirical: a few
#: percent of the cost is what parameters the logs cannot tell move it by.
UNCERTAINTY_RISE = 0.05
PRIOR_WEIGHT = 0.005
FD_FRACTION = 0.1  # difference steps: this fraction of the value ...
FD_FLOOR = np.array([0.02, 0.001, 0.02, 0.005, 0.005, 0.02])  # ... at least this
LAMBDAS = (0.25, 1.0, 4.0)  # damping factors tried together at each iteration
#: A batch goes to the pool only when each worker gets this many simulated servos (slots × windows):
#: narrower, numpy's per-call overhead outweighs the arithmetic and every worker pays it again (a
#: 58 s log's fit: 29-32 s alone, 34-35 s and 1.6 times the processor time on two workers).
POOL_MIN_SERVOS = 3000

Progress = Callable[[int, int], None]  # (iterations done, at most)


@dataclass
class JointFit:
    """One joint's fit, in the keys of a servo model file (:data:`~bench.identify.simulate.FILE_KEYS`)."""

    name: str
    values: dict[str, float]
    stderr: dict[str, float]  # one standard error (inf: the logs do not bound it)
    observable: dict[str, bool]  # the logs tell this value on its own (standard error within 5 %)
    mae_before: float  # position MAE over the logs (rad or m), datasheet
    mae_after: float
    current_mae_before: float  # A
    current_mae_after: float
    iterations: int = 0
    #: File keys the fit ran to the edge of their range (:func:`at_bound_keys`).
    at_bound: tuple[str, ...] = ()
    #: Windows of the logs the joint was not fitted on (log index, start s, end s): the one-joint
    #: simulation could not follow them (:meth:`_Problem.leave_out`).
    left_out: tuple[tuple[int, float, float], ...] = ()
    #: Per key not observable, why (the speeds the logs lack, a parameter it trades against, an edge).
    reasons: dict[str, str] = field(default_factory=dict)


@dataclass
class FitResult:
    joints: dict[str, JointFit]
    skipped: dict[str, str] = field(default_factory=dict)  # joint: why it was not fitted
    simulated_before: list = field(default_factory=list)  # per run: (q, current, velocity) (K, F), datasheet
    simulated_after: list = field(default_factory=list)  # per run: (q, current) (K, F), fitted


#: Where a fitted parameter (in the order of PHYSICS) counts as at the edge of its range: within
#: this fraction of a bound. A zero friction term (no Coulomb, no peak, no viscous part) is a
#: physical answer, not an edge.
AT_BOUND = 0.01
_EDGES = {"kt_scale": (True, True), "armature_kgm2": (True, True), "viscous_nms": (False, True),
          "coulomb_nm": (False, True), "stribeck_nm": (False, True), "stribeck_velocity_rads": (True, True)}
#: The file keys a parameter at an edge takes with it: a friction level goes with the other and the
#: shape, and a shape at an edge (the peak split from Coulomb where the logs cannot tell it) with both.
_FRICTION = ("coulomb_nm", "stribeck_nm", "stribeck_velocity_rads")
_TAKES = {"kt_scale": ("kt_scale",), "armature_kgm2": ("armature_kgm2",), "viscous_nms": ("viscous_nms",),
          "coulomb_nm": _FRICTION, "stribeck_nm": _FRICTION, "stribeck_velocity_rads": _FRICTION}


def at_bound_keys(x: np.ndarray) -> tuple[str, ...]:
    """The file keys of one joint's fit (x in the order of PHYSICS) that ran to an edge of their range."""
    keys: list[str] = []
    for i, name in enumerate(PHYSICS):
        low, high = _EDGES[name]
        if (low and x[i] <= LOWER[i] * (1 + AT_BOUND)) or (high and x[i] >= UPPER[i] * (1 - AT_BOUND)):
            keys += [k for k in _TAKES[name] if k not in keys]
    return tuple(keys)


def initial_physics(setup: RigSetup) -> np.ndarray:
    """The datasheet's physics per joint, (n, len(PHYSICS)): no Stribeck peak (rest at Coulomb)."""
    d = setup.datasheet
    peak = np.where(d.stribeck > 0, d.stribeck, d.coulomb)
    return np.stack([np.ones(d.n), d.armature, d.viscous, d.coulomb, peak, d.stribeck_velocity], axis=1)


class _Problem:
    """The residuals of the fitted joints for batches of parameter sets."""

    def __init__(self, setup: RigSetup, runs: Sequence[LoggedRun], joints: np.ndarray,
                 pool: Executor | None, workers: int = 1) -> None:
        self.setup, self.runs, self.joints, self.pool = setup, list(runs), joints, pool
        self.workers = max(1, workers)
        self.pool_min_servos = POOL_MIN_SERVOS
        q_err = np.concatenate([(r.q - r.goal)[:, joints] for r in runs])
        current = np.concatenate([r.current[:, joints] for r in runs])
        tick = np.abs(setup.ratio[joints]) * x_series_table()["Present Position"].scale
        self.q_scale = np.maximum(np.sqrt(np.mean(q_err ** 2, axis=0)), 2 * tick)
        # the train is fitted on its servo's velocity (its pinion encoder's), scaled by how far it
        # strays from the goals' velocity (at least two of the register's steps), unless every log
        # holds its pinion encoder's position: then on that, like every other joint
        on_encoder = all(r.train_on_encoder for r in runs)
        self.on_servo = (joints == setup.train if setup.train is not None and not on_encoder
                         else np.zeros(len(joints), dtype=bool))
        v_err = np.concatenate([(r.qd - np.gradient(r.goal, r.time, axis=0))[:, joints] for r in runs])
        v_step = np.abs(setup.ratio[joints]) * x_series_table()["Present Velocity"].scale
        self.v_scale = np.maximum(np.sqrt(np.mean(v_err ** 2, axis=0)), 2 * v_step)
        # all logs as one, each cut in windows; the window each residual belongs to (the columns of
        # :meth:`residuals`): windows are simulated apart, so they are the fit's independent clusters
        self.merged, self.windows, self.slices = merge_runs(self.runs)
        self.starts = [sl.start for sl in self.slices]
        window_of_row = np.empty(len(self.merged.time), dtype=int)
        for w, (a, b) in enumerate(self.windows):
            window_of_row[a:b] = w
        self.clusters = np.concatenate([c for sl in self.slices for c in (window_of_row[sl], window_of_row[sl])])
        self.i_scale = np.maximum(current.std(axis=0), 0.01)
        # per run, the rows each joint learns from (1) or not (0), and each joint's count of them
        self.weights = [learning_rows(setup, r, joints).astype(float) for r in runs]
        self._weigh()

    def _weigh(self) -> None:
        """Each joint's residuals divided by the root of its count of learning rows (both channels)."""
        counts = np.sum([w.sum(axis=0) for w in self.weights], axis=0)
        self.norm = 1.0 / np.sqrt(2 * np.maximum(counts, 1.0))

    def simulate(self, physics: np.ndarray, which: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per run, (q, current) of slots ``which`` (indices into the fitted joints) with ``physics``.
        Every log's windows step together; with a pool, the slots go out in one chunk per worker."""
        slots = SlotPhysics(joint=self.joints[which], values=physics)
        n = min(self.workers, len(which) * len(self.windows) // self.pool_min_servos, len(which))
        chunks = np.array_split(np.arange(len(which)), n) if self.pool and n > 1 else []
        if len(chunks) > 1:
            futures = [self.pool.submit(simulate_run, self.setup, self.merged,
                                        SlotPhysics(joint=slots.joint[c], values=slots.values[c]),
                                        windows=self.windows, log_starts=self.starts)
                       for c in chunks]
            parts = [f.result() for f in futures]
            q, cur, qd = (np.concatenate([p[i] for p in parts], axis=1) for i in (0, 1, 2))
        else:
            q, cur, qd = simulate_run(self.setup, self.merged, slots, windows=self.windows,
                                      log_starts=self.starts)
        return [(q[sl], cur[sl], qd[sl]) for sl in self.slices]

    def residuals(self, sims, which: np.ndarray) -> np.ndarray:
        """(S, m) residual rows of the slots (data only): position and current, but for a train whose
        logs lack its encoder channel velocity and current, the readings of its own servo (its
        logged position is then the ultrasonic sensor's, a millimetre of noise the servo never
        steered by)."""
        parts = []
        for run, sim, w in zip(self.runs, sims, self.weights):
            motion, current = self._run_residuals(run, sim, w, which)
            parts += [motion.T, current.T]
        return np.concatenate(parts, axis=1) * self.norm[which][:, None]

    def _run_residuals(self, run: LoggedRun, sim, w: np.ndarray, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One log's (K, S) weighted motion and current residuals of the slots (not yet normed)."""
        q, cur, qd = sim
        j, wk = self.joints[which], w[:, which]
        motion = np.where(self.on_servo[which][None, :], (qd - run.qd[:, j]) / self.v_scale[which],
                          (q - run.q[:, j]) / self.q_scale[which])
        return wk * motion, wk * (cur - run.current[:, j]) / self.i_scale[which]

    def leave_out(self, x: np.ndarray, factor: float) -> list[list[tuple[int, float, float]]]:
        """Per fitted joint, the windows (log index, start and end s) it stops learning from: those
        whose mean squared residual at ``x`` is over ``factor`` times the joint's median window's.
        Each joint is simulated alone, the rest of the robot taken from the log; where the logged
        motion is violent (a fast chirp swinging the arm) the others' accelerations, differentiated
        from velocities read in steps, are too rough for that, and one such window would outweigh
        all the others together."""
        every = np.arange(len(self.joints))
        sims = self.simulate(x, every)
        sq = []  # per run, (K, F) squared residual per row (motion and current)
        for run, sim, w in zip(self.runs, sims, self.weights):
            motion, current = self._run_residuals(run, sim, w, every)
            sq.append(motion ** 2 + current ** 2)
        left: list[list[tuple[int, float, float]]] = [[] for _ in every]
        for f in every:
            means, where = [], []
            for a, b in self.windows:
                r = next(i for i, sl in enumerate(self.slices) if sl.start <= a < sl.stop)
                lo, hi = a - self.slices[r].start, b - self.slices[r].start
                rows = self.weights[r][lo:hi, f] > 0
                if rows.sum() >= 10:
                    means.append(sq[r][lo:hi, f][rows].mean())
                    where.append((r, lo, hi))
            if len(means) < 3:
                continue
            limit = factor * np.median(means)
            for m, (r, lo, hi) in zip(means, where):
                if m > limit:
                    self.weights[r][lo:hi, f] = 0.0
                    t = self.runs[r].time
                    left[f].append((r, float(t[lo]), float(t[hi - 1])))
        self._weigh()
        return left

    def mae(self, sims, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j = self.joints[which]
        q = np.concatenate([np.abs(s[0] - r.q[:, j]) for r, s in zip(self.runs, sims)])
        c = np.concatenate([np.abs(s[1] - r.current[:, j]) for r, s in zip(self.runs, sims)])
        return q.mean(axis=0), c.mean(axis=0)


#: Goal speed above which a joint counts as commanded to move (rad/s or m/s): a degree or a
#: millimetre a second, above the host loop's slow nudges of the train's goal.
MOVING_GOAL = {"revolute": np.radians(1.0), "prismatic": 1e-3}
#: After another joint's goal stops, its motion still shakes this joint for this long (s).
COUPLING_SETTLE_S = 0.5


def goal_moving(setup: RigSetup, run: LoggedRun) -> np.ndarray:
    """(K, n) bool: the rows where each joint's goal moves (:data:`MOVING_GOAL`; a log of two rows
    or more)."""
    speed = np.abs(np.gradient(run.goal, run.time, axis=0))
    return speed > np.array([MOVING_GOAL[k] for k in setup.kinds])


def learning_rows(setup: RigSetup, run: LoggedRun, joints: np.ndarray) -> np.ndarray:
    """(K, F) bool: the rows each fitted joint is fitted on. A joint learns from its own motion and
    from the rest that follows it, but not from the time another joint moves while it holds, nor
    from its rest after that (the :data:`COUPLING_SETTLE_S` after a motion of all joints together
    apart): there its load is mostly the other joint's acceleration times their coupling inertia,
    differentiated from a velocity the servos report in steps of 0.23 rpm, and where its
    friction caught it after the other's jolt (a tick or two either way, on a worn gearbox more)
    would be fitted into its friction."""
    t = run.time
    if len(t) < 2:
        return np.ones((len(t), len(joints)), dtype=bool)
    moving = goal_moving(setup, run)
    # each row: when any joint's goal last moved, ignoring the joint itself
    last_move = np.where(moving, t[:, None], -np.inf)
    last_move = np.maximum.accumulate(last_move, axis=0)
    out = np.empty((len(t), len(joints)), dtype=bool)
    for f, k in enumerate(joints):
        others = np.delete(last_move, k, axis=1).max(axis=1) if last_move.shape[1] > 1 else np.full(len(t), -np.inf)
        shaken = (t - others <= COUPLING_SETTLE_S) | (others > last_move[:, k])
        out[:, f] = moving[:, k] | ~shaken
    return out


#: Stribeck velocities (rad/s at the shaft) the regression tries; the best fit wins.
STRIBECK_GRID = (0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.0)


def regression_guess(setup: RigSetup, runs: Sequence[LoggedRun], joints: np.ndarray) -> np.ndarray:
    """A first estimate from the equation of motion, linear in the unknowns but for the Stribeck
    velocity (the inverse-dynamics least squares of robot identification): per joint, over the
    logged rows where it moves,

        s·Kt·I/r = (M_jj + J_a/r²)·q̈ + load + (b/r²)·q̇ + (c + e·exp(−(ω/ω_s)²))·sign(q̇)/r

    for the motor scale s, armature J_a, viscous b, Coulomb c and Stribeck excess e (negative
    where the friction at rest is below Coulomb), solved for each ω_s of :data:`STRIBECK_GRID`
    and the best kept. Rows at rest are left out: static
    friction there can be anything up to the breakaway, and says nothing of the others. q̈ comes
    from the logged velocity (noisy), so this is a start for the simulation fit, not its answer."""
    from scipy.optimize import lsq_linear  # deferred: scipy loads in ~0.3 s, only fitting needs it

    x = initial_physics(setup)[joints]
    # unknowns (s, J_a, b, c, e): e = peak − c, either sign
    lower, upper = np.r_[LOWER[:4], -UPPER[3]], np.r_[UPPER[:4], UPPER[4]]
    for f, k in enumerate(joints):
        r = setup.ratio[k]
        torque, qdd, qd, y = [], [], [], []
        for run in runs:
            t, v = run.time, run.qd[:, k]
            acc = np.gradient(v, t) if len(t) > 2 else np.zeros_like(v)
            acc = np.convolve(acc, np.ones(5) / 5, mode="same")
            moving = np.abs(v) > max(0.05 * np.abs(v).max(), 2 * abs(r) * 0.024)
            torque.append(setup.kt_datasheet[k] * run.current[moving, k] / r)
            qdd.append(acc[moving])
            qd.append(v[moving])
            y.append(run.inertia[moving, k] * acc[moving] + run.load[moving, k])
        tq, a_, v_, y_ = (np.concatenate(c) for c in (torque, qdd, qd, y))
        if len(tq) < 20:
            continue
        best = None
        for ws in STRIBECK_GRID:
            coulomb, peak = regressors(v_ / abs(r), ws)  # the shaft's speed, signed as the joint's
            A = np.stack([tq, -a_ / r ** 2, -v_ / r ** 2, -coulomb / r, -peak / r], axis=1)
            norm = np.maximum(np.abs(A).max(axis=0), 1e-12)
            sol = lsq_linear(A / norm, y_, bounds=(lower * norm, upper * norm))
            if best is None or sol.cost < best[0]:
                best = (sol.cost, sol.x / norm, ws)
        _, theta, ws = best
        # a value on its bound is the regression giving up on it (too little signal): datasheet
        inside = ((theta > lower * 1.01) & (theta < upper * 0.99)) | (lower <= 0)
        theta = np.where(inside, np.clip(theta, lower, upper), np.r_[x[f, :4], 0.0])
        x[f, :4] = theta[:4]
        x[f, 4] = float(np.clip(theta[3] + theta[4], LOWER[4], UPPER[4]))
        x[f, 5] = ws
    return x


#: A window whose mean squared residual is over this many times its joint's median window's
#: leaves that joint's fit (:meth:`_Problem.leave_out`): over 5 times the typical error, all along.
LEAVE_OUT_FACTOR = 25.0

def best_start(cost: Callable[[np.ndarray, np.ndarray], np.ndarray], guess: np.ndarray,
               datasheet: np.ndarray) -> np.ndarray:
    """Per joint, the best of four starts for the search: its own regression, its peers' (the
    median of every joint's regression, with the joint's own motor constant and armature: one rig's
    gearboxes wear alike, and a joint whose regression gave up, e.g. one gravity barely loads,
    starts from what the others found), its own friction with the peers' Stribeck velocity (the
    regression's grid of them is coarse), and the datasheet."""
    peers = guess.copy()
    peers[:, 2:] = np.median(guess[:, 2:], axis=0)
    shape = guess.copy()  # its own friction levels, faded at the peers' Stribeck velocity
    shape[:, 5] = peers[:, 5]
    starts = np.stack([guess, peers, shape, datasheet])  # (4, F, P)
    F, n = guess.shape[0], len(starts)
    costs = cost(starts.reshape(-1, guess.shape[1]), np.tile(np.arange(F), n)).reshape(n, F)
    return starts[np.argmin(costs, axis=0), np.arange(F)]


def _prior(x: np.ndarray, x0: np.ndarray) -> np.ndarray:
    return PRIOR_WEIGHT * (x - x0) / SCALE


def _prior_costs(r_lo, r0, r_hi, lo, x, hi, x0):
    """Costs (data and prior) at the points below, at and above x: (F, P), (F,), (F, P)."""
    P = x.shape[1]
    eye = np.eye(P)
    prior = lambda pts: np.sum(_prior(pts, x0[:, None, :]) ** 2, axis=2)  # noqa: E731
    at = lambda v: x[:, None, :] * (1 - eye) + eye * v[:, None, :]  # noqa: E731
    c0 = np.sum(r0 ** 2, axis=1) + np.sum(_prior(x, x0) ** 2, axis=1)
    return (np.sum(r_lo ** 2, axis=2) + prior(at(lo)), c0, np.sum(r_hi ** 2, axis=2) + prior(at(hi)))


def _curvature(lo, x, hi, c_lo, c0, c_hi) -> np.ndarray:
    """Second derivative of the parabola through three (unevenly spaced) points, per parameter."""
    a, b = x - lo, hi - x
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = 2 * ((c_hi - c0[:, None]) / b + (c_lo - c0[:, None]) / a) / (a + b)
    return np.where((a > 0) & (b > 0), curv, np.nan)


def _parabola_vertex(lo, x, hi, c_lo, c0, c_hi) -> np.ndarray:
    """Each parameter moved to the bottom of its parabola (at most twice its step), in bounds."""
    a, b = x - lo, hi - x
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = ((c_hi - c0[:, None]) * a / b - (c_lo - c0[:, None]) * b / a) / (a + b)
        curv = _curvature(lo, x, hi, c_lo, c0, c_hi)
        step = np.where(curv > 0, -slope / curv, np.where(slope > 0, -a, b))
    step = np.nan_to_num(np.clip(step, -2 * np.maximum(a, 1e-12), 2 * np.maximum(b, 1e-12)))
    return np.clip(x + step, LOWER, UPPER)


def _central_steps(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points below and above x for each parameter (F, P) each: a tenth of the value or the floor,
    kept inside the bounds (one-sided at a bound)."""
    h = np.maximum(FD_FRACTION * np.abs(x), FD_FLOOR)
    lo = np.maximum(x - h, LOWER)
    hi = np.minimum(x + h, UPPER)
    return lo, hi


def fit_servos(setup: RigSetup, runs: Sequence[LoggedRun], *, max_iterations: int = 4, generations: int = 40,
               pool: Executor | None = None, workers: int = 1, progress: Progress | None = None) -> FitResult:
    """Fit the physics of every joint the logs excite (the others are listed in ``skipped``)."""
    excited = np.any([r.excited for r in runs], axis=0)
    names = setup.joint_names
    skipped = {names[k]: "its goals never moved it by 0.5° or 0.5 mm" for k in np.flatnonzero(~excited)}
    joints = np.flatnonzero(excited)
    F, P = len(joints), len(PHYSICS)
    if F == 0:
        return FitResult({}, skipped)
    prob = _Problem(setup, runs, joints, pool, workers)
    x0 = initial_physics(setup)[joints]
    x = regression_guess(setup, runs, joints)
    every = np.arange(F)
    eye = np.eye(P)
    D = np.diag(np.full(P, PRIOR_WEIGHT)) / SCALE  # the prior's Jacobian
    before = prob.simulate(x0, every)
    total = generations + max_iterations + 1
    if progress:
        progress(0, total)

    def cost(values: np.ndarray, which: np.ndarray) -> np.ndarray:
        res = prob.residuals(prob.simulate(values, which), which)
        return np.sum(res ** 2, axis=1) + np.sum(_prior(values, x0[which]) ** 2, axis=1)

    x = best_start(cost, x, x0)
    left_out: list[list[tuple[int, float, float]]] = [[] for _ in range(F)]
    if generations > 0:
        first = max(1, generations // 2)
        x, _ = cma_search(cost, x, SCALE, LOWER, UPPER, generations=first,
                          progress=(lambda g, _n: progress(g, total)) if progress else None)
        # windows the one-joint simulation cannot follow leave the fit, which then goes on
        left_out = prob.leave_out(x, LEAVE_OUT_FACTOR)
        x, _ = cma_search(cost, x, SCALE, LOWER, UPPER, generations=generations - first, sigma=0.15,
                          progress=(lambda g, _n: progress(first + g, total)) if progress else None)
    lam = np.full(F, 1e-2)
    done = np.zeros(F, dtype=bool)
    iterations = np.zeros(F, dtype=int)
    for it in range(max_iterations + 1):
        # Central differences at x for every joint at once: the base, then each parameter
        # below and above it (secants over a tenth of the value see through the encoder's steps).
        lo, hi = _central_steps(x)
        below = np.repeat(x[:, None, :], P, axis=1) * (1 - eye) + eye * lo[:, None, :]
        above = np.repeat(x[:, None, :], P, axis=1) * (1 - eye) + eye * hi[:, None, :]
        which = np.concatenate([every, np.repeat(every, P), np.repeat(every, P)])
        sims = prob.simulate(np.concatenate([x, below.reshape(-1, P), above.reshape(-1, P)]), which)
        res = prob.residuals(sims, which)
        r0, r_lo, r_hi = res[:F], res[F:F + F * P].reshape(F, P, -1), res[F + F * P:].reshape(F, P, -1)
        base_sims = [(q[:, :F], c[:, :F]) for q, c, _ in sims]
        J = np.transpose((r_hi - r_lo) / (hi - lo)[:, :, None], (0, 2, 1))  # (F, m, P)
        data_cost = np.sum(r0 ** 2, axis=1)
        cost = data_cost + np.sum(_prior(x, x0) ** 2, axis=1)
        if progress:
            progress(generations + it + 1, total)
        if it == max_iterations or done.all():
            break
        # Damped Gauss-Newton steps, three dampings per joint tried in one batch.
        JtJ = np.einsum("fmp,fmq->fpq", J, J) + D.T @ D
        g = np.einsum("fmp,fm->fp", J, r0) + _prior(x, x0) @ D
        diag = np.einsum("fpp->fp", JtJ)
        trials = []
        for factor in LAMBDAS:
            A = JtJ + (lam * factor)[:, None, None] * diag[:, :, None] * eye
            trials.append(np.clip(x - np.linalg.solve(A, g[:, :, None])[:, :, 0], LOWER, UPPER))
        # ... and each parameter to the bottom of the parabola through its own three costs
        # (robust where the cost is a staircase the Jacobian misreads), whole and half way.
        vertex = _parabola_vertex(lo, x, hi, *_prior_costs(r_lo, r0, r_hi, lo, x, hi, x0))
        trials += [vertex, (x + vertex) / 2]
        cand = np.concatenate(trials)
        which_c = np.tile(every, len(trials))
        res_c = prob.residuals(prob.simulate(cand, which_c), which_c)
        cost_c = (np.sum(res_c ** 2, axis=1) + np.sum(_prior(cand, np.tile(x0, (len(trials), 1))) ** 2, axis=1)
                  ).reshape(len(trials), F)
        best = np.argmin(cost_c, axis=0)
        best_cost = cost_c[best, every]
        better = (best_cost < cost) & ~done
        gain = np.where(better, (cost - best_cost) / np.maximum(cost, 1e-30), 0.0)
        x = np.where(better[:, None], np.stack(trials)[best, every], x)
        factors = np.r_[LAMBDAS, 1.0, 1.0]
        lam = np.where(better, lam * factors[best] / 2.0, lam * 8.0)
        iterations += ~done
        done |= (better & (gain < 1e-3)) | ~better & (lam > 1e4)
    # Uncertainty: how far each parameter may move, the others free to make up for it, before the
    # fit's cost rises by UNCERTAINTY_RISE: the parabola through its own three costs at the optimum
    # (robust on the staircase), inflated by how much the others can stand in for it (the
    # variance inflation factor H_ii·(H⁻¹)_ii of the Gauss-Newton Hessian).
    mae_b, mae_a = prob.mae(before, every), prob.mae(base_sims, every)
    c_lo, c0, c_hi = _prior_costs(r_lo, r0, r_hi, lo, x, hi, x0)
    curvature = _curvature(lo, x, hi, c_lo, c0, c_hi)  # d²cost/dx² (F, P)
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.where(curvature > 0, np.sqrt(2 * UNCERTAINTY_RISE * c0[:, None] / curvature), np.inf)
        se = np.maximum(se * np.sqrt(variance_inflation(J, D)), cluster_robust_stderr(J, r0, D, prob.clusters))
    corr = parameter_correlation(J, D)
    joints_fit: dict[str, JointFit] = {}
    for f, k in enumerate(joints):
        values, errors = file_values(x[f], se[f])
        edge = at_bound_keys(x[f])
        why = not_observable(values, errors, edge, steady_speeds(setup, runs, k), corr[f])
        observable = {key: key not in why for key in values}
        joints_fit[names[k]] = JointFit(names[k], values, errors, observable, float(mae_b[0][f]),
                                        float(mae_a[0][f]), float(mae_b[1][f]), float(mae_a[1][f]),
                                        int(iterations[f]), edge, tuple(left_out[f]), why)
    return FitResult(joints_fit, skipped, before, base_sims)
