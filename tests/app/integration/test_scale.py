"""At scale on the real stack: a worker keeps the decoded reference; meshes are built by a job, then served."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tests.app.integration.helpers import RIG, download, finished, simulated_zip, upload, url, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_worker_keeps_the_reference_and_meshes_are_built_on_request(stack, http):
    stack.start_worker("worker-1")
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    reference = upload(http, rig_id, simulated_zip("reference")[0], "reference")
    obj = upload(http, rig_id, simulated_zip("sphere")[0], "object")
    bodies = []
    for _ in range(3):
        started = http.post(
            url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj}
        )
        assert started.status_code == 202, started.text
        body = wait_for(http, f"/api/measurements/{started.json()['id']}/", finished)
        assert body["status"] == "done", body
        bodies.append(body)
    # the first job reads and decodes the reference; the next ones find it kept in the worker
    first, *kept = (body["timings"]["reference"] for body in bodies)
    # a dictionary look-up (0.2 ms on a quiet machine), not a 320x240 read and decode (the first job's,
    # 12-13 ms): under half the first job's time, which a second decode would not be; an absolute
    # bound of 5 ms failed once in a loaded run (5.2 ms: the worker's thread preempted)
    assert all(seconds < first / 2 for seconds in kept), (first, kept)
    assert "mesh" not in bodies[0]["timings"]

    # storage: the two float32 height maps, under 3x one of them
    measurement_id = bodies[0]["id"]
    stored = sum(stack.stored_files(f"measurements/{measurement_id}").values())
    assert stored < 3 * RIG["width_px"] * RIG["height_px"] * 4, stored

    # meshes: the first request queues a derived-file job (202, Location: the job); once it is
    # done the file is served from the storage, with its length and ranges
    path = f"/api/measurements/{measurement_id}/mesh.stl"
    pending = http.get(url(http, path))
    assert pending.status_code == 202 and pending.headers["Location"] == pending.json()["job_url"]
    first_stl = download(http, path)
    assert first_stl.status_code == 200 and int(first_stl.headers["Content-Length"]) == len(first_stl.content)
    (triangles,) = struct.unpack("<I", first_stl.content[80:84])
    assert len(first_stl.content) == 84 + 50 * triangles and triangles > 1000
    assert [name.rsplit(".", 1)[1] for name in stack.stored_files("derived")] == ["stl"]
    again = http.get(url(http, path), headers={"Range": "bytes=80-83"})
    assert again.status_code == 206 and again.content == first_stl.content[80:84]
    normals = np.frombuffer(first_stl.content[84:], dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", 9), ("a", "<u2")]))
    assert np.median(normals["n"][:, 2]) > 0.9  # a sphere on a plane: normals mostly towards the rig
