"""Interlocks the trial runner checks every control cycle, on every backend.

Each interlock looks at one cycle — the time, the measured :class:`drivers.JointState`
and the commanded positions — and either passes (``None``) or returns a
:class:`Trip` saying which interlock, why, and (where one joint is to blame)
the joint and the offending value in SI units. :class:`Interlocks` checks a
list in order and returns the first trip, so cheap checks go first and the
reported cause is deterministic. Interlocks never move anything: stopping
is the runner's job.

:meth:`Interlocks.scan` checks a block of cycles at once for a runner that
executes a block before looking at it (the simulator, which can rewind). Each
interlock's ``may_trip`` marks, vectorised, the cycles where its ``check``
could trip (a superset); only those cycles are checked one by one, in order,
with the very same ``check``, so a scan trips at the same cycle with the same
cause as checking every cycle would.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from bench.scene.contact import GantryClearance
from drivers import JointState

__all__ = ["Trip", "Interlock", "Interlocks", "GantryClearanceInterlock", "JointLimitInterlock",
           "VelocityLimitInterlock", "TrackingErrorInterlock", "StaleDataInterlock"]


@dataclass(frozen=True)
class Trip:
    """Why a cycle must stop: the interlock's name, a one-line cause, and when."""

    interlock: str
    cause: str
    time: float
    joint: str | None = None
    value: float | None = None


@runtime_checkable
class Interlock(Protocol):
    name: str

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None: ...


class Interlocks:
    """Interlocks checked in order; the first trip wins."""

    def __init__(self, interlocks: Sequence[Interlock]) -> None:
        self.interlocks = list(interlocks)
        for i in self.interlocks:
            if not isinstance(i, Interlock):
                raise TypeError(f"{i!r} is not an interlock (needs .name and .check)")
        names = [i.name for i in self.interlocks]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"interlock names must be unique, repeated: {dupes}")
        self._clear = _FusedClear.build(self.interlocks)

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        if self._clear is not None and self._clear(measured, commanded):
            return None  # provably no trip this cycle: the common case, in a dozen numpy calls
        for interlock in self.interlocks:
            trip = interlock.check(t, measured, commanded)
            if trip is not None:
                return trip
        return None

    def scan(self, times: np.ndarray, position: np.ndarray, velocity: np.ndarray,
             effort: np.ndarray, commanded: np.ndarray) -> tuple[int, Trip] | None:
        """The first cycle of a block (rows of the arrays) that trips, and its trip.

        Gives what calling :meth:`check` on every row in order would give; the
        samples carry no flags (a backend that flags samples is checked cycle by
        cycle). Interlocks without ``may_trip`` are checked on every row.
        """
        k = len(times)
        static = np.zeros(k, dtype=bool)
        stateful = []
        for il in self.interlocks:
            may_trip = getattr(il, "may_trip", None)
            if may_trip is None:
                static[:] = True
            elif getattr(il, "stateful", False):
                stateful.append(il)
            else:
                static |= may_trip(position, velocity, commanded)
        i = 0
        while i < k:
            need = static[i:].copy()
            for il in stateful:
                need |= il.may_trip(position[i:], velocity[i:], commanded[i:])
            hits = np.flatnonzero(need)
            if not len(hits):
                return None
            j = i + int(hits[0])
            st = JointState(float(times[j]), position[j].copy(), velocity[j].copy(), effort[j].copy())
            trip = self.check(st.time, st, commanded[j])
            if trip is not None:
                return j, trip
            i = j + 1
        return None

    def __iter__(self):
        return iter(self.interlocks)

    def __len__(self) -> int:
        return len(self.interlocks)


