"""Uploading capture stacks: the good case, and every bad input answers 400 and stores nothing."""

from __future__ import annotations

import io
import struct
import zipfile
import zlib

import numpy as np
import pytest

from metrology.captures.models import Capture, CaptureSession
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.patterns import PATTERN_NAMES
from tests.app.stacks import SMALL_RIG, plane_zip, png, render_images, stack_zip, zip_bytes
from tests.conftest import stored_files


def upload(api, rig_id, data: bytes, name="stack.zip", **fields):
    payload = {"file": io.BytesIO(data), "role": "reference", **fields}
    payload["file"].name = name
    return api.post(f"/api/rigs/{rig_id}/captures/", payload, format="multipart")


def test_upload_stores_the_stack_with_checksum_and_shape(api, rig, media_root):
    data = plane_zip()
    response = upload(api, rig["id"], data)
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["role"] == "reference" and body["source"] == "upload" and body["status"] == "stored"
    assert (body["height_px"], body["width_px"], body["bit_depth"]) == (120, 160, 8)
    import hashlib

    assert body["checksum_sha256"] == hashlib.sha256(data).hexdigest()
    assert len(stored_files(media_root)) == 1
    download = api.get(f"/api/captures/{body['id']}/stack.zip")
    assert download.status_code == 200 and b"".join(download.streaming_content) == data


def test_uploads_without_session_get_one_each_and_may_name_one(api, rig):
    first = upload(api, rig["id"], plane_zip()).json()
    second = upload(api, rig["id"], plane_zip(z_mm=10.0), role="object", session=first["session"]).json()
    assert second["session"] == first["session"]
    third = upload(api, rig["id"], plane_zip(z_mm=10.0), role="object").json()
    assert third["session"] != first["session"]


def test_stage_capture_keeps_z_and_repeat(api, rig):
    body = upload(api, rig["id"], plane_zip(z_mm=4.0), role="stage", z_in_mm=4.0, repeat=3).json()
    assert body["z_in_mm"] == 4.0 and body["repeat"] == 3


def _bad_png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` (its data is a few bytes)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (
        b"\x89PNG\r\n\x1a\n"
        + struct.pack(">I", len(ihdr))
        + chunk
        + struct.pack(">I", zlib.crc32(chunk))
        + b"\x00\x00\x00\x00IEND\xaeB`\x82"
    )


def _bomb() -> bytes:
    images = render_images(Rig.from_dict(SMALL_RIG), 0.0)
    members = {f"{name}.png": png(image) for name, image in zip(PATTERN_NAMES, images, strict=True)}
    members["PS_3.png"] = b"\x00" * (600 * 1024 * 1024)  # 600 MB of zeros deflate to ~600 kB
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def _sixteen_bit() -> bytes:
    return plane_zip(bit_depth=16)


def _mismatched_shapes() -> bytes:
    images = list(render_images(Rig.from_dict(SMALL_RIG), 0.0))
    members = {f"{name}.png": png(image) for name, image in zip(PATTERN_NAMES, images, strict=True)}
    members["GC_3.png"] = png(np.zeros((60, 80), np.uint8))
    return zip_bytes(members)


def _traversal() -> bytes:
    images = render_images(Rig.from_dict(SMALL_RIG), 0.0)
    members = {f"{name}.png": png(image) for name, image in zip(PATTERN_NAMES, images, strict=True)}
    members["../../etc/GC_0.png"] = members.pop("GC_0.png")
    return zip_bytes(members)


def _missing() -> bytes:
    images = render_images(Rig.from_dict(SMALL_RIG), 0.0)
    return zip_bytes({f"{name}.png": png(image) for name, image in zip(PATTERN_NAMES[:-1], images, strict=False)})


def _wrong_names() -> bytes:
    images = render_images(Rig.from_dict(SMALL_RIG), 0.0)
    return stack_zip(images, names=tuple(f"image_{i:02d}" for i in range(11)))


def _huge_header() -> bytes:
    images = render_images(Rig.from_dict(SMALL_RIG), 0.0)
    members = {f"{name}.png": png(image) for name, image in zip(PATTERN_NAMES, images, strict=True)}
    members["GC_0.png"] = _bad_png_header(200_000, 200_000)
    return zip_bytes(members)


