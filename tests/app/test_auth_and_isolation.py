"""Token authentication, the createuser command, and owner isolation (others' objects answer 404)."""

from __future__ import annotations

import io
import re

import pytest
from django.core.management import CommandError, call_command
from rest_framework.test import APIClient

from tests.app.stacks import SMALL_RIG, plane_zip

ENDPOINTS = [
    ("get", "/api/rigs/"),
    ("post", "/api/rigs/"),
    ("get", "/api/rigs/1/"),
    ("get", "/api/rigs/1/captures/"),
    ("post", "/api/rigs/1/captures/"),
    ("post", "/api/rigs/1/captures/simulate/"),
    ("get", "/api/measurements/"),
    ("post", "/api/measurements/"),
    ("get", "/api/measurements/1/"),
    ("get", "/api/measurements/1/height.npy"),
    ("post", "/api/calibrations/"),
    ("post", "/api/characterizations/"),
    ("get", "/api/jobs/1/"),
]


@pytest.mark.django_db
@pytest.mark.parametrize(("method", "url"), ENDPOINTS)
def test_anonymous_requests_answer_401(method, url):
    response = getattr(APIClient(), method)(url)
    assert response.status_code == 401
    assert response.json() == {"error": "Authentication credentials were not provided."}
    assert response["WWW-Authenticate"] == "Token"


@pytest.mark.django_db
def test_wrong_token_answers_401():
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION="Token " + "0" * 40)
    response = client.get("/api/rigs/")
    assert response.status_code == 401 and response.json()["error"] == "Invalid token."


@pytest.mark.django_db
def test_createuser_prints_a_40_hex_token_that_authenticates():
    out = io.StringIO()
    call_command("createuser", "carol", stdout=out)
    key = out.getvalue().strip()
    assert re.fullmatch(r"[0-9a-f]{40}", key)
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    assert client.get("/api/rigs/").status_code == 200
    with pytest.raises(CommandError, match="already exists"):
        call_command("createuser", "carol", stdout=io.StringIO())


@pytest.mark.django_db
def test_schema_and_docs_are_public_and_offline():
    client = APIClient()
    assert client.get("/api/schema/").status_code == 200
    docs = client.get("/api/docs/")
    assert docs.status_code == 200
    assert b"/static/drf_spectacular_sidecar/swagger-ui-dist/" in docs.content


def test_other_users_objects_answer_404(api, other_api, rig):
    upload = io.BytesIO(plane_zip())
    upload.name = "ref.zip"
    capture = api.post(f"/api/rigs/{rig['id']}/captures/", {"file": upload, "role": "reference"}, format="multipart")
    capture_id = capture.json()["id"]
    assert other_api.get(f"/api/rigs/{rig['id']}/").status_code == 404
    assert other_api.get(f"/api/rigs/{rig['id']}/").json() == {"error": f"No rig {rig['id']} among yours."}
    assert other_api.get(f"/api/rigs/{rig['id']}/captures/").status_code == 404
    assert other_api.get(f"/api/captures/{capture_id}/").status_code == 404
    assert other_api.get("/api/rigs/").json() == []
    upload = io.BytesIO(plane_zip())
    upload.name = "x.zip"
    response = other_api.post(
        f"/api/rigs/{rig['id']}/captures/", {"file": upload, "role": "object"}, format="multipart"
    )
    assert response.status_code == 404
    # referencing another user's rig or capture in a body is a 400 naming it
    own_rig = other_api.post("/api/rigs/", SMALL_RIG, format="json").json()
    response = other_api.post(
        "/api/measurements/", {"rig": rig["id"], "reference": capture_id, "object": capture_id}, format="json"
    )
    assert response.status_code == 400 and f"rig {rig['id']} does not exist among yours" in response.json()["error"]
    response = other_api.post(
        "/api/measurements/", {"rig": own_rig["id"], "reference": capture_id, "object": capture_id + 1}, format="json"
    )
    assert response.status_code == 400
    assert f"capture {capture_id} does not exist among yours" in response.json()["error"]


@pytest.mark.django_db
def test_unknown_api_paths_answer_json_404(api):
    response = api.get("/api/measurements/abc/")
    assert response.status_code == 404
    assert response.json() == {"error": "No API endpoint at /api/measurements/abc/; see /api/docs/."}


@pytest.mark.django_db
@pytest.mark.parametrize(("flag", "superuser"), [("--staff", False), ("--superuser", True)])
def test_createuser_makes_staff_who_can_edit_schedules_in_the_admin(flag, superuser):
    from django.contrib.auth import get_user_model
    from django.test import Client

    call_command("createuser", "erin", flag, "--password", "a-long-admin-password-7", stdout=io.StringIO())
    user = get_user_model().objects.get(username="erin")
    assert user.is_staff and user.is_superuser == superuser
    client = Client()
    assert client.login(username="erin", password="a-long-admin-password-7")
    assert client.get("/admin/django_celery_beat/periodictask/").status_code == 200
    assert client.get("/admin/django_celery_beat/periodictask/add/").status_code == 200
    assert client.get("/admin/rigs/rig/").status_code == (200 if superuser else 403)


@pytest.mark.django_db
def test_createuser_staff_without_password_is_refused():
    with pytest.raises(CommandError, match="need --password"):
        call_command("createuser", "frank", "--staff", stdout=io.StringIO())
