"""Bounded rig values at every door (issue 23 item 6): distortion coefficients within +-1e4,
translations within +-1e5 mm, every number finite; the API and the dashboard's rig-file import
refuse them naming the key (the core's rig-file validation, ``core/geometry/rig_file.py``)."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.rigs.models import Rig
from tests.conftest import logged_in
from tests.pinhole_stacks import RIG


def _rig_file(change: str) -> dict[str, Any]:
    data = copy.deepcopy(RIG.to_dict())
    if change == "dist":
        data["camera"]["dist"] = [1e300, 0.0, 0.0, 0.0, 0.0]
    elif change == "projector dist":
        data["projector"]["dist"] = [0.0, 0.0, 0.0, -2e4]
    else:
        data["T"] = [0.0, 0.0, 1e308]
    return data


CASES = [
    ("dist", "camera dist[0] must be within +-10000"),
    ("projector dist", "projector dist[3] must be within +-10000"),
    ("T", "T[2] must be within +-100000 mm"),
]


@pytest.mark.parametrize(("change", "message"), CASES)
def test_the_api_refuses_unbounded_rig_values_naming_the_key(api, change, message):
    response = api.post("/api/rigs/", _rig_file(change), format="json")
    assert response.status_code == 400 and message in response.json()["error"], response.content
    assert Rig.objects.count() == 0


def test_the_rig_file_page_refuses_unbounded_rig_values_naming_the_key(api):
    client = logged_in(api.user)
    for change, message in CASES:
        upload = SimpleUploadedFile("rig.json", json.dumps(_rig_file(change)).encode())
        page = client.post("/rigs/", {"action": "rig_file", "file-name": "bench", "file-rig_file": upload})
        assert page.status_code == 400 and message in page.content.decode(), change
    text = json.dumps(RIG.to_dict()).replace(str(RIG.to_dict()["T"][0]), "1e400", 1)
    page = client.post("/rigs/", {"action": "rig_file", "file-rig_file": SimpleUploadedFile("rig.json", text.encode())})
    assert page.status_code == 400 and "T[0] must be a finite number" in page.content.decode()
    assert Rig.objects.count() == 0
