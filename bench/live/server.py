"""The live view's server: one page, its data and its Stop button, on 127.0.0.1 behind a token.

Python's own threaded HTTP server is enough here (a handful of local browsers
polling a few times a second) and adds no dependency. Every request must carry
the run's random token and come from the loopback with a loopback ``Host``
(a page elsewhere cannot rebind a name to it); any other path is refused. The
page can ask for one thing only, the same safe stop as Ctrl-C: nothing on it
starts or moves anything.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import secrets
import sys
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib.resources import files
from pathlib import Path
from typing import Callable
from urllib.parse import parse_qs, urlsplit

from bench.live.follow import RunFollower

__all__ = ["LiveServer", "LINGER_S"]

#: After the run, how long the server waits for open pages to fetch the verdict.
LINGER_S = 3.0
#: A page that polled within this is open.
_OPEN_S = 2.0
_PATHS = ("/", "/data", "/stop", "/report")


def _page(token: str) -> bytes:
    assets = files("bench.live") / "assets"
    html = (assets / "page.html").read_text(encoding="utf-8")
    return (html.replace("/*UPLOT_CSS*/", (assets / "uPlot.min.css").read_text(encoding="utf-8"))
            .replace("/*UPLOT_JS*/", (assets / "uPlot.iife.min.js").read_text(encoding="utf-8"))
            .replace("__TOKEN__", token)).encode("utf-8")


class _QuietServer(ThreadingHTTPServer):
    """Python's threaded server, minus its traceback on stderr (the operator's) for each request
    that fails: a browser that goes away mid-request is nothing to report, anything else one line."""

    def handle_error(self, request, client_address) -> None:
        error = sys.exc_info()[1]
        if not isinstance(error, (ConnectionError, TimeoutError)):
            sys.stderr.write(f"live view: a request failed ({type(error).__name__}: {error})\n")


class LiveServer:
    """Serves the live view of the runs under ``follower.out`` until :meth:`close`."""

    def __init__(self, follower: RunFollower, on_stop: Callable[[], None],
                 host: str = "127.0.0.1", port: int = 0) -> None:
        self.follower = follower
        self.on_stop = on_stop
        self.token = secrets.token_urlsafe(18)
        self.stop_requested = False
        self._last_poll = -float("inf")
        self.polls = 0  # data requests answered: what a benchmark counts to know the page kept polling
        self.page_open = threading.Event()  # set by a page's first data request: it loaded and runs
        self._final_seen = False
        self._page = _page(self.token)
        self._httpd = _QuietServer((host, port), self._handler())
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="live-view", daemon=True)

    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}/?token={self.token}"

    def start(self) -> "LiveServer":
        self._thread.start()
        return self

    def close(self, linger: bool = True) -> None:
        """Stop serving; first, while a page is open, give it time to fetch the verdict."""
        if linger:
            deadline = time.monotonic() + LINGER_S
            while (time.monotonic() < deadline and time.monotonic() - self._last_poll < _OPEN_S
                   and not self._final_seen):
                time.sleep(0.05)
        self._httpd.shutdown()
        self._httpd.server_close()

    def __enter__(self) -> "LiveServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close(linger=exc[0] is None)

    # -- requests ---------------------------------------------------------------------
    def _allowed(self, handler: BaseHTTPRequestHandler) -> HTTPStatus | None:
        """Why a request is refused (None: it is not)."""
        try:
            local = ipaddress.ip_address(handler.client_address[0]).is_loopback
        except ValueError:
            local = False
        host = (handler.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]")
        if not local or host not in ("127.0.0.1", "localhost", "::1"):
            return HTTPStatus.FORBIDDEN
        url = urlsplit(handler.path)
        if url.path not in _PATHS:
            return HTTPStatus.NOT_FOUND
        token = parse_qs(url.query).get("token", [""])[0]
        if not hmac.compare_digest(token.encode(), self.token.encode()):
            return HTTPStatus.FORBIDDEN
        return None

    def _handler(self):
        server = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "hilbench-live"
            sys_version = ""

            def log_message(self, *args) -> None:  # the trial's console is the operator's, not ours
                pass

            def _send(self, status: HTTPStatus, body: bytes, kind: str = "text/plain; charset=utf-8") -> None:
                self.send_response(status)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.send_header("X-Content-Type-Options", "nosniff")
                self.send_header("X-Frame-Options", "DENY")
                self.send_header("Content-Security-Policy",
                                 "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
                                 "connect-src 'self'; img-src data:; frame-ancestors 'none'")
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(body)

            def _refused(self) -> bool:
                why = server._allowed(self)
                if why is not None:
                    self._send(why, f"{why.value} {why.phrase}\n".encode())
                    return True
                return False

            def do_GET(self) -> None:  # noqa: N802 - the http.server interface
                if self._refused():
                    return
                url = urlsplit(self.path)
                if url.path == "/":
                    self._send(HTTPStatus.OK, server._page, "text/html; charset=utf-8")
                elif url.path == "/data":
                    query = parse_qs(url.query)
                    snap = server.follower.poll()
                    try:
                        since = int(query.get("since", ["0"])[0])
                        epoch = int(query.get("epoch", ["-1"])[0])
                    except ValueError:
                        since, epoch = 0, -1
                    body = snap.since(since if epoch == snap.epoch else 0)
                    body["stop_requested"] = server.stop_requested
                    server._last_poll = time.monotonic()
                    server.polls += 1
                    server.page_open.set()
                    server._final_seen = snap.result is not None
                    self._send(HTTPStatus.OK, json.dumps(body).encode(), "application/json")
                elif url.path == "/report":
                    snap = server.follower.poll()
                    report = Path(snap.run_dir) / "report.html" if snap.run_dir else None
                    if report is None or not report.is_file():
                        self._send(HTTPStatus.NOT_FOUND, b"no report yet\n")
                    else:
                        self._send(HTTPStatus.OK, report.read_bytes(), "text/html; charset=utf-8")
                else:  # /stop is asked for with POST only: a link or a prefetch never stops a trial
                    self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"405 use POST\n")

            def do_POST(self) -> None:  # noqa: N802 - the http.server interface
                if self._refused():
                    return
                if urlsplit(self.path).path != "/stop":
                    self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"405 nothing to post here\n")
                    return
                if not server.stop_requested:
                    server.stop_requested = True
                    server.on_stop()
                self._send(HTTPStatus.ACCEPTED, b'{"stopping": true}', "application/json")

            def do_HEAD(self) -> None:  # noqa: N802 - the http.server interface
                self.do_GET()

        return Handler
