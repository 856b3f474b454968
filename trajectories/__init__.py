"""Joint-space trajectory generators behind one :class:`Trajectory` protocol."""

from .base import Limits, Trajectory, TrajectoryError
from .lspb import LSPB
from .ruckig_traj import RuckigOnline, RuckigTrajectory

__all__ = ["LSPB", "Limits", "RuckigOnline", "RuckigTrajectory", "Trajectory", "TrajectoryError"]
