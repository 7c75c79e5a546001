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
from tests.app.stacks import SMALL_RIG
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


CROSSED_AXES_CASES = [
    ("L_mm", 1e300, "rig L_mm must be at most 100000 mm"),
    ("d_mm", 2e5, "rig d_mm must be at most 100000 mm"),
    ("fw_mm", 1e308, "rig fw_mm must be at most 100000 mm"),
    ("width_px", 1e9, "rig width_px must be at most 65536 pixels"),
    ("height_px", 70000, "rig height_px must be at most 65536 pixels"),
]


@pytest.mark.parametrize(("key", "value", "message"), CROSSED_AXES_CASES)
def test_the_api_refuses_unbounded_crossed_axes_values_naming_the_key(api, key, value, message):
    """The crossed-axes rig is bounded like the pinhole rig: lengths as translations, sides as cameras'."""
    response = api.post("/api/rigs/", {**SMALL_RIG, key: value}, format="json")
    assert response.status_code == 400 and message in response.json()["error"], response.content
    assert Rig.objects.count() == 0


def test_the_api_refuses_a_pinhole_camera_side_beyond_the_bound(api):
    data = copy.deepcopy(RIG.to_dict())
    data["camera"]["width_px"] = 1e9
    response = api.post("/api/rigs/", data, format="json")
    assert response.status_code == 400, response.content
    assert "camera width_px must be at most 65536 pixels" in response.json()["error"]


def test_bounds_leave_the_largest_sensible_crossed_axes_rig_valid(api):
    response = api.post("/api/rigs/", {**SMALL_RIG, "L_mm": 1e5, "d_mm": 1e5, "fw_mm": 1e5}, format="json")
    assert response.status_code == 201, response.content
