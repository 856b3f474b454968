"""Which fitted values the logs tell, and why not where they do not.

A value is *observable* when its standard error (from :mod:`bench.identify.fit`: the cost's
curvature at the optimum, inflated by how far the others can stand in for it, at least the
cluster-robust error over the simulation windows) is within :data:`OBSERVABLE_FRACTION` of it,
the logs hold the constant speeds its kind of friction needs (:mod:`bench.identify.coverage`),
it is not at the edge of its range, and a friction value is not tied to one the logs cannot
tell. :func:`not_observable` says, per value that is not, why.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from bench.identify.coverage import speed_reasons
from bench.identify.simulate import PHYSICS

__all__ = ["OBSERVABLE_FLOOR", "OBSERVABLE_FRACTION", "cluster_robust_stderr", "not_observable",
           "parameter_correlation", "variance_inflation"]

#: Standard error below which a parameter counts as observable: this fraction of its value (two
#: standard errors within 10 %, leaving room for the bias a model mismatch adds) ...
OBSERVABLE_FRACTION = 0.05
#: ... or this much in absolute terms (for values near zero).
OBSERVABLE_FLOOR = {"kt_scale": 0.005, "armature_kgm2": 2e-4, "viscous_nms": 0.002, "coulomb_nm": 0.002,
                    "stribeck_nm": 0.002, "stribeck_velocity_rads": 0.005}


def cluster_robust_stderr(J: np.ndarray, r: np.ndarray, D: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """Per joint and parameter, the sandwich (cluster-robust) standard error H⁻¹BH⁻¹ with the
    simulation windows as clusters: how far the estimate would move were the windows another
    sample of the same motion. Where the model misses something, windows pull a parameter
    different ways, and this says so where the cost's curvature alone would not."""
    H = np.einsum("fmp,fmq->fpq", J, J) + D.T @ D
    n_clusters = int(clusters.max()) + 1
    g = np.zeros((J.shape[0], n_clusters, J.shape[2]))
    contrib = J * r[:, :, None]  # (F, m, P)
    for c in range(n_clusters):
        g[:, c, :] = contrib[:, clusters == c, :].sum(axis=1)
    B = np.einsum("fcp,fcq->fpq", g, g) * (n_clusters / max(n_clusters - 1, 1))
    inv = np.linalg.pinv(H)
    cov = inv @ B @ inv
    return np.sqrt(np.maximum(np.einsum("fpp->fp", cov), 0.0))


def variance_inflation(J: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Per joint and parameter, H_ii·(H⁻¹)_ii for H = JᵀJ + DᵀD (the prior keeps H invertible):
    1 for a parameter nothing else can mimic, large for one the others can stand in for."""
    H = np.einsum("fmp,fmq->fpq", J, J) + D.T @ D
    inv = np.linalg.pinv(H)
    return np.maximum(np.einsum("fpp->fp", H) * np.einsum("fpp->fp", inv), 1.0)


def parameter_correlation(J: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Per joint, the correlation between the parameters' estimates (F, P, P), from the Gauss-Newton
    Hessian: near ±1 for two the logs can trade one for the other."""
    inv = np.linalg.pinv(np.einsum("fmp,fmq->fpq", J, J) + D.T @ D)
    d = np.sqrt(np.maximum(np.einsum("fpp->fp", inv), 1e-300))
    return inv / (d[:, :, None] * d[:, None, :])


#: Above this correlation, a parameter's uncertainty is put down to the one it trades against.
TRADED = 0.8


#: A value this correlated with one the logs cannot tell is not told either: its estimate holds
#: only given the other's (a Coulomb level traded against a viscous slope the sweeps cannot fix).
ENTANGLED = 0.7


#: The values the entanglement rule applies to: the friction's. The motor constant and the
#: armature are told by the response's scale and phase, whatever split of friction goes with them.
FRICTION_KEYS = ("viscous_nms", "coulomb_nm", "stribeck_nm", "stribeck_velocity_rads")


def _entangled(why: dict[str, str], corr: np.ndarray) -> None:
    """Add to ``why`` the friction values entangled (:data:`ENTANGLED`) with one already in it."""
    changed = True
    while changed:
        changed = False
        for i, key in enumerate(PHYSICS):
            if key in why or key not in FRICTION_KEYS:
                continue
            for j, other in enumerate(PHYSICS):
                if other in why and j != i and abs(corr[i, j]) > ENTANGLED:
                    why[key] = (f"the logs trade it against {other} (correlation {corr[i, j]:+.2f}), which "
                                f"they cannot tell: only their combination is known")
                    changed = True
                    break


def _statistical_reason(key: str, value: float, stderr: float, corr: np.ndarray, i: int) -> str:
    """Why a value the logs' speeds could tell still came out uncertain."""
    share = f"{100 * stderr / abs(value):.0f} % of it" if value and np.isfinite(stderr) else "unbounded"
    others = np.abs(np.where(np.arange(len(PHYSICS)) == i, 0.0, corr[i]))
    j = int(np.argmax(others))
    if others[j] > TRADED:
        return (f"standard error {share}: the logs trade it against {PHYSICS[j]} "
                f"(correlation {corr[i, j]:+.2f}), telling their combination only")
    return f"standard error {share}: it moves the logs' simulation too little to tell"




def not_observable(values: Mapping[str, float], errors: Mapping[str, float], edge: tuple[str, ...],
                   speeds: np.ndarray, corr: np.ndarray) -> dict[str, str]:
    """Per value of one joint's fit (file keys) the logs cannot tell, why: the constant ``speeds``
    they lack, its standard error (and what it trades against, from the correlation matrix
    ``corr``), an ``edge`` of its range, or a friction value tied to one of those."""
    why = speed_reasons(values, speeds)
    for i, key in enumerate(PHYSICS):
        if key in why:
            continue
        if key in edge:
            why[key] = "the fit ran it to the edge of its range"
        elif not errors[key] <= max(OBSERVABLE_FRACTION * abs(values[key]), OBSERVABLE_FLOOR[key]):
            why[key] = _statistical_reason(key, values[key], errors[key], corr, i)
    _entangled(why, corr)
    return why
