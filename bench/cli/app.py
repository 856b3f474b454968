"""``hilbench``'s entry point: a stop signal gets one line and exit 128 + N from the first instant.

The console script imports this module first. It holds only the standard library and the
light signal and error modules, so the stop-signal handlers are in place before typer,
rich, numpy and the library load (half a second): a Ctrl-C, SIGTERM or SIGHUP while the
command is still starting ends it with one line, never a traceback or a silent death.
Commands that move something install their own guard over this one and say how they left
the rig; any other command stopped by a signal gets the generic line here.
"""

from __future__ import annotations

import importlib
import signal
import sys
from types import ModuleType
from typing import Any, NoReturn, Optional

from bench.core.interrupts import SignalGuard, signal_name
from drivers.errors import ExitCode, signal_exit_code

__all__ = ["main"]


def main() -> NoReturn:  # pragma: no cover - console entry point (tests run it as a process)
    """Run ``hilbench`` with the stop signals handled from the start; exit with the command's code."""
    guard = SignalGuard().__enter__()  # first of all; held to the end of the process
    commands: Optional[ModuleType] = None
    code: Any = ExitCode.PASSED
    try:
        # imported here, once the handlers are in place: typer, rich and the library take ~0.5 s
        commands = importlib.import_module("bench.cli.commands")
        guard.check()  # a signal swallowed while importing still stops here
        commands.run()
    except SystemExit as e:
        code = e.code
    except KeyboardInterrupt as e:
        code = signal_exit_code(getattr(e, "signum", signal.SIGINT))
    guard.settle()  # from here on a signal is only noted: the last line gets out whole
    code = _final_code(code, guard, commands is not None)
    sys.stdout.flush()
    sys.stderr.flush()
    raise SystemExit(code)


def _final_code(code: Any, guard: SignalGuard, started: bool) -> int:
    """The exit code, and the one line for a signal no command has spoken of."""
    code = _as_int(code)
    common = sys.modules.get("bench.cli.common")
    if getattr(common, "said_interrupted", False):
        return code
    signum = guard.signum
    if signum is None and code == signal_exit_code(signal.SIGINT):
        signum = signal.SIGINT  # a Ctrl-C raised by a handler of the command's own (typer's 130)
    if signum is None:
        return code
    what = " ".join(a for a in sys.argv[1:2] if not a.startswith("-")) or "command"
    where = (" while it was still starting; nothing had moved" if not started else
             "; nothing had moved" if not SignalGuard.nested_entered else "")
    sys.stderr.write(f"interrupted by {signal_name(signum)}: hilbench {what} stopped{where}\n")
    return signal_exit_code(signum)


def _as_int(code: Any) -> int:
    if code is None:
        return int(ExitCode.PASSED)
    if isinstance(code, int):
        return code
    sys.stderr.write(f"{code}\n")  # sys.exit("message"): Python prints it and exits 1
    return int(ExitCode.FAILED)


def __getattr__(name: str) -> Any:
    """``bench.cli.app.app``: the typer application, for tests and ``typer.testing``."""
    if name == "app":
        return importlib.import_module("bench.cli.commands").app
    raise AttributeError(f"module 'bench.cli.app' has no attribute {name!r}")


if __name__ == "__main__":  # pragma: no cover
    main()
