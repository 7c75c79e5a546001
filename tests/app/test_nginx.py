"""Downloads behind the documented reverse proxy: nginx (deploy/nginx/gcps.conf) sends the files itself.

A real nginx (tests/nginx.py: Debian's package, unprivileged, free port) in front of the live
server, with ``GCPS_ACCEL_REDIRECT`` on: the app checks the user and answers an empty body with
``X-Accel-Redirect``; nginx serves the bytes from the media folder, with ranges, at any client speed.
The 200 MB read at 1 MB/s is ``benchmarks/slow_download.py``.
"""

from __future__ import annotations

import hashlib
import os
import shutil

import pytest
import requests
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage

from metrology.core.geometry.crossed_axes import Rig
from metrology.measurements.derived import derived_name
from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload
from tests.nginx import nginx, nginx_binary, paced_download, world_readable_dir

pytestmark = pytest.mark.django_db(transaction=True)


def _measure(api, rig) -> int:
    """The id of a measurement of a rendered block on ``rig`` (its jobs run inline)."""
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, block_heights(), bit_depth=16)), "object")
    started = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    return int(started.json()["id"])


@pytest.fixture
def served(api, rig, settings, live_server, user_and_token):
    """(nginx, measurement id, token) with the media folder readable by nginx's unprivileged user."""
    if nginx_binary() is None:  # skipped on a developer's machine without it; never in CI
        message = "nginx is not installed (scripts/services.sh installs Debian's nginx)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    media = world_readable_dir("gcps-media-")
    static = world_readable_dir("gcps-static-")
    (static / "hello.txt").write_text("static file")
    (static / "hello.txt").chmod(0o644)
    settings.MEDIA_ROOT = media
    settings.GCPS_ACCEL_REDIRECT = True
    measurement_id = _measure(api, rig)
    upstream = live_server.url.removeprefix("http://")
    try:
        with nginx(upstream, static, media) as proxy:
            yield proxy, measurement_id, user_and_token[1]
    finally:
        shutil.rmtree(media, ignore_errors=True)
        shutil.rmtree(static, ignore_errors=True)


