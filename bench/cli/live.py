"""``--live`` of ``trial`` and ``compare``: the live view served beside the run, its URL told once."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

from bench.cli.common import err_console

if TYPE_CHECKING:
    from bench.core.result import PreparedTrial
    from bench.live.server import LiveServer

__all__ = ["live_view", "LIVE_HELP"]

LIVE_HELP = ("Serve a live view of the run on 127.0.0.1 (its URL, with a token, is printed on stderr): "
             "joints, phase, interlock margins, events, verdict, and a Stop button that stops as Ctrl-C does.")


@contextmanager
def live_view(enabled: bool, prepared: Callable[[], "PreparedTrial"], out: Path,
              guard) -> Iterator["LiveServer | None"]:
    """The live view of the runs the command writes under ``out`` (None when not asked for);
    ``prepared`` gives the prepared trial whose interlock margins the page shows."""
    if not enabled:
        yield None
        return
    from bench.live.follow import RunFollower  # deferred: only --live serves a page
    from bench.live.server import LiveServer  # deferred: only --live serves a page

    server = LiveServer(RunFollower(out, prepared), on_stop=lambda: guard.request_stop("Stop pressed in the live view"))
    with server:
        err_console.print(f"live view: {server.url}", markup=False, highlight=False, soft_wrap=True)
        yield server
