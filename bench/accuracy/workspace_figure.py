"""The parallel robot's workspace map as a figure: conditioning maps and reach per needle direction."""

from __future__ import annotations

import pathlib

import numpy as np

from bench.kinematics.para_brachy import DEG, WorkspaceMap

__all__ = ["plot_workspace"]


def plot_workspace(result: WorkspaceMap, path: str | pathlib.Path) -> pathlib.Path:
    """Save a figure: X–Y maps of 1/cond(A), 1/cond(B) at the middle Z, ψ, θ, and reach per (ψ, θ).

    Uses matplotlib's object API with the Agg canvas, so it needs no display
    and does not touch pyplot's global state.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy: loaded only when a figure is drawn
    from matplotlib.figure import Figure  # heavy: loaded only when a figure is drawn

    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    g = result.grid
    kz, kp, kt = g.z.size // 2, g.psi.size // 2, g.theta.size // 2
    fig = Figure(figsize=(13.5, 4.2), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    extent = [g.x[0] * 1e3, g.x[-1] * 1e3, g.y[0] * 1e3, g.y[-1] * 1e3]
    for ax, data, title in (
        (axes[0], result.inv_cond_A, "1/cond(A) (type 2)"),
        (axes[1], result.inv_cond_B, "1/cond(B) (type 1)"),
    ):
        sl = np.ma.masked_invalid(data[:, :, kz, kp, kt].T)
        im = ax.imshow(sl, origin="lower", extent=extent, aspect="auto", vmin=0.0, cmap="viridis")
        ax.set_title(
            f"{title}\nZ={g.z[kz]*1e3:.0f} mm, psi={g.psi[kp]/DEG:.0f} deg, theta={g.theta[kt]/DEG:.0f} deg",
            fontsize=9,
        )
        ax.set_xlabel("X_E [mm]")
        ax.set_ylabel("Y_E [mm]")
        fig.colorbar(im, ax=ax)
    frac = result.reachable.mean(axis=(0, 1, 2))
    lo, hi = float(np.nanmin(frac)), float(np.nanmax(frac))
    if hi - lo < 0.005:  # reachability is the same everywhere: one colour would say nothing
        data = np.nanmin(np.where(result.reachable, result.margin, np.nan), axis=(0, 1, 2))
        title = (f"smallest singularity margin per orientation\n(over all tip positions; "
                 f"{lo:.0%} of them reachable at every orientation)")
        fmt = None
    else:
        data, fmt = frac, (lambda v, _: f"{v:.0%}")
        title = "reachable fraction of tip positions per orientation"
    im = axes[2].imshow(
        data.T, origin="lower", aspect="auto", cmap="magma",
        extent=[g.psi[0] / DEG, g.psi[-1] / DEG, g.theta[0] / DEG, g.theta[-1] / DEG])
    axes[2].set_title(title, fontsize=9)
    axes[2].set_xlabel("psi [deg]")
    axes[2].set_ylabel("theta [deg]")
    fig.colorbar(im, ax=axes[2], format=fmt)
    fig.savefig(path, dpi=110)
    return path
