"""``hilbench init DIR``: a lab folder holding the shipped configs, to edit."""

from __future__ import annotations

from pathlib import Path

import typer

from bench.cli.common import console, fail
from drivers.errors import ConfigError

__all__ = ["init"]


def init(folder: Path = typer.Argument(..., help="The lab folder to create (new or empty).")) -> None:
    """Write the shipped configs into a new lab folder to edit.

    Sim, lab rig, identification, test stand, campaigns and servo models, their layout kept."""
    from bench.config.shipped import write_lab_folder  # deferred: --help and completion stay fast

    try:
        written = write_lab_folder(folder)
    except ConfigError as e:
        fail(str(e))
    except OSError as e:
        fail(f"{folder}: cannot write the lab folder: {e.strerror}")
    console.print(f"wrote {len(written)} configs to {folder}/ (paths they name resolve there first, "
                  f"then in the installed package)", highlight=False, soft_wrap=True)
    console.print(f"next: hilbench trial {folder / 'sim_target1.yaml'}", highlight=False, soft_wrap=True)