class _FusedClear:
    """One pass over a cycle that proves no standard interlock can trip it.

    The rows of ``x = [q, c, v, c − q]`` are checked against one pair of bound
    vectors, and the gantry's carried-forward bound against every checked
    position, each with the same comparisons the interlock's own ``check``
    makes (so NaN never clears). When it cannot prove it, the interlocks check
    the cycle one by one as before, so trips, causes and the gantry's state are
    exactly those of the per-interlock checks.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, with_commanded: bool, gantry) -> None:
        self.lo, self.hi = lo, hi
        self.with_commanded = with_commanded
        self.gantry = gantry

    @classmethod
    def build(cls, interlocks: Sequence[Interlock]) -> "_FusedClear | None":
        kinds = {type(i): i for i in interlocks}
        if len(kinds) != len(interlocks) or not set(kinds) <= {
                JointLimitInterlock, VelocityLimitInterlock, TrackingErrorInterlock,
                StaleDataInterlock, GantryClearanceInterlock}:
            return None  # an interlock this pass knows nothing of: check them one by one
        limits, vel = kinds.get(JointLimitInterlock), kinds.get(VelocityLimitInterlock)
        track, gantry = kinds.get(TrackingErrorInterlock), kinds.get(GantryClearanceInterlock)
        named = [i for i in interlocks if hasattr(i, "names")]
        if not named:
            return None
        n = len(named[0].names)
        inf = np.full(n, np.inf)
        with_c = limits is not None and limits.check_commanded
        lo = [limits._lo if limits else -inf, limits._lo if with_c else -inf,
              -vel._bound if vel else -inf, -track.bound if track else -inf]
        hi = [limits._hi if limits else inf, limits._hi if with_c else inf,
              vel._bound if vel else inf, track.bound if track else inf]
        if gantry is not None and not (gantry.reuse and gantry.check_commanded):
            return None
        return cls(np.concatenate(lo), np.concatenate(hi), with_c, gantry)

    def __call__(self, measured: JointState, commanded: np.ndarray) -> bool:
        if measured.flags:
            return False
        q, v = measured.position, measured.velocity
        if not (q.shape == commanded.shape == v.shape and 4 * q.size == self.lo.size):
            return False
        x = np.concatenate((q, commanded, v, commanded - q))
        if not ((x >= self.lo) & (x <= self.hi)).all():
            return False
        g = self.gantry
        if g is None:
            return True
        if g._last_q is None:
            return False
        stack = np.stack((q, q + v * g.lookahead_s, commanded))
        return bool((g._last_d - np.abs(stack - g._last_q) @ g._levers >= g.margin).all())


def _per_joint(values, names: Sequence[str], what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 0:
        arr = np.full(len(names), float(arr))
    if arr.shape != (len(names),):
        raise ValueError(f"{what} needs one value per joint ({len(names)}: {list(names)}), "
                         f"got shape {arr.shape}")
    if np.any(np.isnan(arr)):
        raise ValueError(f"{what} has NaN entries: {arr}")
    return arr


def _check_shape(name: str, names: Sequence[str], arr: np.ndarray, what: str) -> None:
    if np.shape(arr) != (len(names),):
        raise ValueError(f"{name}: {what} has shape {np.shape(arr)}, expected ({len(names)},) "
                         f"for joints {list(names)}")


def _amount(value: float, kind: str | None, rate: bool = False) -> str:
    """A joint quantity in the words a technician reads: degrees or mm (per second for rates)."""
    def fixed(v: float, digits: int) -> str:  # small limits keep three significant digits
        return f"{v:.{digits}f}" if abs(v) >= 10.0 ** -digits * 10 or v == 0 else f"{v:.3g}"

    if kind == "revolute":
        return f"{fixed(np.degrees(value), 2)} °/s" if rate else f"{fixed(np.degrees(value), 2)}°"
    if kind == "prismatic":
        return f"{fixed(value * 1e3, 1)} mm/s" if rate else f"{fixed(value * 1e3, 1)} mm"
    return f"{value:.6g}" + (" rad/s or m/s" if rate else "")


def _kinds(kinds: Sequence[str] | None, names: Sequence[str]) -> list[str | None]:
    if kinds is None:
        return [None] * len(names)
    if len(kinds) != len(names):
        raise ValueError(f"kinds needs one entry per joint ({len(names)}), got {len(kinds)}")
    return list(kinds)


class JointLimitInterlock:
    """Measured (and commanded) positions must stay within [lower − tol, upper + tol]."""

    name = "joint_limits"

    def __init__(self, lower: Sequence[float], upper: Sequence[float], names: Sequence[str],
                 tolerance: float | Sequence[float] = 0.0, check_commanded: bool = True,
                 kinds: Sequence[str] | None = None) -> None:
        self.names = list(names)
        self.kinds = _kinds(kinds, self.names)  # "revolute" | "prismatic": for the messages
        self.lower = _per_joint(lower, self.names, "lower")
        self.upper = _per_joint(upper, self.names, "upper")
        self.tolerance = _per_joint(tolerance, self.names, "tolerance")
        if np.any(self.lower > self.upper):
            bad = [n for n, lo, hi in zip(self.names, self.lower, self.upper) if lo > hi]
            raise ValueError(f"lower limit above upper limit for joints {bad}")
        if np.any(self.tolerance < 0):
            raise ValueError(f"tolerance must be non-negative, got {self.tolerance}")
        self.check_commanded = check_commanded
        self._lo = self.lower - self.tolerance
        self._hi = self.upper + self.tolerance

    def may_trip(self, position: np.ndarray, velocity: np.ndarray,
                 commanded: np.ndarray) -> np.ndarray:
        ok = ((position >= self._lo) & (position <= self._hi)).all(axis=1)
        if self.check_commanded:
            ok &= ((commanded >= self._lo) & (commanded <= self._hi)).all(axis=1)
        return ~ok

    def _first_out(self, q: np.ndarray) -> int | None:
        bad = ~((q >= self._lo) & (q <= self._hi))
        return int(np.argmax(bad)) if bad.any() else None  # NaN counts as outside

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        q = measured.position
        if (self.check_commanded and q.shape == commanded.shape == self._lo.shape
                and ((q >= self._lo) & (q <= self._hi) & (commanded >= self._lo)
                     & (commanded <= self._hi)).all()):
            return None  # the common case, in one pass
        _check_shape(self.name, self.names, measured.position, "measured position")
        sources = [("measured", np.asarray(measured.position, dtype=float))]
        if self.check_commanded:
            _check_shape(self.name, self.names, commanded, "commanded position")
            sources.append(("commanded", np.asarray(commanded, dtype=float)))
        for label, q in sources:
            i = self._first_out(q)
            if i is not None:
                k = self.kinds[i]
                tol = f" (tolerance {_amount(self.tolerance[i], k)})" if self.tolerance[i] else ""
                return Trip(self.name, f"{label} {self.names[i]} at {_amount(q[i], k)} is outside "
                            f"its range [{_amount(self.lower[i], k)}, {_amount(self.upper[i], k)}]"
                            f"{tol}", t, self.names[i], float(q[i]))
        return None


class VelocityLimitInterlock:
    """|measured velocity| must stay within ``factor`` × the joint's limit (rad/s or m/s)."""

    name = "velocity_limits"

    def __init__(self, limits: Sequence[float], names: Sequence[str], factor: float = 1.2,
                 kinds: Sequence[str] | None = None) -> None:
        self.names = list(names)
        self.kinds = _kinds(kinds, self.names)
        self.limits = _per_joint(limits, self.names, "velocity limits")
        if np.any(self.limits <= 0):
            raise ValueError(f"velocity limits must be positive, got {self.limits}")
        if not factor > 0:
            raise ValueError(f"factor must be positive, got {factor}")
        self.factor = float(factor)
        self._bound = self.factor * self.limits

    def may_trip(self, position: np.ndarray, velocity: np.ndarray,
                 commanded: np.ndarray) -> np.ndarray:
        return ~(np.abs(velocity) <= self._bound).all(axis=1)

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        _check_shape(self.name, self.names, measured.velocity, "measured velocity")
        v = np.asarray(measured.velocity, dtype=float)
        bad = ~(np.abs(v) <= self.factor * self.limits)
        if not bad.any():
            return None
        i = int(np.argmax(bad))
        k = self.kinds[i]
        return Trip(self.name, f"{self.names[i]} moves at {_amount(v[i], k, rate=True)}, beyond "
                    f"{self.factor:g} × its limit of {_amount(self.limits[i], k, rate=True)}", t,
                    self.names[i], float(v[i]))


