"""Multi-exposure captures through the REST API and a measurement job (issue 26, docs/exposures.md):
the upload of exposures.json + one folder per exposure, refused with the exposure and the file
named; a multi-exposure object against a single-exposure reference and the reverse, measured to
the exact heights; the exposure map, its PLY property and the counts per exposure."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import Rig
from tests.app.stacks import SMALL_RIG, block_heights, hdr_members, render_images, stack_zip, zip_bytes
from tests.app.uploads import post_capture, upload
from tests.conftest import stored_files

pytestmark = pytest.mark.django_db(transaction=True)  # jobs are enqueued on commit

CORE = Rig.from_dict(SMALL_RIG)


def _multi(z) -> bytes:
    return zip_bytes(hdr_members(CORE, z))


def _single(z) -> bytes:
    return stack_zip(render_images(CORE, z, bit_depth=16))


def test_a_multi_exposure_upload_is_stored_with_its_exposures(api, rig):
    response = post_capture(api, rig["id"], _multi(0.0), "reference")
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["exposures"] == [{"name": "short", "exposure_us": 1000.0}, {"name": "long", "exposure_us": 10000.0}]
    assert (body["height_px"], body["width_px"], body["bit_depth"]) == (120, 160, 16)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda m: m.pop("long/PS_2.png"), ("long", "PS_2")),
        (
            lambda m: m.update(
                {"exposures.json": m["exposures.json"].replace(b'"exposure_us"', b'"iso": 1, "exposure_us"', 1)}
            ),
            ("exposures.json", "short", "iso"),
        ),
        (lambda m: [m.pop(k) for k in list(m) if k.startswith("short/")], ("short",)),
        (lambda m: m.update({"long/GC_0.png": b"not a png"}), ("long", "GC_0")),
    ],
    ids=["missing-frame", "unknown-key", "missing-folder", "unreadable-frame"],
)
def test_a_bad_multi_exposure_upload_names_the_exposure_and_the_file(api, rig, media_root, change, words):
    members = hdr_members(CORE, 0.0)
    change(members)
    response = post_capture(api, rig["id"], zip_bytes(members), "reference")
    assert response.status_code == 400, response.content
    message = str(response.json())
    assert all(word in message for word in words), message
    assert stored_files(media_root) == []


def _measure(api, rig_id: int, reference: int, obj: int) -> dict:
    response = api.post("/api/measurements/", {"rig": rig_id, "reference": reference, "object": obj}, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    return body


def _download(api, body: dict, name: str) -> bytes:
    response = api.get(f"/api/measurements/{body['id']}/{name}")
    assert response.status_code == 200, name
    return b"".join(response.streaming_content)


@pytest.mark.parametrize("multi", ["object", "reference"])
def test_multi_and_single_exposure_captures_measure_together_through_a_job(api, rig, multi):
    truth = block_heights()
    reference = upload(api, rig["id"], _multi(0.0) if multi == "reference" else _single(0.0), "reference")
    obj = upload(api, rig["id"], _multi(truth) if multi == "object" else _single(truth), "object")
    body = _measure(api, rig["id"], reference, obj)
    z = np.load(io.BytesIO(_download(api, body, "height.npy")))
    inner = np.zeros(truth.shape, bool)
    inner[35:85, 45:115] = True
    inner[:20, :] = True
    ok = inner & np.isfinite(z)
    assert ok.sum() > 0.8 * inner.sum()
    assert np.abs(z[ok] - truth[ok]).max() < 0.01  # as the single 16-bit stacks: quantisation
    counts = body["statistics"]["points_per_exposure"]
    exposure = np.load(io.BytesIO(_download(api, body, "exposure.npy")))
    assert exposure.dtype == np.uint8 and exposure.shape == z.shape
    assert np.array_equal(exposure == 255, ~np.isfinite(z))  # 255 exactly where not measured
    if multi == "reference":  # the single-exposure object: one exposure measured every point
        assert counts == {"exp0": int(np.isfinite(z).sum())}
        return
    assert counts == {"short": int((exposure == 0).sum()), "long": int((exposure == 1).sum())}
    assert sum(counts.values()) == body["statistics"]["valid_pixels"]
    measured = np.isfinite(z)
    left, right = measured[:, :75], measured[:, 85:]
    assert (exposure[:, :75][left] == 0).all()  # the long exposure saturates the bright half
    assert (exposure[:, 85:][right] == 1).all()  # and measures the dark half with 10x the modulation
    ply = _download(api, body, "mesh.ply")
    header, _, data = ply.partition(b"end_header\n")
    assert b"property uchar exposure\n" in header
    vertices = int(header.split(b"element vertex ")[1].split(b"\n")[0])
    assert vertices == measured.sum()
    record = np.dtype([("p", "<f8", (3,)), ("n", "<f8", (3,)), ("exposure", "u1")])
    written = np.frombuffer(data[: vertices * record.itemsize], record)
    assert np.array_equal(written["exposure"], exposure[measured])
