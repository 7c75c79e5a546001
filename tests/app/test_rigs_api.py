"""Rigs: create from the rig JSON, list, read; out-of-range values answer 400 naming the value."""

from __future__ import annotations

import pytest

from metrology.rigs.models import Rig, RigParameters
from tests.app.stacks import SMALL_RIG


def test_create_list_and_read_a_rig(api):
    response = api.post("/api/rigs/", {**SMALL_RIG, "name": "bench", "notes": "lab 2", "lens": "25 mm"}, format="json")
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["name"] == "bench" and body["L_mm"] == 1022.0 and body["nlp"] == 128
    assert body["extra"] == {"lens": "25 mm"}
    assert [entry["source"] for entry in body["history"]] == ["created"]
    assert [rig["id"] for rig in api.get("/api/rigs/").json()] == [body["id"]]
    assert api.get(f"/api/rigs/{body['id']}/").json()["width_px"] == 160


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"L_mm": -5}, "L_mm must be a positive finite number"),
        ({"alpha_rad": 2.0}, "alpha_rad must lie in (0, pi/2)"),
        ({"nlp": 0}, "nlp"),
        ({"nlp": 300}, "nlp"),
        ({"width_px": 0}, "width_px"),
        ({"fw_mm": "wide"}, "fw_mm must be a positive finite number, got 'wide'"),
        ({"d_mm": None}, "d_mm"),
    ],
)
def test_out_of_range_rig_values_are_refused(api, change, words):
    response = api.post("/api/rigs/", {**SMALL_RIG, **change}, format="json")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]
    assert Rig.objects.count() == 0 and RigParameters.objects.count() == 0


def test_missing_key_is_named(api):
    data = dict(SMALL_RIG)
    del data["alpha_rad"]
    response = api.post("/api/rigs/", data, format="json")
    assert response.status_code == 400
    assert response.json()["error"] == "rig is missing required key(s): alpha_rad"


def test_degenerate_geometry_is_refused_with_the_core_message(api):
    response = api.post("/api/rigs/", {**SMALL_RIG, "L_mm": 1.0, "d_mm": 1.0, "fw_mm": 1000.0}, format="json")
    assert response.status_code == 400
    assert response.json()["error"] == "rig field extends implausibly far behind the projector"


def test_body_that_is_not_an_object_is_refused(api):
    response = api.post("/api/rigs/", [1, 2, 3], format="json")
    assert response.status_code == 400
    assert "JSON object" in response.json()["error"]


def test_malformed_json_is_refused(api):
    response = api.generic("POST", "/api/rigs/", "{not json", content_type="application/json")
    assert response.status_code == 400
    assert "JSON parse error" in response.json()["error"]
