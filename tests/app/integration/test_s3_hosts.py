"""Several hosts: processes that share only PostgreSQL, Redis and an S3-protocol server (issue 23 item 3).

Each process below has its own MEDIA_ROOT, temporary folder (TMPDIR) and local cache folder, as
processes on different machines would; the results live in the bucket (moto_server, tests/s3.py).
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import requests

from tests.app.integration.harness import Stack, migrated_stack, template_user_token
from tests.app.integration.helpers import RIG, download, finished, simulated_zip, upload, url, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def host_env(root: Path, name: str) -> dict[str, str]:
    """A folder of ``root`` standing for host ``name``'s own disk: media root, temporary files, local cache."""
    host = root / name
    for folder in ("media", "tmp", "cache"):
        (host / folder).mkdir(parents=True)
    return {"MEDIA_ROOT": str(host / "media"), "TMPDIR": str(host / "tmp"), "GCPS_LOCAL_CACHE_DIR": str(host / "cache")}


def local_files(root: Path, name: str) -> list[Path]:
    return [p for p in (root / name / "media").rglob("*") if p.is_file()]


@pytest.fixture
def s3_stack(tmp_path, s3) -> Iterator[tuple[Stack, str]]:
    bucket = s3.bucket()
    web = host_env(tmp_path, "web")
    with migrated_stack(tmp_path, Path(web["MEDIA_ROOT"]), {**s3.env(bucket), **web}) as stack:
        stack.start_web()
        yield stack, bucket


@pytest.fixture
def http(s3_stack) -> requests.Session:
    stack, _bucket = s3_stack
    key = template_user_token()
    session = requests.Session()
    session.headers["Authorization"] = f"Token {key}"
    session.base = stack.base_url  # type: ignore[attr-defined]
    return session


def test_two_worker_hosts_drain_30_jobs_through_s3(s3_stack, http, s3, tmp_path):
    stack, bucket = s3_stack
    stack.start_worker("host-a", host_env(tmp_path, "host-a"))
    stack.start_worker("host-b", host_env(tmp_path, "host-b"))
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    reference = upload(http, rig_id, simulated_zip("reference")[0], "reference")
    object_zip, truth = simulated_zip("block", top_mm=30.0, size_x_mm=200.0, size_y_mm=150.0)
    obj = upload(http, rig_id, object_zip, "object")
    ids = []
    for _ in range(30):
        started = http.post(
            url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj}
        )
        assert started.status_code == 202, started.text
        ids.append(started.json()["id"])
    bodies = [wait_for(http, f"/api/measurements/{i}/", finished, timeout=600) for i in ids]
    assert [b["status"] for b in bodies] == ["done"] * 30, [b["error"] for b in bodies if b["status"] != "done"]
    jobs = [http.get(url(http, f"/api/jobs/{b['job']}/")).json() for b in bodies]
    assert all(job["attempts"] == 1 for job in jobs), [job["attempts"] for job in jobs]  # none lost, none redone

    # both hosts worked; neither (nor the web host) wrote a result to its own disk
    ran = {
        name: len(
            re.findall(rb"Task workers\.tasks\.run_job\[[^\]]+\] succeeded", (stack.logs / f"{name}.log").read_bytes())
        )
        for name in ("host-a", "host-b")
    }
    assert sum(ran.values()) >= 30 and all(count > 0 for count in ran.values()), ran
    for host in ("web", "host-a", "host-b"):
        assert local_files(tmp_path, host) == [], host
    keys = s3.objects(bucket)
    assert sum(key.endswith("/height.npy") for key in keys) == 30

    # every result downloads through the API (a redirect to a presigned URL of the bucket)
    both = None
    for measurement_id in ids:
        response = http.get(url(http, f"/api/measurements/{measurement_id}/height.npy"))
        assert response.status_code == 200 and response.history[0].status_code == 302
        z = np.load(io.BytesIO(response.content))
        both = np.isfinite(z) & np.isfinite(truth)
        assert np.median(np.abs(z[both] - truth[both])) < 0.005
    # a derived mesh is built by a worker host into the bucket, and served from it with ranges
    mesh = download(http, f"/api/measurements/{ids[0]}/mesh.ply")
    assert mesh.status_code == 200 and mesh.content.startswith(b"ply\n") and mesh.history[0].status_code == 302
    assert any(key.startswith("derived/") for key in s3.objects(bucket))
    part = requests.get(mesh.url, headers={"Range": "bytes=0-2"}, timeout=10)
    assert part.status_code == 206 and part.content == b"ply"
    for host in ("web", "host-a", "host-b"):
        assert local_files(tmp_path, host) == [], host
