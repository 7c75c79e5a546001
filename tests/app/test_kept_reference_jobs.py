"""Jobs decode a reference once per process (the kept reference) and read stacks verified by their hash."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.captures import references
from metrology.captures.models import Capture
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import StackError, read_stack, read_verified_stack
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload, upload_heights

pytestmark = pytest.mark.django_db(transaction=True)
CORE_RIG = Rig.from_dict(SMALL_RIG)


@pytest.fixture(autouse=True)
def fresh_process_cache(settings):
    """Each test starts with an empty kept-reference cache, as a new worker process would."""
    settings.GCPS_REFERENCE_CACHE_BYTES = 64 * 1024**2
    references.kept_references().clear()
    references.kept_references().stats.__init__()  # type: ignore[misc]


def measure(api, rig_id: int, reference: int, obj: int, options: dict | None = None) -> dict:
    body = {"rig": rig_id, "reference": reference, "object": obj, **({"options": options} if options else {})}
    response = api.post("/api/measurements/", body, format="json")
    assert response.status_code == 202, response.content
    done = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert done["status"] in ("done", "failed"), done
    return done


def heights(api, measurement_id: int) -> np.ndarray:
    return np.load(io.BytesIO(b"".join(api.get(f"/api/measurements/{measurement_id}/height.npy").streaming_content)))


def test_second_measurement_reuses_the_decoded_reference(api, rig):
    reference = upload(api, rig["id"], stack_zip(render_images(CORE_RIG, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(CORE_RIG, block_heights(), bit_depth=16)), "object")
    stats = references.kept_references().stats
    first = measure(api, rig["id"], reference, obj)
    assert (stats.hits, stats.misses) == (0, 1)
    second = measure(api, rig["id"], reference, obj)
    assert (stats.hits, stats.misses) == (1, 1)
    assert first["status"] == second["status"] == "done"
    np.testing.assert_array_equal(heights(api, first["id"]), heights(api, second["id"]))
    # other decoding options are another decoded reference
    third = measure(api, rig["id"], reference, obj, {"decode": {"edge_band_px": 0}})
    assert third["status"] == "done" and (stats.hits, stats.misses) == (1, 2)
    # a changed rig (a recalibrated L) or a replaced file is another key: decoded again
    from metrology.core.measure import MeasureOptions

    capture = Capture.objects.get(pk=reference)
    rig_file = {"model": "crossed_axes", **SMALL_RIG}
    key = references.reference_key(capture, rig_file, None, MeasureOptions())
    assert references.reference_key(capture, {**rig_file, "L_mm": 1030.0}, None, MeasureOptions()) != key
    capture.checksum_sha256 = "0" * 64
    assert references.reference_key(capture, rig_file, None, MeasureOptions()) != key


def test_a_stack_changed_since_upload_is_refused(api, rig, media_root):
    reference = upload(api, rig["id"], stack_zip(render_images(CORE_RIG, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(CORE_RIG, block_heights(), bit_depth=16)), "object")
    stored = Capture.objects.get(pk=obj)
    # another valid stack written over the stored file: valid, but not what was validated and hashed
    (media_root / stored.file.name).write_bytes(stack_zip(render_images(CORE_RIG, 5.0, bit_depth=16)))
    failed = measure(api, rig["id"], reference, obj)
    assert failed["status"] == "failed"
    assert "no longer matches the sha256 recorded when it was validated" in failed["error"], failed["error"]


def test_read_verified_stack_equals_read_stack_and_checks_the_hash():
    import hashlib

    data = stack_zip(render_images(CORE_RIG, block_heights(), bit_depth=16))
    digest = hashlib.sha256(data).hexdigest()
    verified = read_verified_stack(data, digest, shape=CORE_RIG.shape)
    checked = read_stack(io.BytesIO(data), rig=CORE_RIG)
    np.testing.assert_array_equal(verified.images, checked.images)
    assert verified.bit_depth == checked.bit_depth == 16 and verified.shape == CORE_RIG.shape
    with pytest.raises(StackError, match="no longer matches the sha256"):
        read_verified_stack(data + b"\0", digest)
    with pytest.raises(StackError, match=r"but \(10, 10\) was expected"):
        read_verified_stack(data, digest, shape=(10, 10))


def test_characterization_uses_the_kept_reference(api, rig):
    reference = upload_heights(api, rig["id"], 0.0, "reference")["id"]
    session = api.post(f"/api/rigs/{rig['id']}/sessions/", {"name": "stage"}, format="json").json()["id"]
    for z in (0.0, 4.0, 8.0):
        upload_heights(api, rig["id"], z, "stage", z_in_mm=z, repeat=0, session=session)
    stats = references.kept_references().stats
    bodies = []
    for _ in range(2):
        response = api.post(
            "/api/characterizations/",
            {"rig": rig["id"], "reference": reference, "session": session, "options": {"n_points": 5}},
            format="json",
        )
        assert response.status_code == 202, response.content
        bodies.append(api.get(f"/api/characterizations/{response.json()['id']}/").json())
    assert [body["status"] for body in bodies] == ["done", "done"]
    assert (stats.hits, stats.misses) == (1, 1)
    assert bodies[0]["results"]["test_points"] == bodies[1]["results"]["test_points"]
    assert abs(bodies[1]["overall_mean_error_mm"]) < 0.01