def _other_shape() -> bytes:
    return plane_zip({**SMALL_RIG, "width_px": 80, "height_px": 60})


BAD_STACKS = {
    "not a zip": (lambda: b"this is not a zip file at all", {}, "not a zip"),
    "missing pattern": (_missing, {}, "PS_3"),
    "wrong names": (_wrong_names, {}, "GC_0"),
    "mismatched shapes": (_mismatched_shapes, {}, "shape"),
    "shape unlike the rig's": (_other_shape, {}, "rig"),
    "16-bit where 8 declared": (_sixteen_bit, {"bit_depth": 8}, "bit"),
    "path traversal": (_traversal, {}, ".."),
    "huge image header": (_huge_header, {}, "200000"),
    "zip bomb": (_bomb, {}, "limit"),
}


@pytest.mark.parametrize("case", list(BAD_STACKS))
def test_bad_stack_is_refused_and_nothing_is_stored(api, rig, media_root, case):
    make, fields, words = BAD_STACKS[case]
    response = upload(api, rig["id"], make(), **fields)
    assert response.status_code == 400, response.content
    message = response.json()["error"]
    assert message.startswith("capture stack refused:"), message
    assert words.lower() in message.lower(), message
    assert Capture.objects.count() == 0
    assert CaptureSession.objects.count() == 0
    assert stored_files(media_root) == []


def test_stack_larger_than_the_rig_says_it_does_not_match_the_rig(api, rig, media_root):
    """A stack bigger than the rig is a mismatch, not a size-limit problem (issue 9 item 2)."""
    response = upload(api, rig["id"], plane_zip({**SMALL_RIG, "width_px": 320, "height_px": 240}))
    assert response.status_code == 400, response.content
    message = response.json()["error"]
    assert "does not match the rig" in message, message
    assert "expected 160x120 from the rig, got 320x240" in message, message
    assert "limit" not in message, message
    assert Capture.objects.count() == 0 and stored_files(media_root) == []


def test_oversized_upload_is_refused(api, rig, media_root, settings):
    settings.GCPS_MAX_UPLOAD_BYTES = 1000
    response = upload(api, rig["id"], plane_zip())
    assert response.status_code == 400
    assert "exceeds the limit of 1000 bytes" in response.json()["error"]
    assert "GCPS_MAX_UPLOAD_BYTES" in response.json()["error"]
    assert Capture.objects.count() == 0 and stored_files(media_root) == []


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"role": "sideways"}, "role"),
        ({"role": "stage"}, "z_in_mm is required"),
        ({"repeat": -1}, "repeat"),
        ({"session": 999}, "session 999 does not exist"),
        ({"bit_depth": 12}, "bit_depth"),
    ],
)
def test_bad_fields_are_refused(api, rig, media_root, fields, words):
    response = upload(api, rig["id"], plane_zip(), **fields)
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]
    assert Capture.objects.count() == 0 and stored_files(media_root) == []


def test_missing_file_is_refused(api, rig):
    response = api.post(f"/api/rigs/{rig['id']}/captures/", {"role": "reference"}, format="multipart")
    assert response.status_code == 400
    assert response.json()["error"].startswith("file:")


def test_session_of_another_rig_is_refused(api, rig, media_root):
    other = api.post("/api/rigs/", SMALL_RIG, format="json").json()
    session = upload(api, other["id"], plane_zip()).json()["session"]
    before = stored_files(media_root)
    response = upload(api, rig["id"], plane_zip(), session=session)
    assert response.status_code == 400
    assert f"belongs to rig {other['id']}" in response.json()["error"]
    assert Capture.objects.count() == 1 and stored_files(media_root) == before


def test_file_is_removed_when_the_row_cannot_be_written(api, rig, media_root, monkeypatch):
    def broken(**_kwargs):
        raise RuntimeError("database went away")

    monkeypatch.setattr(Capture.objects, "create", broken)
    with pytest.raises(RuntimeError):
        upload(api, rig["id"], plane_zip())
    assert stored_files(media_root) == []
