"""A codec.json in a sub-folder of an uploaded zip, or nested too deep to parse, is refused
(issue 23 item 6): 400 from the API, a form error on the page, nothing stored, no traceback.
(The command line's exit 2: tests/commands/test_decode.py.)"""

from __future__ import annotations

import json

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.models import Capture
from tests.app.codec_stacks import CODEC, codec_images
from tests.app.stacks import png, zip_bytes
from tests.app.uploads import post_capture
from tests.conftest import logged_in

DEEP = b'{"codec": "gcps-codec/1", "axes": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
CASES = [
    ("stack/codec.json", json.dumps(CODEC).encode(), "holds codec.json in a sub-folder (stack/codec.json)"),
    ("a/b/c/d/e/f/codec.json", json.dumps(CODEC).encode(), "in a sub-folder (a/b/c/d/e/f/codec.json)"),
    ("codec.json", DEEP, "codec.json is nested deeper than 16 levels"),
]


@pytest.fixture(scope="module")
def frames() -> dict[str, bytes]:
    return {f"frame{index:02d}.png": png(image) for index, image in enumerate(codec_images(0.0))}


@pytest.mark.parametrize(("member", "data", "message"), CASES)
def test_the_api_refuses_a_nested_codec_json(api, rig, media_root, frames, member, data, message):
    response = post_capture(api, rig["id"], zip_bytes({**frames, member: data}), "reference")
    assert response.status_code == 400, response.content[:500]
    assert message in response.json()["error"]
    assert Capture.objects.count() == 0


def test_the_upload_page_refuses_a_nested_codec_json(api, rig, media_root, frames):
    client = logged_in(api.user)
    for member, data, message in CASES:
        response = client.post(
            f"/rigs/{rig['id']}/captures/",
            {
                "action": "upload",
                "upload-role": "reference",
                "upload-file": SimpleUploadedFile("r.zip", zip_bytes({**frames, member: data})),
            },
        )
        assert response.status_code == 400 and message in response.content.decode(), member
    assert Capture.objects.count() == 0


def test_a_zip_wholly_inside_one_folder_keeps_its_codec_json(api, rig, media_root, frames):
    members = {f"stack/{name}": data for name, data in frames.items()}
    members["stack/codec.json"] = json.dumps(CODEC).encode()
    response = post_capture(api, rig["id"], zip_bytes(members), "reference")
    assert response.status_code == 201, response.content[:500]
    assert response.json()["codec"]["codec"] == "gcps-codec/1"
