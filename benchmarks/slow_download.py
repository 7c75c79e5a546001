"""A 200 MB derived file read at 1 MB/s: through nginx (X-Accel-Redirect), and straight from the app.

    .venv/bin/python benchmarks/slow_download.py                      # 200 MB at 1 MB/s (about 200 s)
    .venv/bin/python benchmarks/slow_download.py --mb 20 --rate-mb 4  # a quick look

Sets up the embedded application in a temporary folder (SQLite, jobs inline), measures a small
virtual capture, stores a ``--mb`` MB file as that measurement's built ``mesh.obj`` (pseudo-random
bytes standing in for a 1280x1024 OBJ, about 200 MB), then starts two gunicorn servers as
documented in issue 23 (3 sync workers, ``--timeout 120``) on the same database and media folder:

- ``nginx``: ``GCPS_ACCEL_REDIRECT=1`` behind ``deploy/nginx/gcps.conf`` (Debian's nginx, run by
  ``tests/nginx.py``): the app answers with X-Accel-Redirect and nginx sends the file;
- ``app``: ``GCPS_ACCEL_REDIRECT=0``, read straight from gunicorn (the app streams the file itself).

Both are read at the same time, each at ``--rate-mb`` MB/s (MB = 10^6 bytes), and the script prints,
per way: the HTTP status, bytes received, whether the SHA-256 matches, and the time taken.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import secrets
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import requests

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.nginx import nginx, paced_download, world_readable_dir  # noqa: E402
from tests.processes import free_port, stop_group  # noqa: E402


def prepare(folder: Path, media: Path, size: int) -> tuple[str, int, str]:
    """Migrate, make a user and a done measurement, store its ``mesh.obj``; (token, measurement id, sha256)."""
    import django

    django.setup()
    from django.core.files.base import ContentFile
    from django.core.files.storage import default_storage
    from django.core.management import call_command
    from rest_framework.test import APIClient

    from metrology.accounts.services import create_user_with_token
    from metrology.core.geometry.crossed_axes import Rig
    from metrology.measurements.derived import derived_name
    from metrology.measurements.models import Measurement
    from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip

    call_command("migrate", verbosity=0)
    _user, token = create_user_with_token(username="slow")
    api = APIClient()
    api.credentials(HTTP_AUTHORIZATION=f"Token {token}")
    rig = api.post("/api/rigs/", {**SMALL_RIG, "name": "slow"}, format="json").json()["id"]
    core = Rig.from_dict(SMALL_RIG)
    ids = []
    for role, heights in (("reference", 0.0), ("object", block_heights())):
        handle = io.BytesIO(stack_zip(render_images(core, heights, bit_depth=16)))
        handle.name = f"{role}.zip"
        ids.append(
            api.post(f"/api/rigs/{rig}/captures/", {"file": handle, "role": role}, format="multipart").json()["id"]
        )
    body = {"rig": rig, "reference": ids[0], "object": ids[1]}
    measurement_id = api.post("/api/measurements/", body, format="json").json()["id"]
    name = derived_name(Measurement.objects.get(pk=measurement_id), "mesh.obj")
    block = hashlib.sha256(b"gcps").digest() * (1 << 15)  # 1 MiB
    data = (block * (size // len(block) + 1))[:size]
    default_storage.save(name, ContentFile(data))
    for path in media.rglob("*"):  # nginx's unprivileged user reads them
        path.chmod(0o755 if path.is_dir() else 0o644)
    return token, measurement_id, hashlib.sha256(data).hexdigest()


def gunicorn(env: dict[str, str], log: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    command = [sys.executable, "-m", "gunicorn", "metrology.wsgi", "-b", f"127.0.0.1:{port}", "-w", "3"]
    with log.open("ab") as out:
        process = subprocess.Popen(
            [*command, "--timeout", "120"],
            cwd=ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            requests.get(f"http://127.0.0.1:{port}/api/schema/", timeout=30)
            return process, f"127.0.0.1:{port}"
        except requests.RequestException:
            time.sleep(0.2)
    raise RuntimeError(f"gunicorn did not start; see {log}")


def slow_read(url: str, token: str, rate: float, expected: str, out: dict[str, Any]) -> None:
    paced_download(url, {"Authorization": f"Token {token}"}, rate, out)
    headers = out.pop("headers", {})
    out["served_by_nginx"] = "X-Accel-Redirect" not in headers and headers.get("Server", "").startswith("nginx")
    out["sha256_ok"] = out.pop("sha256") == expected


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mb", type=float, default=200.0, help="file size, MB (10^6 bytes)")
    parser.add_argument("--rate-mb", type=float, default=1.0, help="client read rate, MB/s")
    parser.add_argument("--only", choices=("nginx", "app"), help="read one way only")
    args = parser.parse_args()
    folder = world_readable_dir("gcps-slow-")
    media, static = folder / "media", folder / "static"
    for path in (media, static):
        path.mkdir()
        path.chmod(0o755)
    env = {key: value for key, value in os.environ.items() if not key.startswith(("DJANGO_", "GCPS_"))}
    env.update(
        DJANGO_SETTINGS_MODULE="metrology.settings",
        GCPS_VAR_DIR=str(folder / "var"),
        MEDIA_ROOT=str(media),
        STATIC_ROOT=str(static),
        GCPS_EMBEDDED_JOBS="inline",
        SECRET_KEY=secrets.token_urlsafe(50),
        DEBUG="0",
        ALLOWED_HOSTS="127.0.0.1,localhost,testserver",
        SECURE_SSL_REDIRECT="0",
        GCPS_THROTTLE_USER="100000/minute",
    )
    os.environ.update(env)
    size = int(args.mb * 1e6)
    token, measurement_id, expected = prepare(folder, media, size)
    processes = []
    results: dict[str, dict[str, Any]] = {}
    try:
        via_nginx, upstream = gunicorn({**env, "GCPS_ACCEL_REDIRECT": "1"}, folder / "gunicorn-accel.log")
        direct, direct_address = gunicorn({**env, "GCPS_ACCEL_REDIRECT": "0"}, folder / "gunicorn-app.log")
        processes += [via_nginx, direct]
        with nginx(upstream, static, media) as proxy:
            path = f"/api/measurements/{measurement_id}/mesh.obj"
            ways = {"nginx": proxy.base_url + path, "app": f"http://{direct_address}{path}"}
            threads = []
            for way, url in ways.items():
                if args.only and way != args.only:
                    continue
                results[way] = {}
                threads.append(
                    threading.Thread(target=slow_read, args=(url, token, args.rate_mb * 1e6, expected, results[way]))
                )
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
    finally:
        for process in processes:
            stop_group(process)
        shutil.rmtree(folder, ignore_errors=True)
    print(json.dumps({"file_bytes": size, "rate_bytes_per_s": args.rate_mb * 1e6, "reads": results}, indent=2))


if __name__ == "__main__":
    main()
