"""Excitation motions for identifying the servos: one joint at a time, from a rest pose and back.

For each excited joint, in turn, up to six pieces around the rest pose (the other joints hold):

* a **chirp**: a sine sweeping from ``f0`` to ``f1`` (logarithmically), for the response
  over the band the servos work in;
* a **multi-sine**: a sum of harmonics of ``1/period`` with Schroeder phases (a low crest
  factor, so the amplitude is spent on excitation rather than one peak);
* a **slow up-and-down** (``updown_s`` long; left out where the sweeps below do its work): out
  to the amplitude and back at one constant speed, the friction's home ground (nearly no
  inertia, the velocity held long enough to read the Coulomb and Stribeck levels on both sides);
* **constant-speed sweeps** (``sweep_speeds`` > 0): across and back at each of several speeds,
  log-spaced from ``sweep_slowest`` to ``sweep_fastest`` of the joint's top speed (the Stribeck
  region up to near its limit), each pass at most ``sweep_s`` long: friction against speed, so
  Coulomb, the Stribeck curve and viscous friction come apart, on both sides;
* **slow reversals** (``reversal_s`` > 0): two periods of a sine whose peak speed is the
  second-slowest sweep's, turning round slowly where friction sticks and breaks away;
* **holds** (``hold_s`` > 0): at the top, the rest pose, the bottom and the rest pose again
  (reached at the fastest sweep's speed), each held ``hold_s``: the friction at rest under
  different gravity loads, approached from both sides.

Every piece is faded in and out with a raised cosine, so position, velocity and
acceleration start and end at the rest pose at rest, and a pause separates pieces. Each
joint's amplitude is the largest within its ``amplitude`` (rad or m), its room to the
``lower``/``upper`` limits (less ``margin``), and (for the chirp and the multi-sine) its
velocity and acceleration limits over the band. Units are SI; times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .base import Limits, PointToPoint, TrajectoryError, as_joint_vector, as_times
from .lspb import LSPB

__all__ = ["Excitation", "ExcitationSpec"]

#: The sweeps and holds reach their speed in this long (s): a servo accelerates far faster than the
#: plan's share of its limits, and the time a sweep spends at its speed is what it measures.
SWEEP_RAMP_S = 0.08


@dataclass(frozen=True)
class ExcitationSpec:
    """How to excite each joint (the same for every joint; amplitudes are per joint)."""

    chirp_s: float = 6.0
    f0_hz: float = 0.2
    f1_hz: float = 2.0
    multisine_s: float = 6.0
    multisine_period_s: float = 3.0
    harmonics: int = 6
    updown_s: float = 6.0  # the slow up-and-down's length: out, through and back at one speed
    pause_s: float = 0.5
    fade_s: float = 0.5
    sweep_speeds: int = 0  # constant-speed sweeps, each out and back (0: none)
    sweep_slowest: float = 0.02  # the slowest sweep, as a fraction of the joint's top speed
    sweep_fastest: float = 0.4  # the fastest, as a fraction of it
    sweep_s: float = 1.0  # the longest a constant-speed pass lasts (s)
    reversal_s: float = 0.0  # the slow reversals' length (s; 0: none)
    hold_s: float = 0.0  # each of the four holds (s; 0: none)

    def __post_init__(self) -> None:
        for name in ("chirp_s", "f0_hz", "f1_hz", "multisine_s", "multisine_period_s", "fade_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise TrajectoryError(f"excitation {name} must be positive, got {v!r}")
        if self.f1_hz <= self.f0_hz:
            raise TrajectoryError(f"excitation f1_hz ({self.f1_hz}) must be above f0_hz ({self.f0_hz})")
        if self.harmonics < 1:
            raise TrajectoryError(f"excitation harmonics must be >= 1, got {self.harmonics}")
        if not (math.isfinite(self.updown_s) and self.updown_s > 0):
            raise TrajectoryError(f"excitation updown_s must be positive, got {self.updown_s!r}")
        if self.pause_s < 0:
            raise TrajectoryError(f"excitation pause_s must be >= 0, got {self.pause_s}")
        for name in ("reversal_s", "hold_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise TrajectoryError(f"excitation {name} must be >= 0, got {v!r}")
        if self.sweep_speeds < 0:
            raise TrajectoryError(f"excitation sweep_speeds must be >= 0, got {self.sweep_speeds}")
        if not (0 < self.sweep_slowest <= self.sweep_fastest <= 1 and self.sweep_s > 0):
            raise TrajectoryError(f"excitation sweeps need 0 < sweep_slowest ({self.sweep_slowest}) <= "
                                  f"sweep_fastest ({self.sweep_fastest}) <= 1 and sweep_s > 0")

    def sweep_fractions(self) -> np.ndarray:
        """The sweeps' speeds as fractions of a joint's top speed, slowest first (log-spaced)."""
        if self.sweep_speeds == 0:
            return np.zeros(0)
        return np.geomspace(self.sweep_slowest, self.sweep_fastest, self.sweep_speeds)


def _fade(t: np.ndarray, duration: float, fade: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A window 0 → 1 → 0 with raised-cosine edges of ``fade`` s, and its two derivatives."""
    w, wd, wdd = np.ones_like(t), np.zeros_like(t), np.zeros_like(t)
    for edge, sign in ((t, 1.0), (duration - t, -1.0)):
        m = edge < fade
        x = np.clip(edge[m] / fade, 0.0, 1.0)
        w[m] = 0.5 - 0.5 * np.cos(np.pi * x)
        wd[m] = sign * 0.5 * np.pi / fade * np.sin(np.pi * x)
        wdd[m] = 0.5 * (np.pi / fade) ** 2 * np.cos(np.pi * x)
    return w, wd, wdd