class TrackingErrorInterlock:
    """|commanded − measured position| must stay within each joint's bound (rad or m)."""

    name = "tracking_error"

    def __init__(self, bound: float | Sequence[float], names: Sequence[str],
                 kinds: Sequence[str] | None = None) -> None:
        self.names = list(names)
        self.kinds = _kinds(kinds, self.names)
        self.bound = _per_joint(bound, self.names, "tracking-error bound")
        if np.any(self.bound <= 0):
            raise ValueError(f"tracking-error bounds must be positive, got {self.bound}")

    def may_trip(self, position: np.ndarray, velocity: np.ndarray,
                 commanded: np.ndarray) -> np.ndarray:
        return ~(np.abs(commanded - position) <= self.bound).all(axis=1)

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        _check_shape(self.name, self.names, measured.position, "measured position")
        _check_shape(self.name, self.names, commanded, "commanded position")
        err = np.asarray(commanded, dtype=float) - np.asarray(measured.position, dtype=float)
        bad = ~(np.abs(err) <= self.bound)
        if not bad.any():
            return None
        i = int(np.argmax(bad))
        k = self.kinds[i]
        return Trip(self.name, f"{self.names[i]} is {_amount(abs(err[i]), k)} off its command "
                    f"(limit {_amount(self.bound[i], k)})", t, self.names[i], float(err[i]))


