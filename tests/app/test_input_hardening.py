"""No 500 on input (issue 9 item 4): deep JSON, NUL characters, booleans for numbers, big ``extra``,
oversized bodies; each answers a JSON 400/413 and stores nothing."""

from __future__ import annotations

import json

import pytest
from django.test import Client

from metrology.rigs.models import Rig
from tests.app.stacks import SMALL_RIG


def post_raw(api, path: str, body: bytes, content_type: str = "application/json"):
    return api.generic("POST", path, body, content_type=content_type)


@pytest.mark.parametrize("depth", [50, 100_000])
def test_deeply_nested_json_is_refused(api, rig, depth):
    nested = "[" * depth + "]" * depth
    body = ('{"role": "object", "scene": {"name": "plane", "x": ' + nested + "}}").encode()
    response = post_raw(api, f"/api/rigs/{rig['id']}/captures/simulate/", body)
    assert response.status_code == 400, response.content[:300]
    assert "nested" in response.json()["error"]
    rig_body = ('{"L_mm": 1022, "deep": ' + nested + "}").encode()
    response = post_raw(api, "/api/rigs/", rig_body)
    assert response.status_code == 400, response.content[:300]
    assert "nested" in response.json()["error"]


@pytest.mark.parametrize(
    "extra",
    [{"lens\x00": "25 mm"}, {"lens": "25\x00mm"}, {"lenses": [{"focal": "a\x00"}]}, {"notes2": {"k\x00": 1}}],
)
def test_nul_characters_in_extra_are_refused(api, extra):
    response = api.post("/api/rigs/", {**SMALL_RIG, **extra}, format="json")
    assert response.status_code == 400, response.content
    assert "NUL" in response.json()["error"], response.json()
    assert Rig.objects.count() == 0


def test_nul_character_anywhere_in_a_json_body_is_refused(api, rig):
    response = api.post("/api/rigs/", {**SMALL_RIG, "name": "a\x00b"}, format="json")
    assert response.status_code == 400, response.content
    assert "NUL" in response.json()["error"]
    body = {"role": "object", "scene": {"name": "plane", "z\x00": 1}}
    response = api.post(f"/api/rigs/{rig['id']}/captures/simulate/", body, format="json")
    assert response.status_code == 400, response.content
    assert "NUL" in response.json()["error"]


def test_nul_character_in_extra_is_refused_by_the_service(user_and_token):
    from metrology.api_errors import BadInput
    from metrology.rigs.services import create_rig

    with pytest.raises(BadInput, match="NUL"):
        create_rig(owner=user_and_token[0], data={**SMALL_RIG, "lenses": [{"focal\x00": 25}]})
    assert Rig.objects.count() == 0


@pytest.mark.parametrize("key", ["L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px"])
def test_booleans_are_not_numbers(api, key):
    response = api.post("/api/rigs/", {**SMALL_RIG, key: True}, format="json")
    assert response.status_code == 400, response.content
    assert key in response.json()["error"]
    assert Rig.objects.count() == 0


def test_boolean_stage_position_is_refused(api, rig):
    body = {"role": "stage", "scene": {"name": "stage"}, "z_in_mm": True}
    response = api.post(f"/api/rigs/{rig['id']}/captures/simulate/", body, format="json")
    assert response.status_code == 400, response.content
    assert "z_in_mm" in response.json()["error"]


def test_extra_is_bounded(api, settings):
    limit = settings.GCPS_MAX_RIG_EXTRA_BYTES
    assert limit == 16 * 1024
    response = api.post("/api/rigs/", {**SMALL_RIG, "blob": "x" * (limit + 1)}, format="json")
    assert response.status_code == 400, response.content
    assert "extra" in response.json()["error"] and str(limit) in response.json()["error"]
    assert Rig.objects.count() == 0
    ok = api.post("/api/rigs/", {**SMALL_RIG, "blob": "x" * (limit - 100)}, format="json")
    assert ok.status_code == 201, ok.content


def test_rig_list_leaves_extra_and_history_to_the_detail(api):
    created = api.post("/api/rigs/", {**SMALL_RIG, "blob": "x" * 10_000}, format="json").json()
    listed = api.get("/api/rigs/").json()
    assert [rig["id"] for rig in listed] == [created["id"]]
    assert "extra" not in listed[0] and "history" not in listed[0]
    assert len(json.dumps(listed)) < 2000
    detail = api.get(f"/api/rigs/{created['id']}/").json()
    assert detail["extra"] == {"blob": "x" * 10_000} and detail["history"]


@pytest.mark.parametrize("path", ["/api/rigs/", "/api/measurements/", "/api/rigs/1/captures/simulate/"])
def test_thirty_megabyte_body_gets_a_json_answer(api, path):
    body = b'{"name": "' + b"x" * (30 * 1024 * 1024) + b'"}'
    response = post_raw(api, path, body)
    assert response.status_code == 413, response.content[:300]
    assert response["Content-Type"].startswith("application/json")
    assert "bytes" in response.json()["error"]
    assert Rig.objects.count() == 0


def test_thirty_megabyte_form_outside_the_api_is_refused_without_a_server_error(db):
    body = b"a=" + b"x" * (30 * 1024 * 1024)
    response = Client().post("/login/", body, content_type="application/x-www-form-urlencoded")
    assert response.status_code in (400, 413)


NON_FINITE = ["1e400", "-1e400", "NaN", "Infinity", "-Infinity"]


