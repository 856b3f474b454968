"""``hilbench schema | urdf build``: the files generated from the code (config reference, URDF scene)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from bench.cli.common import console, err_console, fail
from drivers.errors import ExitCode

__all__ = ["schema", "urdf_build"]


def schema(markdown: bool = typer.Option(False, "--markdown", help="The field reference (docs/config.md) instead."),
           out: Optional[Path] = typer.Option(None, "--out", help="Write to this file instead of stdout.")) -> None:
    """The trial config's JSON Schema, generated from the models (or its Markdown reference)."""
    from bench.config.reference import (  # deferred: --help and completion stay fast
        json_schema,
        markdown_reference,
    )

    text = markdown_reference() if markdown else json.dumps(json_schema(), indent=2) + "\n"
    if out is None:
        sys.stdout.write(text)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    err_console.print(f"wrote {out}", highlight=False)


def urdf_build(check: bool = typer.Option(False, "--check", help="Fail if the files differ instead of writing.")) -> None:
    """Write urdf/ from the parameter sets in bench/kinematics and bench/scene/room.py."""
    from bench.scene.room import (  # deferred: --help and completion stay fast
        URDF_DIR,
        generated_files,
        write_scene,
    )

    if check:
        stale = [rel for rel, text in generated_files().items()
                 if not (URDF_DIR / rel).exists() or (URDF_DIR / rel).read_text() != text]
        if stale:
            fail(f"out of date: {', '.join(stale)}; run `hilbench urdf build`", ExitCode.FAILED)
        console.print("urdf/ is up to date")
        return
    for p in write_scene():
        console.print(f"wrote {p}")
