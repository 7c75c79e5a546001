"""Bounded codec values at every door (issue 23 item 6): the API's rig codec and rig creation, an
upload's codec.json, the dashboard's codec form and upload form. Each refuses, naming the field,
what ``metrology.core.codecs.model.validate_codec`` refuses: projector sides above 16384 px,
periods and words above 64 times the projector's extent, numbers that are not finite."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.models import Capture
from metrology.rigs.models import Rig
from tests.app.codec_stacks import CODEC, codec_images, codec_zip
from tests.app.stacks import SMALL_RIG
from tests.app.uploads import post_capture
from tests.conftest import logged_in


def _codec(change: str) -> dict[str, Any]:
    codec = copy.deepcopy(CODEC)
    if change == "period":
        codec["axes"]["u"]["phase"][0]["period"] = 1e308
    elif change == "word":
        codec["axes"]["u"]["gray"]["word"] = 64 * 1024 + 1
    else:
        codec["projector"]["width"] = 10**9
    return codec


CASES = [
    ("period", "axes.u.phase[0].period must be at most 64 times the projector's extent"),
    ("word", "axes.u.gray.word must be at most 64 times the projector's extent"),
    ("width", "projector.width must be at most 16384 pixels"),
]


@pytest.mark.parametrize(("change", "message"), CASES)
def test_the_api_refuses_unbounded_codecs_naming_the_field(api, rig, change, message):
    url = f"/api/rigs/{rig['id']}/codec/"
    response = api.put(url, {"codec": _codec(change)}, format="json")
    assert response.status_code == 400 and message in response.json()["error"], response.content
    assert api.get(url).json() == {"codec": "gcps-v1"}
    created = api.post("/api/rigs/", {**SMALL_RIG, "codec": _codec(change)}, format="json")
    assert created.status_code == 400 and message in created.json()["error"], created.content
    acquire = api.post(
        f"/api/rigs/{rig['id']}/captures/acquire/", {"role": "object", "codec": _codec(change)}, format="json"
    )
    assert acquire.status_code == 400 and message in acquire.json()["error"], acquire.content
    assert Rig.objects.count() == 1


@pytest.mark.parametrize(("change", "message"), CASES)
def test_an_upload_whose_codec_json_is_unbounded_is_refused(api, rig, media_root, change, message):
    response = post_capture(api, rig["id"], codec_zip(codec_images(0.0), _codec(change)), "reference")
    assert response.status_code == 400 and message in response.json()["error"], response.content
    assert Capture.objects.count() == 0


def test_the_dashboard_refuses_unbounded_codecs_naming_the_field(api, rig, media_root):
    client = logged_in(api.user)
    for change, message in CASES:
        page = client.post(f"/rigs/{rig['id']}/", {"codec": json.dumps(_codec(change))})
        assert page.status_code == 400 and message in page.content.decode().replace("&#x27;", "'"), change
        upload = client.post(
            f"/rigs/{rig['id']}/captures/",
            {
                "action": "upload",
                "upload-role": "reference",
                "upload-file": SimpleUploadedFile("r.zip", codec_zip(codec_images(0.0), _codec(change))),
            },
        )
        assert upload.status_code == 400 and message in upload.content.decode().replace("&#x27;", "'"), change
    assert api.get(f"/api/rigs/{rig['id']}/codec/").json() == {"codec": "gcps-v1"}
    assert Capture.objects.count() == 0
