"""Stall benchmark: does a handful of long requests stall the site? (issue 23, Must show 1)

For each checkout (this one; ``--checkout PATH`` for another, e.g. the commit before the change,
measured in the same run) it starts a fresh PostgreSQL database, its own redis-server, one Celery
worker and the documented web server with 3 workers: for a checkout with ``metrology/streaming.py``
(the ASGI one) ``gunicorn metrology.asgi:application -k uvicorn_worker.UvicornWorker -w 3``, else
``gunicorn metrology.wsgi -w 3 --timeout 120`` (sync workers, as documented before). It stores one measurement
(realistic 8-bit stacks of the virtual paper rig, ``--size``), then for ``--seconds``:

- ``--long-polls`` clients (3) each loop on the projector long-poll of the owner's rig
  (``GET /api/rigs/{id}/projector/?after=SEQ&wait=25``, nothing changes: each waits 25 s);
- ``--downloads`` clients (6) each loop on downloading ``mesh.obj`` of the measurement, as the
  meshes are served at that commit, with the derived-file cache off (``GCPS_MESH_CACHE_BYTES=0``)
  so that every download builds its mesh as a first download does (``--cached-meshes``: the cache
  kept and filled first, so that the downloads read a stored file);
- another user times ``GET /api/rigs/`` every 0.25 s (timeout 60 s).

``--nginx``: the documented topology (docs/operations.md, "Topology"). In front of the web server
of each checkout that has ``deploy/nginx/gcps.conf``, the real nginx renders that checkout's file
(``tests/nginx.py``: Debian's nginx, unprivileged, on a free port), the web server runs with
``GCPS_ACCEL_REDIRECT=1`` and ``GCPS_NUM_PROXIES=1``, and the stack's folder is readable by nginx's
user. Every client (the owner's setup, the long-polls, the downloads, the other user) then goes
through nginx. A checkout without that file (b2c99ec) runs as it was documented: its web server,
direct.

The download clients follow the derived-file protocol of docs/storage.md: a ``202`` (the mesh is
being built by a job) is followed by waiting ``Retry-After`` seconds and polling its ``Location``
(the job) until the job has ended, then the download is asked for again; a ``200`` is read to the
end. A download counts as completed when its bytes equal its ``Content-Length`` (or, without one,
the size of the first completed download); the first completed download is hashed (SHA-256) and
compared with the stored file (``MEDIA_ROOT/derived/``), when the checkout stored one, and, with
several checkouts, with the first download of the others (the same mesh bytes).

It reports that user's latency p50, p95 and max, the number of his requests, the mesh downloads
completed (and their bytes), the long-polls answered, and the 1-minute load average while timed.
Figures are wall-clock on whatever else the machine is doing.

    .venv/bin/python benchmarks/stall.py --checkout /tmp/gcps-b2c99ec     # git archive b2c99ec | tar -x -C ...
    .venv/bin/python benchmarks/stall.py --size 1280x1024 --seconds 120 --checkout /tmp/gcps-b2c99ec
    .venv/bin/python benchmarks/stall.py --nginx --size 1280x1024 --seconds 90 --checkout /tmp/gcps-b2c99ec
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import requests

sys.path.insert(0, str(Path(__file__).resolve().parent))
from load import ROOT, Client, Stack, free_port, percentile, stacks

sys.path.insert(0, str(ROOT))
from tests.nginx import Nginx, world_readable_dir


class StallStack(Stack):
    """load.py's stack with the documented web server of the checkout, 3 workers; with ``proxied``,
    behind the checkout's ``deploy/nginx/gcps.conf`` (``GCPS_ACCEL_REDIRECT=1``)."""

    def __init__(self, checkout: Path, workdir: Path, proxied: bool = False) -> None:
        super().__init__(checkout, workdir)
        self.nginx_config = checkout / "deploy" / "nginx" / "gcps.conf"
        self.proxied = proxied and self.nginx_config.exists()
        self.nginx: Nginx | None = None
        if self.proxied:
            self.env["GCPS_ACCEL_REDIRECT"] = "1"
            self.env["GCPS_NUM_PROXIES"] = "1"

    def stop(self) -> None:
        if self.nginx is not None:
            self.nginx.stop()
        super().stop()

    def start_web(self) -> None:
        port = free_port()
        asgi = (self.checkout / "metrology" / "streaming.py").exists()
        if asgi:
            args = [sys.executable, "-m", "gunicorn", "metrology.asgi:application"]
            args += ["-k", "uvicorn_worker.UvicornWorker"]
            self.server = "gunicorn metrology.asgi -k uvicorn_worker.UvicornWorker -w 3"
        else:
            args = [sys.executable, "-m", "gunicorn", "metrology.wsgi", "--timeout", "120"]  # as its README said
            self.server = "gunicorn metrology.wsgi -w 3 --timeout 120 (sync)"
        self._spawn("web", [*args, "-w", "3", "-b", f"127.0.0.1:{port}", "--no-control-socket"])
        self.base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 90
        while True:
            try:
                requests.get(f"{self.base}/login/", timeout=10)
                break
            except requests.RequestException:
                if time.monotonic() > deadline:
                    log = (self.logs / "web.log").read_text(errors="replace")[-2000:]
                    raise RuntimeError(f"web server did not start:\n{log}") from None
                time.sleep(0.2)
        if self.proxied:  # everything goes through nginx from here on
            static = self.workdir / "static"
            static.mkdir(exist_ok=True)
            self.nginx = Nginx(f"127.0.0.1:{port}", static, self.media, config=self.nginx_config)
            self.base = self.nginx.base_url
            self.server += " behind nginx (deploy/nginx/gcps.conf, GCPS_ACCEL_REDIRECT=1)"
        else:
            self.server += ", direct"