class StaleDataInterlock:
    """Trips when the backend flags a reading as stale (``measured.flags`` entry ``stale:…``)."""

    name = "stale_data"

    def may_trip(self, position: np.ndarray, velocity: np.ndarray,
                 commanded: np.ndarray) -> np.ndarray:
        return np.zeros(len(position), dtype=bool)  # a scanned block carries no flags

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        for flag in measured.flags:
            if flag.startswith("stale:"):
                what = flag[len("stale:"):] or None
                return Trip(self.name, f"stale data from {what or 'the backend'} ({flag})", t,
                            what)
        return None


class GantryClearanceInterlock:
    """Trips when any link comes closer to the CT gantry than the margin (seed 001: 20 mm).

    Uses the per-cycle :class:`bench.scene.contact.GantryClearance` (a certified
    lower bound of the exact mesh distance, about 0.1-0.3 ms) at the measured
    positions and, unless ``check_commanded`` is False, at the commanded
    ones too, so a command into the margin stops before the robot gets there.
    With ``reuse`` the last full result is carried forward while it provably
    still clears the margin: no point of the robot moves farther than
    ``sum(levers · |Δq|)`` (:attr:`RobotGeometry.levers`), so the check costs
    a few microseconds until the robot has moved that close.

    ``lookahead_s`` also checks where the measured motion leads within that
    time (position + velocity · lookahead): a robot cannot stop in zero time,
    so the trip comes early enough for the hold to halt it outside the margin.
    """

    name = "gantry_clearance"
    stateful = True  # the carried-forward result changes at every exact check
    #: Rounding allowance between the block bound and the per-cycle one (m).
    _SCAN_SLACK = 1e-9

    def __init__(self, model, margin: float = 0.020, clearance=None,
                 check_commanded: bool = True, reuse: bool = True,
                 lookahead_s: float = 0.0) -> None:
        if lookahead_s < 0:
            raise ValueError(f"lookahead_s must be >= 0, got {lookahead_s}")
        self.lookahead_s = float(lookahead_s)

        self.margin = float(margin)
        self.clearance = clearance if clearance is not None else GantryClearance(model, self.margin)
        self.names = list(model.joint_names)
        self.check_commanded = check_commanded
        self.reuse = reuse
        self._levers = self.clearance.geometry.levers
        self._last_q: np.ndarray | None = None
        self._last_d = -np.inf

    def may_trip(self, position: np.ndarray, velocity: np.ndarray,
                 commanded: np.ndarray) -> np.ndarray:
        """Rows where the carried-forward bound does not clear every checked position."""
        if not self.reuse or self._last_q is None:
            return np.ones(len(position), dtype=bool)
        sources = [position, position + velocity * self.lookahead_s]
        if self.check_commanded:
            sources.append(commanded)
        reach = np.abs(np.stack(sources, axis=1) - self._last_q) @ self._levers
        return ~(self._last_d - reach >= self.margin + self._SCAN_SLACK).all(axis=1)

    def _distance(self, q: np.ndarray) -> tuple[float, str | None]:
        """A lower bound of the clearance at q, and the closest link when computed afresh."""
        if self.reuse and self._last_q is not None:
            d = self._last_d - float(self._levers @ np.abs(q - self._last_q))
            if d >= self.margin:
                return d, None
        c = self.clearance.check(q)
        self._last_q, self._last_d = q.copy(), c.distance
        return c.distance, c.link

    def check(self, t: float, measured: JointState, commanded: np.ndarray) -> Trip | None:
        if self.reuse and self._last_q is not None and self.check_commanded \
                and measured.position.shape == commanded.shape == self._last_q.shape:
            # Every source at once against the carried-forward bound: the common case.
            ahead = measured.position + measured.velocity * self.lookahead_s
            stack = np.stack((measured.position, ahead, commanded))
            if (self._last_d - np.abs(stack - self._last_q) @ self._levers >= self.margin).all():
                return None
        _check_shape(self.name, self.names, measured.position, "measured position")
        sources = [("measured", measured.position)]
        if self.lookahead_s > 0 and np.all(np.isfinite(measured.velocity)):
            ahead = measured.position + measured.velocity * self.lookahead_s
            sources.append((f"predicted ({self.lookahead_s * 1e3:.0f} ms ahead)", ahead))
        if self.check_commanded:
            _check_shape(self.name, self.names, commanded, "commanded position")
            sources.append(("commanded", commanded))
        for label, q in sources:
            q = np.asarray(q, dtype=float)
            if not np.all(np.isfinite(q)):
                return Trip(self.name, f"{label} position is not finite: {q}", t)
            d, link = self._distance(q)
            if d < self.margin:
                return Trip(self.name, f"{link} is {d * 1e3:.1f} mm from the gantry at the "
                            f"{label} position (margin {self.margin * 1e3:.1f} mm)", t, None, d)
        return None
