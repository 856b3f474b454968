"""``--live`` of ``trial`` and ``compare``: the live view served beside the run, its URL told once."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

from bench.cli.common import err_console, fail

if TYPE_CHECKING:
    from bench.live.process import LiveProcess

__all__ = ["live_view", "LIVE_HELP", "LIVE_WAIT_HELP", "LIVE_WAIT_S"]

LIVE_HELP = ("Serve a live view of the run on 127.0.0.1 (its URL, with a token, is printed on stderr): "
             "joints, phase, interlock margins, events, verdict, and a Stop button that stops as Ctrl-C does.")
LIVE_WAIT_HELP = ("With --live, wait up to this many seconds for a page to open before anything moves "
                  "(a browser opening a page takes the computer's CPU for a second); 0 starts at once.")
#: How long ``--live`` waits for a page by default (s).
LIVE_WAIT_S = 20.0


@contextmanager
def live_view(enabled: bool, config: Path, out: Path,
              guard, wait_s: float = 0.0,
              tell: Callable[[str], None] | None = None) -> Iterator["LiveProcess | None"]:
    """The live view of the runs the command writes under ``out`` (None when not asked for), served
    by a process of its own (:mod:`bench.live.process`); ``config`` is the trial config whose
    interlock margins the page shows. With
    ``wait_s`` it returns once a page is open, or after ``wait_s`` without one, saying so through
    ``tell`` (a progress bar's line) or, on a terminal, a status line of its own."""
    if not enabled:
        yield None
        return
    from bench.live.process import LiveProcess  # deferred: only --live serves a page

    try:
        server = LiveProcess(out, config, on_stop=lambda: guard.request_stop("Stop pressed in the live view"))
    except RuntimeError as e:
        fail(str(e))
    with server:
        err_console.print(f"live view: {server.url}", markup=False, highlight=False, soft_wrap=True)
        if wait_s > 0:
            what = f"waiting up to {wait_s:g} s for the live view's page to open (--live-wait 0 starts at once)"
            if tell is not None:
                tell(what)
                server.wait_for_page(wait_s, guard.check)
            elif err_console.is_terminal:
                with err_console.status(what):
                    server.wait_for_page(wait_s, guard.check)
            else:
                server.wait_for_page(wait_s, guard.check)
        yield server
