"""What every ``hilbench`` command shares: its consoles, the one-line refusal and the JSON line.

Bad input ends with one line on stderr (``error: …``) and exit code 2 before
anything moves; ``--json`` output is exactly one line on stdout.
"""

from __future__ import annotations

import json
import sys
from typing import NoReturn

import typer
from rich.console import Console

__all__ = ["console", "emit_json", "err_console", "fail"]

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
