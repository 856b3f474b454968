"""Where the bench's shipped data lives, and how a path a config names is found.

The robots' URDFs and the shipped configs are the package's data: a wheel carries them
as ``bench/data/urdf`` and ``bench/data/hil_configs`` (found through importlib.resources);
a checkout (an editable install, or the tests) has them at its top, ``urdf/`` and
``hil_configs/``. Every lookup at run time goes through :data:`DATA_ROOT`, so a command
works from any directory, installed either way. :data:`REPO_ROOT` is the checkout's root,
for the tests and the generated docs only.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Optional

__all__ = ["CONFIG_DIR", "DATA_ROOT", "REPO_ROOT", "URDF_DIR", "data_root", "resolve_named", "robot_urdf"]

REPO_ROOT = Path(__file__).resolve().parent.parent


def data_root() -> Path:
    """The folder holding ``urdf/`` and ``hil_configs/``: the installed package's data when it
    has them (a wheel), else the checkout's top (whose ``bench/data`` holds no copies)."""
    packaged = resources.files("bench.data")
    if packaged.joinpath("urdf").is_dir() and packaged.joinpath("hil_configs").is_dir():
        return Path(str(packaged))
    return REPO_ROOT


DATA_ROOT = data_root()
URDF_DIR = DATA_ROOT / "urdf"
CONFIG_DIR = DATA_ROOT / "hil_configs"


def resolve_named(path: Path | str, beside: Optional[Path | str] = None) -> Path:
    """A path a config names: absolute as written; relative, beside the config's own file
    (``beside``, its folder) when it is there, else in the shipped data (``hil_configs/…``,
    ``urdf``), so a lab folder written by ``hilbench init`` and the shipped configs both resolve."""
    p = Path(path)
    if p.is_absolute():
        return p
    if beside is not None:
        local = Path(beside) / p
        if local.exists():
            return local
    return DATA_ROOT / p


def robot_urdf(robot: str, urdf_dir: Optional[Path | str] = None) -> Path:
    """The URDF of ``robot`` ("arc-train" → urdf/arc_train.urdf); a relative folder, the shipped data's."""
    d = resolve_named(urdf_dir) if urdf_dir is not None else URDF_DIR
    return d / f"{robot.replace('-', '_')}.urdf"
