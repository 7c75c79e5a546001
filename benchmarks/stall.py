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

It reports that user's latency p50, p95 and max, the number of his requests, the mesh downloads
completed (and their bytes), and the long-polls answered. Figures are wall-clock on whatever else
the machine is doing.

    .venv/bin/python benchmarks/stall.py --checkout /tmp/gcps-b2c99ec     # git archive b2c99ec | tar -x -C ...
    .venv/bin/python benchmarks/stall.py --size 1280x1024 --seconds 120 --checkout /tmp/gcps-b2c99ec
"""

from __future__ import annotations

import argparse
import json
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


class StallStack(Stack):
    """load.py's stack with the documented web server of the checkout, 3 workers."""

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
        while time.monotonic() < deadline:
            try:
                requests.get(f"{self.base}/login/", timeout=10)
                return
            except requests.RequestException:
                time.sleep(0.2)
        raise RuntimeError(f"web server did not start:\n{(self.logs / 'web.log').read_text(errors='replace')[-2000:]}")


def run(checkout: Path, args: argparse.Namespace, inputs: tuple) -> dict[str, Any]:
    reference_zip, object_zips, values = inputs
    with tempfile.TemporaryDirectory(prefix="gcps-stall-") as tmp:
        stack = StallStack(checkout, Path(tmp))
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
                owner.get(f"/api/measurements/{mid}/mesh.obj").raise_for_status()
            return measure(stack, owner, other, rig, seq, mid, args)
        finally:
            stack.stop()


def measure(
    stack: Stack, owner: Client, other: requests.Session, rig: int, seq: int, mid: int, args: argparse.Namespace
) -> dict[str, Any]:
    stop = threading.Event()
    counts = {"long_polls": 0, "downloads": 0, "download_bytes": 0, "download_errors": 0}
    lock = threading.Lock()
    headers = dict(owner.session.headers)

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
                try:
                    with client.get(f"{stack.base}/api/measurements/{mid}/mesh.obj", stream=True, timeout=300) as r:
                        for chunk in r.iter_content(1 << 20):
                            size += len(chunk)
                    ok = r.status_code == 200
                except requests.RequestException:
                    ok = False
                with lock:
                    counts["downloads" if ok else "download_errors"] += 1
                    counts["download_bytes"] += size

    threads = [threading.Thread(target=long_poll, daemon=True) for _ in range(args.long_polls)]
    threads += [threading.Thread(target=download, daemon=True) for _ in range(args.downloads)]
    for thread in threads:
        thread.start()
    time.sleep(3.0)  # the long-polls wait, the meshes are being built
    latencies: list[float] = []
    failures = 0
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        start = time.perf_counter()
        try:
            ok = other.get(f"{stack.base}/api/rigs/", timeout=60).status_code == 200
        except requests.RequestException:
            ok = False
        latencies.append(time.perf_counter() - start)
        failures += not ok
        time.sleep(0.25)
    stop.set()
    return {
        "server": stack.server,
        "rigs_requests": len(latencies),
        "rigs_failures": failures,
        "rigs_p50_s": statistics.median(latencies),
        "rigs_p95_s": percentile(latencies, 95),
        "rigs_max_s": max(latencies),
        **counts,
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
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    inputs = stacks(width, height)
    results = {}
    for checkout in [ROOT, *args.checkout]:
        print(f"--- {checkout}", flush=True)
        result = run(checkout.resolve(), args, inputs)
        results[str(checkout)] = result
        print(json.dumps(result, indent=1), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