def test_a_download_is_sent_by_nginx_with_ranges(served, live_server):
    proxy, measurement_id, token = served
    headers = {"Authorization": f"Token {token}"}
    path = f"/api/measurements/{measurement_id}/mesh.ply"
    # the app alone: an empty answer naming the file for the proxy (the job built it inline)
    direct = requests.get(live_server.url + path, headers=headers, timeout=30)
    assert direct.status_code == 200 and direct.content == b""
    name = derived_name(Measurement.objects.get(pk=measurement_id), "mesh.ply")
    assert direct.headers["X-Accel-Redirect"] == f"/protected/{name}"
    with default_storage.open(name, "rb") as handle:
        data = handle.read()

    through = requests.get(proxy.base_url + path, headers=headers, timeout=30)
    assert through.status_code == 200 and through.content == data and len(data) > 1000
    assert "X-Accel-Redirect" not in through.headers and through.headers["Server"].startswith("nginx")
    assert through.headers["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-mesh.ply"'
    assert through.headers["Accept-Ranges"] == "bytes" and int(through.headers["Content-Length"]) == len(data)
    part = requests.get(proxy.base_url + path, headers={**headers, "Range": "bytes=100-199"}, timeout=30)
    assert part.status_code == 206 and part.content == data[100:200]
    assert part.headers["Content-Range"] == f"bytes 100-199/{len(data)}"
    # nginx logged the bytes it sent itself (the app's answer had none)
    log = proxy.access_log.read_text()
    assert f'"GET {path} HTTP/1.1" 200 {len(data)}' in log and f'"GET {path} HTTP/1.1" 206 100' in log

    # the media folder is not reachable without the app: neither /protected/ nor /media/
    assert requests.get(f"{proxy.base_url}/protected/{name}", timeout=10).status_code == 404
    assert requests.get(f"{proxy.base_url}/media/{name}", timeout=10).status_code == 404
    # without a token the app refuses, and nginx sends nothing
    refused = requests.get(proxy.base_url + path, timeout=30)
    assert refused.status_code in (401, 403) and data[:20] not in refused.content
    # static files are nginx's own
    assert requests.get(f"{proxy.base_url}/static/hello.txt", timeout=10).text == "static file"


def test_a_slow_client_gets_the_whole_file(served):
    """8 MiB read at about 2 MiB/s through nginx arrives whole (sha256); the 200 MB at 1 MB/s is a benchmark."""
    proxy, measurement_id, token = served
    measurement = Measurement.objects.get(pk=measurement_id)
    name = derived_name(measurement, "mesh.obj")
    payload = hashlib.sha256(b"seed").digest() * (8 * 1024 * 1024 // 32)  # stands in for a built OBJ
    assert default_storage.save(name, ContentFile(payload)) == name
    read: dict = {}
    url = f"{proxy.base_url}/api/measurements/{measurement_id}/mesh.obj"
    paced_download(url, {"Authorization": f"Token {token}"}, 2 * 1024 * 1024, read)
    assert read["status"] == 200 and "error" not in read, read
    assert read["bytes"] == len(payload) and read["sha256"] == hashlib.sha256(payload).hexdigest()
    assert "X-Accel-Redirect" not in read["headers"]
    elapsed = read["seconds"]
    assert elapsed > 3.0, elapsed  # it really was read slowly


@pytest.fixture
def served_from_s3(api, rig, settings, live_server, user_and_token, s3):
    """(nginx, measurement id, token) with the storage in a bucket of the session's S3 server and
    nginx forwarding ``/protected-s3/`` to it, as docker-compose.yml runs nginx in front of MinIO."""
    if nginx_binary() is None:
        message = "nginx is not installed (scripts/services.sh installs Debian's nginx)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    bucket = s3.bucket()
    settings.STORAGES = s3.storages(bucket)
    settings.GCPS_S3_BUCKET = bucket
    settings.GCPS_ACCEL_REDIRECT = True
    static = world_readable_dir("gcps-static-")
    media = world_readable_dir("gcps-media-")
    measurement_id = _measure(api, rig)
    upstream = live_server.url.removeprefix("http://")
    try:
        with nginx(upstream, static, media, s3.endpoint_url) as proxy:
            yield proxy, measurement_id, user_and_token[1], bucket
    finally:
        shutil.rmtree(media, ignore_errors=True)
        shutil.rmtree(static, ignore_errors=True)


def test_a_download_from_s3_is_streamed_by_nginx_with_ranges(served_from_s3, live_server, s3):
    """With S3 storage and GCPS_ACCEL_REDIRECT the bucket need not be reachable by the client: the app
    names a presigned path-style request, nginx fetches it from the S3 endpoint and streams it."""
    proxy, measurement_id, token, bucket = served_from_s3
    headers = {"Authorization": f"Token {token}"}
    path = f"/api/measurements/{measurement_id}/mesh.ply"
    direct = requests.get(live_server.url + path, headers=headers, timeout=30, allow_redirects=False)
    name = derived_name(Measurement.objects.get(pk=measurement_id), "mesh.ply")
    accel = direct.headers["X-Accel-Redirect"]
    assert direct.status_code == 200 and direct.content == b""
    assert accel.startswith(f"/protected-s3/{bucket}/{name}?") and "X-Amz-Signature=" in accel
    with default_storage.open(name, "rb") as handle:
        data = handle.read()
    assert len(data) > 1000 and name in s3.objects(bucket)

    through = requests.get(proxy.base_url + path, headers=headers, timeout=30, allow_redirects=False)
    assert through.status_code == 200 and through.content == data
    assert through.headers["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-mesh.ply"'
    assert "X-Accel-Redirect" not in through.headers and "x-amz-request-id" not in through.headers
    part = requests.get(proxy.base_url + path, headers={**headers, "Range": "bytes=100-199"}, timeout=30)
    assert part.status_code == 206 and part.content == data[100:200]
    assert part.headers["Content-Range"] == f"bytes 100-199/{len(data)}"
    # the internal location is not reachable from outside, and without a token nothing is sent
    assert requests.get(proxy.base_url + accel, timeout=10).status_code == 404
    refused = requests.get(proxy.base_url + path, timeout=30)
    assert refused.status_code in (401, 403) and data[:20] not in refused.content
