"""What every ``hilbench`` command shares: its consoles, the one-line refusal and the JSON line.

Bad input ends with one line on stderr (``error: …``) and exit code 2 before
anything moves; ``--json`` output is exactly one line on stdout.

No text from outside — a config's values and keys, a robot name, a path, a log, a
servo's reply — is ever read as console markup: both consoles have markup off, and the
command line's own styling goes through :func:`styled`, which takes the outside text as
plain values.
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.text import Text

from bench.core.interrupts import signal_name
from drivers.errors import ConfigError, ExitCode, signal_exit_code

if TYPE_CHECKING:
    from bench.config.models import TrialConfig

__all__ = ["console", "emit_json", "err_console", "fail", "interrupted", "load_config", "say",
           "signum_of", "stopped", "styled"]

console = Console(markup=False)
err_console = Console(stderr=True, highlight=False, markup=False)

#: Set once a command has printed its own line for a stop signal (the entry point then adds none).
said_interrupted = False


def styled(template: str, *values: object) -> Text:
    """``template`` (this package's own markup, ``{}`` for each value) with ``values`` as plain
    text: a bracket in a value is printed as it is, never read as a style."""
    return Text.from_markup(template.format(*(escape(str(v)) for v in values)))


def say(template: str, *values: object) -> None:
    """One styled line on stderr (see :func:`styled`), soft-wrapped: a terminal never cuts it."""
    err_console.print(styled(template, *values), soft_wrap=True)


def fail(message: str, code: int = ExitCode.REFUSED) -> NoReturn:
    """One line on stderr, then exit with ``code`` (2: refused before anything moved)."""
    say("[bold red]error:[/] {}", message)
    raise typer.Exit(int(code))


def signum_of(e: BaseException) -> int:
    """The signal behind a ``KeyboardInterrupt`` (a guard's ``TrialInterrupted`` says; a bare one
    is Ctrl-C)."""
    return int(getattr(e, "signum", signal.SIGINT))


def interrupted(signum: int, message: str) -> NoReturn:
    """The one line of a command stopped by signal ``signum`` (``interrupted by SIGTERM: …``),
    then exit 128 + N."""
    say("[bold red]interrupted by {}:[/] {}", signal_name(signum), message)
    stopped(signum)


def stopped(signum: int) -> NoReturn:
    """Exit 128 + N for a stop signal that the command's own line has spoken of."""
    global said_interrupted
    said_interrupted = True
    raise typer.Exit(signal_exit_code(signum))


def emit_json(obj: object) -> None:
    """The command's result as one JSON line on stdout (flushed: scripts read it at once)."""
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


CLOCK_HELP = ("The emulated rig's clock, with --emulate: realtime (the rig's pace; the default unless the "
              "config's emulator.clock says otherwise) or virtual (time advances when each instant's work "
              "is done: the same log bit for bit on any machine, as fast as the CPU allows).")


CAPTURE_HELP = ("Write every byte the bench sends and receives on its serial ports to FILE, one chunk a line "
                "with its time and port (servo bus or ultrasonic sensor): on the virtual clock the same file "
                "bit for bit on any machine.")


@contextlib.contextmanager
def wire_capture(path: "Path | None"):
    """The ports opened inside write to a wire capture at ``path`` (nothing when None)."""
    if path is None:
        yield
        return
    from drivers.link import capturing  # deferred: --help and completion stay fast
    from drivers.wirecapture import WireCapture  # deferred: --help and completion stay fast

    try:
        capture = WireCapture(path).__enter__()
    except OSError as e:
        fail(f"--capture {path}: {e.strerror or e}")
    try:
        with capturing(capture):
            yield
    finally:
        capture.__exit__()


def checked_clock(emulate: bool, clock: "str | None") -> "str | None":
    """``--clock`` as given, or exit 2 with one line: it sets an emulated rig's clock, and a real
    rig keeps the wall clock."""
    if clock is None:
        return None
    if clock not in ("realtime", "virtual"):
        fail(f"--clock {clock}: choose realtime or virtual")
    if not emulate:
        fail(f"--clock {clock} sets the emulated rig's clock: add --emulate (a real rig keeps the "
             f"wall clock)")
    return clock


def load_config(path: Path) -> "TrialConfig":
    """The trial config at ``path``, or exit 2 with the one line saying what is wrong in it."""
    from bench.config.models import load_trial_config  # deferred: --help and completion stay fast

    try:
        return load_trial_config(path)
    except ConfigError as e:
        fail(str(e))