class Excitation(PointToPoint):
    """The joints excited one after another from ``rest`` and back to it (a :class:`Trajectory`)."""

    def __init__(self, rest: ArrayLike, joints: list[int], amplitude: ArrayLike, lower: ArrayLike,
                 upper: ArrayLike, limits: Limits, spec: ExcitationSpec = ExcitationSpec(),
                 margin: ArrayLike = 0.0, top_speed: ArrayLike | None = None) -> None:
        self._start = self._goal = as_joint_vector("rest", rest)
        n = self._start.size
        amp = as_joint_vector("amplitude", amplitude, n)
        lo, hi = as_joint_vector("lower", lower, n), as_joint_vector("upper", upper, n)
        margin = np.broadcast_to(np.asarray(margin, dtype=float), (n,))
        if limits.dof != n:
            raise TrajectoryError(f"limits have {limits.dof} joints, the rest pose {n}")
        bad = [j for j in joints if not 0 <= j < n]
        if bad or not joints:
            raise TrajectoryError(f"excited joints must be indices 0..{n - 1}, got {joints}")
        self.spec = s = spec
        w1 = 2 * math.pi * max(s.f1_hz, s.harmonics / s.multisine_period_s)
        room = np.minimum(self._start - lo, hi - self._start) - margin
        self.amplitude = np.minimum.reduce([amp, room, limits.velocity / w1 * 0.8,
                                            limits.acceleration / w1 ** 2 * 0.8])
        #: The slow up-and-down goes as far as the limits allow (speed, not frequency, bounds it).
        self.updown_amplitude = np.minimum(amp, room)
        thin = [j for j in joints if not self.amplitude[j] > 0]
        if thin:
            raise TrajectoryError(f"joint(s) {thin} have no room to move from the rest pose within "
                                  f"their limits and the margin")
        k = np.arange(1, s.harmonics + 1)
        self._harmonics = k
        self._phases = -math.pi * k * (k - 1) / s.harmonics  # Schroeder
        self._ms_norm = 1.0 / float(np.max(np.abs(self._multisine_raw(np.linspace(0, s.multisine_period_s, 2001))[0])))
        # each joint's top speed for the sweeps (joint units): the limits' unless given (the joint's
        # own limit or its servo's, past the share of it the rest of the plan keeps to)
        top = limits.velocity if top_speed is None else as_joint_vector("top_speed", top_speed, n)
        self._pieces: list[tuple[float, float, int, str, float]] = []  # (t0, duration, joint, kind, speed)
        t = 0.0
        self._legs: dict[tuple[int, str], list[LSPB | float]] = {}  # a move, or a hold of that many s
        fractions = s.sweep_fractions()
        for j in joints:
            a = float(self.updown_amplitude[j])
            speed = min(4.0 * a / s.updown_s, float(limits.velocity[j]))
            # out, back through the rest pose and home at `speed`, corners blended in 0.2 s
            self._legs[(j, "updown")] = _moves((0.0, a, -a, 0.0), speed, speed / 0.2)
            speeds = fractions * float(top[j])
            if len(speeds):  # each speed across the room and back (passes at most sweep_s long)
                d = np.minimum(a, speeds * s.sweep_s / 2)
                self._legs[(j, "sweeps")] = [leg for v, dv in zip(speeds, d)
                                             for leg in _moves((0.0, -dv, dv, -dv, 0.0), v, v / SWEEP_RAMP_S)]
            if len(speeds) and s.hold_s > 0:  # top, rest, bottom, rest: a hold after each move
                v = float(speeds[-1])
                moves = _moves((0.0, a, 0.0, -a, 0.0), v, v / SWEEP_RAMP_S)
                self._legs[(j, "holds")] = [x for leg in moves for x in (leg, float(s.hold_s))]
            # the sweeps do the up-and-down's work at several speeds: one or the other
            pieces = [("chirp", s.chirp_s), ("multisine", s.multisine_s),
                      ("sweeps", None) if len(speeds) else ("updown", None)]
            if len(speeds) and s.reversal_s > 0:
                pieces.append(("reversals", s.reversal_s))
            pieces.append(("holds", None))
            for kind, dur in pieces:
                if dur is None:
                    if (j, kind) not in self._legs:
                        continue
                    dur = sum(x if isinstance(x, float) else x.duration for x in self._legs[(j, kind)])
                piece_speed = float(speeds[min(1, len(speeds) - 1)]) if kind == "reversals" else speed
                self._pieces.append((t, dur, j, kind, piece_speed))
                t += dur + s.pause_s
        self._duration = t

    @property
    def duration(self) -> float:
        return self._duration

    @property
    def pieces(self) -> list[tuple[float, float, int, str]]:
        """(start s, duration s, joint index, kind) of each piece, in time order."""
        return [(t0, d, j, k) for t0, d, j, k, _ in self._pieces]

    def _multisine_raw(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = 2 * math.pi * self._harmonics / self.spec.multisine_period_s
        arg = np.outer(t, w) + self._phases
        return (np.sin(arg).sum(axis=1), (np.cos(arg) * w).sum(axis=1), (-np.sin(arg) * w ** 2).sum(axis=1))

    def _shape(self, kind: str, tau: np.ndarray, dur: float, a: float, joint: int, speed: float):
        s = self.spec
        if kind == "chirp":
            k = math.log(s.f1_hz / s.f0_hz) / dur
            phase = 2 * math.pi * s.f0_hz * (np.exp(k * tau) - 1.0) / k
            f = s.f0_hz * np.exp(k * tau)
            dphase, ddphase = 2 * math.pi * f, 2 * math.pi * f * k
            y = np.sin(phase)
            yd = np.cos(phase) * dphase
            ydd = -np.sin(phase) * dphase ** 2 + np.cos(phase) * ddphase
            return a * y, a * yd, a * ydd
        if kind == "multisine":
            y, yd, ydd = self._multisine_raw(tau)
            return a * self._ms_norm * y, a * self._ms_norm * yd, a * self._ms_norm * ydd
        if kind == "reversals":  # two periods of a sine peaking at the reversal speed (faded by the caller)
            w = 4 * math.pi / dur
            r = min(a, speed / w)
            return r * np.sin(w * tau), r * w * np.cos(w * tau), -r * w * w * np.sin(w * tau)
        # up and down, sweeps, holds: moves at constant speed between rests, blended corners (no fade)
        y, yd, ydd = np.zeros_like(tau), np.zeros_like(tau), np.zeros_like(tau)
        t0, last = 0.0, 0.0
        for leg in self._legs[(joint, kind)]:
            if isinstance(leg, float):  # a hold where the last move ended
                y[(tau >= t0) & (tau <= t0 + leg)] = last
                t0 += leg
                continue
            m = (tau >= t0) & (tau <= t0 + leg.duration)
            if m.any():
                q, qd, qdd = leg.sample(tau[m] - t0)
                y[m], yd[m], ydd[m] = q[:, 0], qd[:, 0], qdd[:, 0]
            t0 += leg.duration
            last = float(leg.goal[0])
        return y, yd, ydd

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        times, scalar = as_times(t)
        n = self._start.size
        q = np.tile(self._start, (times.size, 1))
        qd = np.zeros((times.size, n))
        qdd = np.zeros((times.size, n))
        for t0, dur, j, kind, speed in self._pieces:
            m = (times >= t0) & (times <= t0 + dur)
            if not m.any():
                continue
            tau = times[m] - t0
            amp = self.amplitude[j] if kind in ("chirp", "multisine") else self.updown_amplitude[j]
            y, yd, ydd = self._shape(kind, tau, dur, float(amp), j, speed)
            if kind not in ("chirp", "multisine", "reversals"):  # starts and ends at rest by itself
                w, wd, wdd = np.ones_like(tau), np.zeros_like(tau), np.zeros_like(tau)
            else:
                w, wd, wdd = _fade(tau, dur, self.spec.fade_s)
            q[m, j] += w * y
            qd[m, j] += wd * y + w * yd
            qdd[m, j] += wdd * y + 2 * wd * yd + w * ydd
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd


def _moves(points: tuple[float, ...], speed: float, acceleration: float) -> list[LSPB]:
    """One-joint moves through ``points`` (offsets from the rest pose), each from rest to rest at
    ``speed`` with ``acceleration`` at its ends."""
    return [LSPB([x0], [x1], [speed], [acceleration]) for x0, x1 in zip(points[:-1], points[1:]) if x1 != x0]
