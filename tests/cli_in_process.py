"""``hilbench`` run in the test's own process, for tests of what a command prints, exits with and
writes: its parsing, output and exit code are the command line's own code, without an interpreter
started and the bench imported again for each command (tests of the process itself, signals, the
installed entry point, start-up, run ``hilbench`` as a subprocess)."""

from __future__ import annotations

from click.testing import Result
from typer.testing import CliRunner


def invoke(*args: str, columns: int | None = None) -> Result:
    """``hilbench ARGS`` in this process; ``columns``: the terminal's width, as COLUMNS gives it to a
    command in a pipe. An exception the command does not handle fails the test, as a traceback on
    stderr would."""
    from bench.cli.app import app  # deferred: collecting a test file imports no command

    env = None if columns is None else {"COLUMNS": str(columns)}
    return CliRunner(env=env).invoke(app, list(args), catch_exceptions=False)
