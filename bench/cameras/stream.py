"""Frames served as an MJPEG stream over HTTP on the loopback interface, as an IP camera serves
them: what the real camera path (``cv2.VideoCapture`` on a URL) opens when a rig is rehearsed
against emulated cameras. Only 127.0.0.1 is ever bound.
"""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Callable

import numpy as np

__all__ = ["MjpegServer"]

_BOUNDARY = "hilbenchframe"


class MjpegServer:
    """``with MjpegServer(frame) as s: cv2.VideoCapture(s.url)``: each part of the stream is
    ``frame()`` (a BGR image) encoded as JPEG, for as long as the client reads."""

    def __init__(self, frame: Callable[[], np.ndarray], quality: int = 95, max_frames: int = 10_000) -> None:
        import cv2  # heavy: OpenCV, only when frames are served

        def encode() -> bytes:
            ok, buf = cv2.imencode(".jpg", frame(), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
            return buf.tobytes()

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                self.send_response(200)
                self.send_header("Content-Type", f"multipart/x-mixed-replace;boundary={_BOUNDARY}")
                self.end_headers()
                try:
                    for _ in range(max_frames):
                        data = encode()
                        self.wfile.write(f"--{_BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                                         f"Content-Length: {len(data)}\r\n\r\n".encode() + data + b"\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client has what it wanted

            def log_message(self, *args) -> None:  # quiet: no line per request on stderr
                pass

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self._server.server_address[1]}/stream.mjpg"

    def __enter__(self) -> "MjpegServer":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()
