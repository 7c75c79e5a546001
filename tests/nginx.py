"""A real nginx running ``deploy/nginx/gcps.conf`` for the tests and benchmarks, unprivileged, on a free port.

The documented server block is used as written, with five values put in: the listening address
(``listen 80;``), the web server (``server 127.0.0.1:8000;``), the S3 endpoint
(``http://127.0.0.1:9000/``) and the two folders (``/var/lib/gcps/static/``,
``/var/lib/gcps/media/``); each must appear exactly once, so a change of
the file that this does not follow fails loudly. nginx runs from the Debian package (``nginx``,
installed by ``scripts/services.sh``) under its own prefix and error log, as the user ``nobody`` when
started by root, so the folders it serves must be readable by everyone (:func:`world_readable_dir`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import requests

from tests.processes import free_port, stop_group

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "deploy" / "nginx" / "gcps.conf"


def nginx_binary() -> str | None:
    return shutil.which("nginx") or next((p for p in ("/usr/sbin/nginx",) if os.path.exists(p)), None)


def world_readable_dir(prefix: str) -> Path:
    """A new folder under the system's temporary folder that ``nobody`` can read."""
    path = Path(tempfile.mkdtemp(prefix=prefix, dir="/tmp" if os.path.isdir("/tmp") else None))
    path.chmod(0o755)
    return path


def render_config(
    port: int,
    upstream: str,
    static_root: Path,
    media_root: Path,
    s3_endpoint: str = "http://127.0.0.1:9000",
    config: Path = CONFIG,
) -> str:
    """``deploy/nginx/gcps.conf`` listening on 127.0.0.1:``port``, proxying to ``upstream`` (host:port)
    and to the S3 endpoint ``s3_endpoint`` (``http://host:port``). ``config``: another checkout's
    ``deploy/nginx/gcps.conf`` (benchmarks that compare checkouts); default this one's."""
    text = config.read_text()
    for old, new in (
        ("listen 80;", f"listen 127.0.0.1:{port};"),
        ("server 127.0.0.1:8000;", f"server {upstream};"),
        ("http://127.0.0.1:9000/;", f"{s3_endpoint.rstrip('/')}/;"),
        ("/var/lib/gcps/static/", f"{static_root}/"),
        ("/var/lib/gcps/media/", f"{media_root}/"),
    ):
        assert text.count(old) == 1, f"{config} should hold {old!r} once"
        text = text.replace(old, new)
    return text


class Nginx:
    """nginx serving ``deploy/nginx/gcps.conf`` on ``base_url``; its access log in ``access_log``."""

    def __init__(
        self,
        upstream: str,
        static_root: Path,
        media_root: Path,
        s3_endpoint: str = "http://127.0.0.1:9000",
        config: Path = CONFIG,
    ) -> None:
        binary = nginx_binary()
        if binary is None:
            raise RuntimeError("nginx is not installed (scripts/services.sh installs Debian's nginx)")
        self.prefix = world_readable_dir("gcps-nginx-")
        self.port = free_port()
        self.base_url = f"http://127.0.0.1:{self.port}"
        self.access_log = self.prefix / "access.log"
        self.error_log = self.prefix / "error.log"
        site = self.prefix / "gcps.conf"
        site.write_text(render_config(self.port, upstream, static_root, media_root, s3_endpoint, config))
        mime = "/etc/nginx/mime.types"
        temp = "".join(
            f"    {kind}_temp_path {self.prefix}/{kind};\n"
            for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
        )
        main = self.prefix / "nginx.conf"
        main.write_text(
            "daemon off;\nworker_processes 1;\n"
            f"pid {self.prefix}/nginx.pid;\nerror_log {self.error_log} info;\n"
            "events { worker_connections 256; }\n"
            "http {\n"
            + (f"    include {mime};\n" if os.path.exists(mime) else "")
            + "    default_type application/octet-stream;\n"
            f"    access_log {self.access_log};\n{temp}"
            f"    include {site};\n}}\n"
        )
        for path in self.prefix.iterdir():
            path.chmod(0o644)
        command = [binary, "-p", str(self.prefix), "-e", str(self.error_log), "-c", str(main)]
        if os.geteuid() == 0:  # never run the test's nginx as root
            self.access_log.touch()
            self.error_log.touch()
            shutil.chown(self.prefix, "nobody")
            for path in self.prefix.iterdir():
                shutil.chown(path, "nobody")
            command = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups", *command]
        with open(self.prefix / "stderr.log", "wb") as stderr:  # the child keeps its own descriptor
            self.process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True)
        deadline = time.monotonic() + 30
        while True:
            try:
                requests.get(f"{self.base_url}/media/", timeout=2)
                return
            except requests.ConnectionError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        "nginx did not start: " + (self.prefix / "stderr.log").read_text(errors="replace")
                    ) from None
                time.sleep(0.05)

    def stop(self) -> None:
        stop_group(self.process)
        shutil.rmtree(self.prefix, ignore_errors=True)


@contextlib.contextmanager
def nginx(
    upstream: str, static_root: Path, media_root: Path, s3_endpoint: str = "http://127.0.0.1:9000"
) -> Iterator[Nginx]:
    server = Nginx(upstream, static_root, media_root, s3_endpoint)
    try:
        yield server
    finally:
        server.stop()


def paced_download(url: str, headers: dict[str, str], rate: float, out: dict[str, Any]) -> None:
    """GET ``url`` reading at most ``rate`` bytes per second, as a slow client; fills ``out`` with
    ``status``, ``headers``, ``bytes``, ``sha256`` (hex) and ``seconds`` (and ``error`` if it broke)."""
    digest = hashlib.sha256()
    received = 0
    start = time.monotonic()
    try:
        with requests.get(url, headers=headers, stream=True, timeout=600) as response:
            out["status"] = response.status_code
            out["headers"] = dict(response.headers)
            for chunk in response.iter_content(64 * 1024):
                digest.update(chunk)
                received += len(chunk)
                ahead = received / rate - (time.monotonic() - start)
                if ahead > 0:
                    time.sleep(ahead)
    except requests.RequestException as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"[:200]
    out["bytes"] = received
    out["sha256"] = digest.hexdigest()
    out["seconds"] = round(time.monotonic() - start, 1)
