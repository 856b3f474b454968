"""The workspace map: reachability, conditioning and singularity margin over a grid of poses, saved as npz/csv."""

from __future__ import annotations

import csv
import json
import pathlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.para_brachy.geometric import _IGM_OK, IGM_FAILURES, _igm_core
from bench.kinematics.para_brachy.jacobians import inverse_condition
from bench.kinematics.para_brachy.model import (
    DEFAULT_PARAMS,
    DEG,
    WORKSPACE_CENTRE,
    ParaBrachyParams,
    _mode_signs,
)
from bench.kinematics.para_brachy.singularities import _TYPE1, _TYPE2, SingularityCase, singularity_factors

# ---------------------------------------------------------------------------
# Workspace map
# ---------------------------------------------------------------------------


POSE_NAMES_GRID = ("x", "y", "z", "psi", "theta")


@dataclass(frozen=True)
class WorkspaceGrid:
    """Axes of a pose grid: tip X, Y, Z (m), ψ, θ (rad); 1-D arrays."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    psi: np.ndarray
    theta: np.ndarray

    def __post_init__(self) -> None:
        for name in POSE_NAMES_GRID:
            arr = np.atleast_1d(np.asarray(getattr(self, name), dtype=float))
            if arr.ndim != 1 or arr.size == 0 or not np.isfinite(arr).all():
                raise ValueError(f"WorkspaceGrid.{name} must be a non-empty finite 1-D array, got {arr!r}")
            object.__setattr__(self, name, arr)

    @classmethod
    def around(
        cls,
        centre: ArrayLike = WORKSPACE_CENTRE,
        half_width: float = 0.06,
        half_depth: float = 0.03,
        psi_half_range: float = 30.0 * DEG,
        theta_range: tuple[float, float] = (10.0 * DEG, 40.0 * DEG),
        n: Sequence[int] = (13, 13, 7, 7, 7),
    ) -> "WorkspaceGrid":
        """The default CT-bed workspace: X, Y ± 6 cm, Z ± 3 cm, ψ ± 30°, θ 10°–40°."""
        c = np.asarray(centre, dtype=float)
        if len(n) != 5 or min(n) < 1:
            raise ValueError(f"n must be 5 positive grid sizes, got {tuple(n)!r}")
        return cls(
            x=np.linspace(c[0] - half_width, c[0] + half_width, n[0]),
            y=np.linspace(c[1] - half_width, c[1] + half_width, n[1]),
            z=np.linspace(c[2] - half_depth, c[2] + half_depth, n[2]),
            psi=np.linspace(c[3] - psi_half_range, c[3] + psi_half_range, n[3]),
            theta=np.linspace(theta_range[0], theta_range[1], n[4]),
        )

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        return (self.x.size, self.y.size, self.z.size, self.psi.size, self.theta.size)

    def poses(self) -> np.ndarray:
        """All grid poses, shape ``self.shape + (5,)``."""
        mesh = np.meshgrid(self.x, self.y, self.z, self.psi, self.theta, indexing="ij")
        return np.stack(mesh, axis=-1)


@dataclass(frozen=True)
class WorkspaceMap:
    """Reachability and conditioning over a :class:`WorkspaceGrid` (arrays shaped ``grid.shape``).

    ``fail_code`` is 0 where reachable, else a key of ``IGM_FAILURES``;
    ``inv_cond_A`` / ``inv_cond_B`` are NaN where unreachable;
    ``margin`` is the smallest normalised singularity factor and ``nearest``
    the index into ``cases`` of the factor that attains it.
    """

    grid: WorkspaceGrid
    params: ParaBrachyParams
    q: np.ndarray
    reachable: np.ndarray
    fail_code: np.ndarray
    inv_cond_A: np.ndarray
    inv_cond_B: np.ndarray
    margin: np.ndarray
    nearest: np.ndarray
    cases: tuple[str, ...]

    @property
    def reachable_fraction(self) -> float:
        return float(np.mean(self.reachable))


def workspace_map(
    grid: WorkspaceGrid | None = None,
    params: ParaBrachyParams = DEFAULT_PARAMS,
    working_mode: Sequence[int] = (1, 1),
    *,
    check_limits: bool = True,
) -> WorkspaceMap:
    """Evaluate the IGM, conditioning and singularity margin on every grid pose."""
    grid = WorkspaceGrid.around() if grid is None else grid
    x = grid.poses()
    q, code, extra = _igm_core(x, params, _mode_signs(working_mode), check_limits)
    ok = code == _IGM_OK
    q_safe = np.nan_to_num(extra["q_raw"])  # unreachable entries are masked below
    with np.errstate(invalid="ignore", divide="ignore"):
        ica, icb = inverse_condition(q_safe, x, params)
        factors = singularity_factors(q_safe, x, params)
    cases = tuple(c.value for c in (*_TYPE1, *_TYPE2))
    stack = np.stack([factors[SingularityCase(c)] for c in cases], axis=-1)
    nearest = np.argmin(stack, axis=-1).astype(np.int8)
    margin = np.min(stack, axis=-1)
    nan = np.nan
    return WorkspaceMap(
        grid=grid,
        params=params,
        q=q,
        reachable=ok,
        fail_code=code,
        inv_cond_A=np.where(ok, ica, nan),
        inv_cond_B=np.where(ok, icb, nan),
        margin=np.where(ok, margin, nan),
        nearest=np.where(ok, nearest, -1).astype(np.int8),
        cases=cases,
    )


def save_workspace(
    result: WorkspaceMap, path: str | pathlib.Path, *, csv_path: str | pathlib.Path | None = None
) -> pathlib.Path:
    """Write the map to ``path`` (.npz; parameters as JSON) and optionally a flat CSV.

    The .npz keeps the grid axes and full arrays for later analysis; the CSV
    has one row per grid pose for spreadsheets.
    """
    path = pathlib.Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"workspace file must end in .npz, got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    g = result.grid
    np.savez_compressed(
        path,
        x=g.x,
        y=g.y,
        z=g.z,
        psi=g.psi,
        theta=g.theta,
        q=result.q,
        reachable=result.reachable,
        fail_code=result.fail_code,
        inv_cond_A=result.inv_cond_A,
        inv_cond_B=result.inv_cond_B,
        margin=result.margin,
        nearest=result.nearest,
        cases=np.array(result.cases),
        fail_reasons=json.dumps({str(k): v for k, v in IGM_FAILURES.items()}),
        params=json.dumps(result.params.as_dict()),
    )
    if csv_path is not None:
        csv_path = pathlib.Path(csv_path)
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        poses = g.poses().reshape(-1, 5)
        q = result.q.reshape(-1, 5)
        cols = [
            result.reachable.ravel(),
            result.fail_code.ravel(),
            result.inv_cond_A.ravel(),
            result.inv_cond_B.ravel(),
            result.margin.ravel(),
            result.nearest.ravel(),
        ]
        with csv_path.open("w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow([
                "X_E_m", "Y_E_m", "Z_E_m", "psi_rad", "theta_rad", "reachable", "fail_reason",
                "q1_m", "q2_m", "q3_rad", "q4_m", "q5_m", "inv_cond_A", "inv_cond_B",
                "singularity_margin", "nearest_case",
            ])
            for k in range(poses.shape[0]):
                code = int(cols[1][k])
                near = int(cols[5][k])
                wr.writerow([
                    *(f"{v:.9g}" for v in poses[k]),
                    int(cols[0][k]),
                    IGM_FAILURES.get(code, "") if code else "",
                    *(f"{v:.9g}" for v in q[k]),
                    f"{cols[2][k]:.6g}", f"{cols[3][k]:.6g}", f"{cols[4][k]:.6g}",
                    result.cases[near] if near >= 0 else "",
                ])
    return path
