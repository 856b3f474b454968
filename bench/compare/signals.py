"""Trial logs as signals: samples in time order, a common time base, first motion, velocity lag.

Logs come at different rates and with dropped samples; resampling leaves gaps longer than
``max_gap`` empty (NaN) instead of inventing data across them."""

from __future__ import annotations

import math
import warnings

import numpy as np

from bench.core.log import TrialLog
from drivers.errors import PlanMismatchError


DEFAULT_MAX_LAG_S = 1.0  #: lags searched within ± this (s)


LAG_SMOOTH_S = 0.05  #: half-width of the velocity's central difference for the lag (s)


LAG_CLIP = 2.0  #: measured speeds beyond this × the joint's peak commanded speed are clipped


def log_samples(log: TrialLog) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(time, segment, q_cmd, q, effort) in time order, rows without a finite time dropped."""
    t = np.asarray(log.time, dtype=float)
    keep = np.isfinite(t)
    order = np.argsort(t[keep], kind="stable")
    idx = np.flatnonzero(keep)[order]
    t = t[idx]
    # repeated time stamps carry no new information about timing: keep the first
    if t.size > 1:
        first = np.concatenate([[True], np.diff(t) > 0])
        idx, t = idx[first], t[first]
    return (t, np.asarray(log.segment)[idx], np.asarray(log.q_cmd, dtype=float)[idx],
            np.asarray(log.q, dtype=float)[idx], np.asarray(log.effort, dtype=float)[idx])


def sample_period(t: np.ndarray) -> float:
    """The log's sampling period: the median step (robust to dropped samples)."""
    if t.size < 2:
        raise ValueError(f"a log needs at least two samples to have a rate, it has {t.size}")
    return float(np.median(np.diff(t)))


def resample(t: np.ndarray, y: np.ndarray, grid: np.ndarray, max_gap: float) -> np.ndarray:
    """Linear interpolation of ``y`` (N,) or (N, n) onto ``grid``, per column over its finite
    samples; grid points outside the samples or inside a gap longer than ``max_gap`` are NaN."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    grid = np.asarray(grid, dtype=float)
    cols = y.reshape(len(t), -1)
    out = np.full((grid.size, cols.shape[1]), np.nan)
    for j in range(cols.shape[1]):
        ok = np.isfinite(cols[:, j])
        tf, yf = t[ok], cols[ok, j]
        if tf.size < 2:
            continue
        v = np.interp(grid, tf, yf)
        k = np.clip(np.searchsorted(tf, grid), 1, tf.size - 1)
        gap = tf[k] - tf[k - 1]
        exact = np.isin(grid, tf)
        bad = (grid < tf[0]) | (grid > tf[-1]) | ((gap > max_gap + 1e-12) & ~exact)
        v[bad] = np.nan
        out[:, j] = v
    return out.reshape((grid.size,) + y.shape[1:])


def first_motion_time(t: np.ndarray, q_cmd: np.ndarray, rtol: float = 1e-9) -> float:
    """Time of the last commanded sample before the command first changes.

    The runner commands the start pose at a segment's first sample and the
    profile leaves it at the next, so this is the instant the plan started.
    """
    q = np.asarray(q_cmd, dtype=float)
    ok = np.all(np.isfinite(q), axis=1)
    t, q = np.asarray(t)[ok], q[ok]
    if t.size < 2:
        raise ValueError("the log has fewer than two commanded samples: no motion to align on")
    tol = 1e-12 + rtol * np.maximum(1.0, np.abs(q[0]))
    moved = np.flatnonzero(np.any(np.abs(q[1:] - q[0]) > tol, axis=1))
    if moved.size == 0:
        raise ValueError("the commanded profile never moves: no first motion to align on")
    return float(t[moved[0]])


def max_gap_for(dt: float) -> float:
    """The longest gap bridged by interpolation: a few periods, never under 50 ms."""
    return max(5.0 * dt, 0.05)


def velocity_lag(v_cmd: np.ndarray, v_meas: np.ndarray, dt: float,
                 max_lag_s: float = DEFAULT_MAX_LAG_S) -> float:
    """Delay (s) of ``v_meas`` behind ``v_cmd`` (uniformly sampled, NaN = no data).

    The peak of their cross-correlation within ±``max_lag_s``, refined by a
    parabola through the peak and its neighbours. Positive: measured is late.
    NaN when either velocity is zero throughout.
    """
    a = np.asarray(v_cmd, dtype=float).copy()
    b = np.asarray(v_meas, dtype=float).copy()
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"velocities must be 1-D of equal length, got {a.shape} and {b.shape}")
    gone = ~np.isfinite(a) | ~np.isfinite(b)
    a[gone] = 0.0
    b[gone] = 0.0
    if not np.any(a) or not np.any(b):
        return math.nan
    n = a.size
    kmax = int(min(n - 1, max(1, round(max_lag_s / dt))))
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    c = np.fft.irfft(np.fft.rfft(b, nfft) * np.conj(np.fft.rfft(a, nfft)), nfft)
    lags = np.arange(-kmax, kmax + 1)
    cc = c[lags % nfft]  # cc[k] = sum_i b[i + k] a[i]
    i = int(np.argmax(cc))
    frac = 0.0
    if 0 < i < cc.size - 1:
        y0, y1, y2 = cc[i - 1], cc[i], cc[i + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0:
            frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    return float((lags[i] + frac) * dt)


def smoothed_velocity(y: np.ndarray, dt: float, half_width_s: float = 0.0) -> np.ndarray:
    """Central difference over ±``half_width_s`` (at least one sample) on a uniform grid.

    Symmetric, so it shifts nothing in time; the wider baseline averages out the
    servos' 4096-tick quantisation, which at a slow joint's speed is a few ticks
    per second and would otherwise make the velocity mostly spikes. Before its
    first and after its last finite sample a column is taken to rest where it
    was (a log starts as its first motion does: cutting the ends would cut the
    command's start but not a late measurement's, and bias the lag). NaN where
    a neighbour inside the series is missing.
    """
    y = np.asarray(y, dtype=float)
    m = max(1, int(round(half_width_s / dt)))
    cols = y.reshape(y.shape[0], -1)
    v = np.full(cols.shape, np.nan)
    for j in range(cols.shape[1]):
        c = cols[:, j]
        fin = np.flatnonzero(np.isfinite(c))
        if fin.size < 2:
            continue
        padded = np.concatenate([np.full(m, c[fin[0]]), c, np.full(m, c[fin[-1]])])
        padded[m:m + fin[0]] = c[fin[0]]
        padded[m + fin[-1] + 1:m + c.size] = c[fin[-1]]
        v[:, j] = (padded[2 * m:] - padded[:-2 * m]) / (2 * m * dt)
    return v.reshape(y.shape)


def nanmedian(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """Median ignoring NaN; all-NaN columns give NaN without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(a, axis=axis)


def nanmean(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """Mean ignoring NaN; all-NaN columns give NaN without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(a, axis=axis)