@pytest.mark.parametrize("number", NON_FINITE)
def test_non_finite_number_in_extra_answers_400_naming_its_key(api, number):
    body = json.dumps({**SMALL_RIG, "extra": {"a": {"b": "NUMBER"}}}).replace('"NUMBER"', number)
    response = post_raw(api, "/api/rigs/", body.encode())
    assert response.status_code == 400, response.content
    error = response.json()["error"]
    assert "extra.a.b" in error and "finite" in error, error
    assert Rig.objects.count() == 0


@pytest.mark.parametrize("number", NON_FINITE)
def test_non_finite_number_anywhere_answers_400_naming_its_json_path(api, rig, number):
    from tests.app.codec_stacks import CODEC

    body = json.dumps({"codec": CODEC}).replace('"period": 32.0', f'"period": {number}')
    response = api.generic("PUT", f"/api/rigs/{rig['id']}/codec/", body.encode(), content_type="application/json")
    assert response.status_code == 400, response.content
    assert "codec.axes.u.phase[0].period" in response.json()["error"]
    assert api.get(f"/api/rigs/{rig['id']}/codec/").json() == {"codec": "gcps-v1"}
    top = post_raw(api, "/api/rigs/", json.dumps({**SMALL_RIG, "L_mm": "N"}).replace('"N"', number).encode())
    assert top.status_code == 400 and "L_mm must be a finite number" in top.json()["error"], top.content
    in_list = {"role": "object", "scene": {"name": "plane", "xs": [1.0, "N"]}}
    simulate = f"/api/rigs/{rig['id']}/captures/simulate/"
    listed = post_raw(api, simulate, json.dumps(in_list).replace('"N"', number).encode())
    assert listed.status_code == 400 and "scene.xs[1]" in listed.json()["error"], listed.content
    whole = post_raw(api, "/api/rigs/", number.encode())
    assert whole.status_code == 400 and "finite" in whole.json()["error"], whole.content
    assert Rig.objects.count() == 1


def test_json_problem_names_the_first_non_finite_number_in_document_order():
    from metrology.api_input import json_problem

    value = {"a": [1.0, {"b": float("nan")}], "c": float("inf")}
    assert json_problem(value, 32) == "a[1].b must be a finite number, got NaN"
    assert json_problem({"a": 1e308, "b": [0.5]}, 32) is None


def test_non_finite_number_in_extra_is_refused_by_the_service_and_the_rig_file_page(alice, client_alice):
    from django.core.files.uploadedfile import SimpleUploadedFile

    from metrology.errors import BadInput
    from metrology.rigs.services import create_rig

    with pytest.raises(BadInput, match=r"lens\.k\[1\] must be a finite number"):
        create_rig(owner=alice, data={**SMALL_RIG, "lens": {"k": [0.5, float("inf")]}})
    text = json.dumps({**SMALL_RIG, "lens": {"k": [0.5, "N"]}}).replace('"N"', "1e400")
    page = client_alice.post(
        "/rigs/", {"action": "rig_file", "file-rig_file": SimpleUploadedFile("rig.json", text.encode())}
    )
    assert page.status_code == 400 and "lens.k[1] must be a finite number" in page.content.decode()
    assert Rig.objects.count() == 0


DEEP_OBJECT = '{"a": ' + "[" * 50_000 + "]" * 50_000 + "}"  # under the codec fields' 200,000 characters


def test_json_typed_into_pages_is_checked_like_a_json_body(api, rig, media_root):
    """The codec fields of the rig and acquire pages, the rig-file upload and an agent's multipart
    ``frames``: deep nesting and non-finite numbers answer 400 in words, never a RecursionError."""
    from django.core.files.uploadedfile import SimpleUploadedFile

    from tests.conftest import logged_in

    client = logged_in(api.user)
    codec_nan = '{"codec": "gcps-codec/1", "frames": 3, "projector": {"width": 64, "height": NaN}}'
    for text, message in ((DEEP_OBJECT, "nested deeper than 32 levels"), (codec_nan, "projector.height must be")):
        page = client.post(f"/rigs/{rig['id']}/", {"codec": text})
        assert page.status_code == 400 and message in page.content.decode(), page.content[-2000:]
        acquire = client.post(f"/rigs/{rig['id']}/acquire/", {"role": "reference", "codec": text})
        assert acquire.status_code == 400 and message in acquire.content.decode(), acquire.content[-2000:]
    upload = SimpleUploadedFile("rig.json", DEEP_OBJECT.encode())
    page = client.post("/rigs/", {"action": "rig_file", "file-rig_file": upload})
    assert page.status_code == 400 and "nested deeper than 32 levels" in page.content.decode()
    assert api.get(f"/api/rigs/{rig['id']}/codec/").json() == {"codec": "gcps-v1"}
    assert Rig.objects.count() == 1


def test_an_agents_multipart_frames_field_is_checked_like_a_json_body(api, rig):
    import io

    rig_id = rig["id"]
    session = api.post(f"/api/rigs/{rig_id}/agent/register/", {"camera": "virtual"}, format="json").json()["session"]
    queued = api.post(f"/api/rigs/{rig_id}/captures/acquire/", {"role": "reference"}, format="json").json()
    taken = api.post(f"/api/rigs/{rig_id}/agent/take/", {"session": session}, format="json")
    assert taken.status_code == 200 and taken.json()["id"] == queued["id"]
    for frames, message in (("[" * 100_000 + "]" * 100_000, "nested deeper"), ('[{"mean": NaN}]', "[0].mean")):
        upload = io.BytesIO(b"PK\x05\x06" + b"\x00" * 18)
        upload.name = "stack.zip"
        body = {"session": session, "file": upload, "frames": frames}
        response = api.post(f"/api/acquisitions/{queued['id']}/upload/", body, format="multipart")
        assert response.status_code == 400 and message in response.json()["error"], response.content[:500]
