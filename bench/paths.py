"""Where the project's own data lives: the checkout's root, its ``urdf/`` folder, a robot's URDF."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

REPO_ROOT = Path(__file__).resolve().parent.parent
URDF_DIR = REPO_ROOT / "urdf"


def robot_urdf(robot: str, urdf_dir: Optional[Path | str] = None) -> Path:
    """The URDF of ``robot`` ("arc-train" → urdf/arc_train.urdf); a relative folder is the project's."""
    d = Path(urdf_dir) if urdf_dir is not None else URDF_DIR
    return (d if d.is_absolute() else REPO_ROOT / d) / f"{robot.replace('-', '_')}.urdf"
