"""Joint-space trajectory generators behind one :class:`Trajectory` protocol."""

from .base import Limits, Trajectory, TrajectoryError
from .excitation import Excitation, ExcitationSpec
from .lspb import LSPB
from .ruckig_traj import RuckigOnline, RuckigTrajectory

__all__ = ["LSPB", "Excitation", "ExcitationSpec", "Limits", "RuckigOnline", "RuckigTrajectory", "Trajectory", "TrajectoryError"]