def stored_mesh(media: Path) -> Path | None:
    """The mesh.obj the checkout stored as a derived file, if any (the largest .obj under derived/)."""
    found = sorted((p for p in (media / "derived").rglob("*.obj") if p.is_file()), key=lambda p: p.stat().st_size)
    return found[-1] if found else None


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def fetch_derived(
    client: requests.Session, base: str, path: str, stop: threading.Event, counts: dict[str, Any], lock: threading.Lock
) -> requests.Response | None:
    """GET ``base + path`` (streamed) following the derived-file protocol: on 202, wait Retry-After and poll
    the job at Location until it has ended, then ask again. The open response (any status but 202), or
    None when ``stop`` is set first."""
    while not stop.is_set():
        response = client.get(base + path, stream=True, timeout=300)
        if response.status_code != 202:
            return response
        with lock:
            counts["answers_202"] += 1
        response.close()
        location = response.headers["Location"]
        retry = float(response.headers.get("Retry-After", "2"))
        while not stop.wait(retry):
            job = client.get(base + location if location.startswith("/") else location, timeout=60)
            if job.status_code != 200 or job.json().get("status") in ("done", "failed"):
                break
    return None


def run(checkout: Path, args: argparse.Namespace, inputs: tuple) -> dict[str, Any]:
    reference_zip, object_zips, values = inputs
    # behind nginx its unprivileged user reads the media folder: the stack's folder is world-readable
    tmp = world_readable_dir("gcps-stall-") if args.nginx else Path(tempfile.mkdtemp(prefix="gcps-stall-"))
    try:
        stack = StallStack(checkout, tmp, proxied=args.nginx)
        if not args.cached_meshes:
            stack.env["GCPS_MESH_CACHE_BYTES"] = "0"
        stack.env["GCPS_THROTTLE_USER"] = "100000/minute"
        try:
            stack.start(workers=1)
            owner = Client(stack)
            rig, reference, objects = owner.setup(values, reference_zip, object_zips[:1])
            pair = {"rig": rig, "reference": reference, "object": objects[0]}
            measurement = owner.post("/api/measurements/", json=pair)
            measurement.raise_for_status()
            mid = measurement.json()["id"]
            deadline = time.monotonic() + 900
            while owner.get(f"/api/measurements/{mid}/").json()["status"] not in ("done", "failed"):
                if time.monotonic() > deadline:
                    raise RuntimeError("the measurement did not finish in 900 s")
                time.sleep(1)
            other_token = stack.manage("createuser", "other").strip().split()[-1]
            other = requests.Session()
            other.headers["Authorization"] = f"Token {other_token}"
            other.post(f"{stack.base}/api/rigs/", json={**values, "name": "other's"}, timeout=60).raise_for_status()
            seq = owner.get(f"/api/rigs/{rig}/projector/").json()["seq"]
            if args.cached_meshes:  # built and cached once: the downloads read the stored file
                counts = {"answers_202": 0}
                first = fetch_derived(
                    owner.session,
                    stack.base,
                    f"/api/measurements/{mid}/mesh.obj",
                    threading.Event(),
                    counts,
                    threading.Lock(),
                )
                assert first is not None
                with first:
                    first.raise_for_status()
                    for _ in first.iter_content(1 << 20):
                        pass
            return measure(stack, owner, other, rig, seq, mid, args)
        finally:
            stack.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def measure(
    stack: Stack, owner: Client, other: requests.Session, rig: int, seq: int, mid: int, args: argparse.Namespace
) -> dict[str, Any]:
    stop = threading.Event()
    counts: dict[str, Any] = {
        "long_polls": 0,
        "downloads": 0,
        "download_bytes": 0,
        "downloads_incomplete": 0,
        "download_errors": 0,
        "answers_202": 0,
        "served_by_nginx": 0,
    }
    sizes: set[int] = set()
    hashed: dict[str, Any] = {}  # the first completed download: its sha256
    lock = threading.Lock()
    headers = dict(owner.session.headers)
    began = time.monotonic()

    def long_poll() -> None:
        with requests.Session() as client:
            client.headers.update(headers)
            while not stop.is_set():
                try:
                    client.get(f"{stack.base}/api/rigs/{rig}/projector/?after={seq}&wait=25", timeout=60)
                    with lock:
                        counts["long_polls"] += 1
                except requests.RequestException:
                    time.sleep(0.5)

    def download() -> None:
        with requests.Session() as client:
            client.headers.update(headers)
            while not stop.is_set():
                size = 0
                digest = None
                with lock:
                    if not hashed:  # this client hashes the next download (the first to complete is kept)
                        hashed["claimed"] = True
                        digest = hashlib.sha256()
                try:
                    r = fetch_derived(client, stack.base, f"/api/measurements/{mid}/mesh.obj", stop, counts, lock)
                    if r is None:
                        break
                    with r:
                        for chunk in r.iter_content(1 << 20):
                            size += len(chunk)
                            if digest is not None:
                                digest.update(chunk)
                    status = r.status_code
                    expected = int(r.headers.get("Content-Length", "-1"))
                    nginx = r.headers.get("Server", "").startswith("nginx") and "X-Accel-Redirect" not in r.headers
                except requests.RequestException:
                    status, expected, nginx = 0, -1, False
                with lock:
                    counts["download_bytes"] += size
                    if status != 200:
                        counts["download_errors"] += 1
                    elif size != expected and (expected >= 0 or (sizes and size not in sizes)):
                        counts["downloads_incomplete"] += 1
                    else:
                        counts["downloads"] += 1
                        counts["served_by_nginx"] += nginx
                        sizes.add(size)
                        counts.setdefault("first_download_done_s", round(time.monotonic() - began, 1))
                        if digest is not None and "sha256" not in hashed:
                            hashed.update(sha256=digest.hexdigest(), bytes=size)
                    if digest is not None and "sha256" not in hashed:
                        hashed.pop("claimed", None)  # not completed: the next download is hashed

    threads = [threading.Thread(target=long_poll, daemon=True) for _ in range(args.long_polls)]
    threads += [threading.Thread(target=download, daemon=True) for _ in range(args.downloads)]
    for thread in threads:
        thread.start()
    time.sleep(3.0)  # the long-polls wait, the meshes are being built
    latencies: list[float] = []
    loads: list[float] = []
    failures = 0
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        loads.append(os.getloadavg()[0])
        start = time.perf_counter()
        try:
            ok = other.get(f"{stack.base}/api/rigs/", timeout=60).status_code == 200
        except requests.RequestException:
            ok = False
        latencies.append(time.perf_counter() - start)
        failures += not ok
        time.sleep(0.25)
    stop.set()
    with lock:
        counts = dict(counts)
        download_sizes = sorted(sizes)
        first = dict(hashed)
    stored = stored_mesh(stack.media)
    integrity: dict[str, Any] = {
        "download_sizes": download_sizes,
        "first_download_sha256": first.get("sha256"),
        "stored_mesh_bytes": None,
        "sha256_equal": None,
    }
    if stored is not None:
        integrity["stored_mesh_bytes"] = stored.stat().st_size
        if "sha256" in first:
            integrity["sha256_equal"] = first["sha256"] == sha256_file(stored)
    return {
        "server": stack.server,
        "rigs_requests": len(latencies),
        "rigs_failures": failures,
        "rigs_p50_s": statistics.median(latencies),
        "rigs_p95_s": percentile(latencies, 95),
        "rigs_max_s": max(latencies),
        **counts,
        **integrity,
        "load_average_1min_mean": round(statistics.mean(loads), 2),
        "load_average_1min_max": round(max(loads), 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkout", type=Path, action="append", default=[], help="another checkout, same run")
    parser.add_argument("--size", default="640x480", help="camera size WIDTHxHEIGHT (default 640x480)")
    parser.add_argument("--seconds", type=float, default=60.0, help="how long the other user is timed")
    parser.add_argument("--long-polls", type=int, default=3)
    parser.add_argument("--downloads", type=int, default=6)
    parser.add_argument(
        "--cached-meshes", action="store_true", help="keep the derived-file cache: the downloads read a stored mesh"
    )
    parser.add_argument(
        "--nginx",
        action="store_true",
        help="the documented topology: nginx (deploy/nginx/gcps.conf) in front, X-Accel-Redirect downloads",
    )
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    inputs = stacks(width, height)
    results = {}
    for checkout in [ROOT, *args.checkout]:
        print(f"--- {checkout}", flush=True)
        result = run(checkout.resolve(), args, inputs)
        results[str(checkout)] = result
        print(json.dumps(result, indent=1), flush=True)
    digests = {r["first_download_sha256"] for r in results.values()}
    if len(results) > 1 and None not in digests:  # the same mesh bytes from every checkout?
        print(f"first downloads of every checkout have the same sha256: {len(digests) == 1}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
