"""What every ``hilbench`` command shares: its consoles, the one-line refusal and the JSON line.

Bad input ends with one line on stderr (``error: …``) and exit code 2 before
anything moves; ``--json`` output is exactly one line on stdout.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer
from rich.console import Console

if TYPE_CHECKING:
    from bench.config.models import TrialConfig

__all__ = ["console", "emit_json", "err_console", "fail", "load_config"]

console = Console()
err_console = Console(stderr=True, highlight=False)


def fail(message: str, code: int = 2) -> NoReturn:
    """One line on stderr, then exit with ``code`` (2: refused before anything moved)."""
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def emit_json(obj: object) -> None:
    """The command's result as one JSON line on stdout (flushed: scripts read it at once)."""
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def load_config(path: Path) -> "TrialConfig":
    """The trial config at ``path``, or exit 2 with the one line saying what is wrong in it."""
    from bench.config.models import ConfigError, load_trial_config  # deferred: --help stays fast

    try:
        return load_trial_config(path)
    except ConfigError as e:
        fail(str(e))
