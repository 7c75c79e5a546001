"""The projector page without the application: a small local HTTP server for ``gcps capture --projector page``.

It serves the same page script as the application (``static/acquisition/projector.js``) and the
three calls it makes (state long-poll, shown confirmation, frame PNGs), on 127.0.0.1 by default.
Open ``http://HOST:PORT/`` full screen on the projector's screen.
"""

from __future__ import annotations

import html
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlparse

import cv2

from metrology.acquisition.agent.cameras import Shown
from metrology.acquisition.agent.patterns import ProjectedCodec
from metrology.acquisition.agent.sequencer import AcquisitionError

STATIC = Path(__file__).resolve().parents[1] / "static" / "acquisition"

PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>GCPS projector (local)</title>
<link rel="stylesheet" href="/static/projector.css"></head>
<body><main id="projector" data-rig="local" data-rig-name="{name}" data-state-url="/state"
 data-shown-url="/shown" data-frame-url="/frames/{{acquisition}}/{{frame}}.png" data-csrf="-" data-shown-seq="0">
<canvas id="projector-canvas" width="1" height="1"></canvas></main>
<script src="/static/projector.js"></script></body></html>
"""


class LocalPageProjector:
    """Serves the projector page and shows patterns on it (``show`` blocks until the page confirms)."""

    def __init__(self, codec: ProjectedCodec, host: str = "127.0.0.1", port: int = 8765, timeout_s: float = 60.0):
        self.codec = codec
        self.timeout_s = timeout_s
        self.cond = threading.Condition()
        self.state: dict[str, Any] = {"seq": 0, "kind": "test", "frame": -1, "acquisition": 0, "shown_seq": 0}
        projector = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, format: str, *args: Any) -> None:  # quiet
                return

            def _send(self, status: int, body: bytes, ctype: str) -> None:
                self.send_response(status)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                url = urlparse(self.path)
                if url.path == "/":
                    self._send(200, PAGE.format(name=html.escape(codec.spec)).encode(), "text/html; charset=utf-8")
                elif url.path in ("/static/projector.js", "/static/projector.css"):
                    ctype = "text/javascript" if url.path.endswith(".js") else "text/css"
                    self._send(200, (STATIC / url.path.rsplit("/", 1)[1]).read_bytes(), ctype)
                elif url.path == "/state":
                    query = parse_qs(url.query)
                    after = int(query.get("after", ["0"])[0])
                    wait = min(20.0, float(query.get("wait", ["0"])[0]))
                    with projector.cond:
                        projector.cond.wait_for(lambda: projector.state["seq"] > after, timeout=wait)
                        body = json.dumps(projector.state).encode()
                    self._send(200, body, "application/json")
                elif url.path.startswith("/frames/"):
                    try:
                        frame = int(url.path.rsplit("/", 1)[1].removesuffix(".png"))
                        image = codec.images()[frame]
                    except (ValueError, IndexError):
                        self._send(404, b"no such frame", "text/plain")
                        return
                    _ok, data = cv2.imencode(".png", image)
                    self._send(200, data.tobytes(), "image/png")
                else:
                    self._send(404, b"not found", "text/plain")

            def do_POST(self) -> None:
                if urlparse(self.path).path != "/shown":
                    self._send(404, b"not found", "text/plain")
                    return
                length = int(self.headers.get("Content-Length") or 0)
                data = json.loads(self.rfile.read(length) or b"{}")
                with projector.cond:
                    if int(data.get("seq", -1)) == projector.state["seq"]:
                        projector.state.update(
                            shown_seq=int(data["seq"]), shown_kind=data.get("kind"), shown_frame=data.get("frame")
                        )
                        projector.cond.notify_all()
                self._send(200, b"{}", "application/json")

        self.server = ThreadingHTTPServer((host, port), Handler)
        self.server.daemon_threads = True
        self.url = f"http://{host}:{self.server.server_address[1]}/"
        self.thread = threading.Thread(target=self.server.serve_forever, name="gcps-projector-page", daemon=True)
        self.thread.start()

    def show(self, kind: str, frame: int = -1) -> Shown:
        with self.cond:
            seq = self.state["seq"] + 1
            self.state.update(seq=seq, kind=kind, frame=frame if kind == "frame" else -1)
            self.cond.notify_all()
            deadline = time.monotonic() + self.timeout_s
            while self.state["shown_seq"] < seq:
                if not self.cond.wait(timeout=max(0.0, deadline - time.monotonic())):
                    raise AcquisitionError(
                        f"the projector page did not confirm {kind} within {self.timeout_s:.0f} s: open {self.url} "
                        "full screen on the projector"
                    )
            return Shown(kind=str(self.state["shown_kind"]), frame=int(self.state["shown_frame"]), seq=seq)

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
