"""409 in the OpenAPI schema (issue 23 item 6): every operation that answers 409 documents it, with
the error body, and no other operation claims it (``metrology.api_schema.CONFLICT_OPERATIONS``)."""

from __future__ import annotations

import io
import uuid

import pytest
from rest_framework.test import APIClient

from metrology.api_schema import CONFLICT_OPERATIONS

ERROR_REF = {"$ref": "#/components/schemas/Error"}


@pytest.fixture
def schema(db) -> dict:
    response = APIClient().get("/api/schema/", HTTP_ACCEPT="application/vnd.oai.openapi+json")
    assert response.status_code == 200
    return response.json()


def _operations(schema: dict) -> dict[tuple[str, str], dict]:
    return {
        (method, path): operation
        for path, item in schema["paths"].items()
        if path.startswith("/api/")
        for method, operation in item.items()
        if isinstance(operation, dict) and "responses" in operation
    }


def test_the_operations_that_answer_409_document_it_and_no_other(schema):
    operations = _operations(schema)
    ids = {operation["operationId"]: operation for operation in operations.values()}
    assert set(CONFLICT_OPERATIONS) <= set(ids), sorted(set(CONFLICT_OPERATIONS) - set(ids))
    for operation_id, operation in ids.items():
        documented = operation["responses"].get("409")
        if operation_id in CONFLICT_OPERATIONS:
            assert documented is not None, operation_id
            assert documented["content"]["application/json"]["schema"] == ERROR_REF, operation_id
            assert documented["description"], operation_id
        else:
            assert documented is None, operation_id


def test_every_409_the_acquisition_protocol_answers_is_documented(api, rig, schema):
    """Drive each operation into its 409 (an unknown agent session, a second agent) and look the
    answer up in the schema."""
    operations = _operations(schema)
    rig_id = rig["id"]
    acquisition = api.post(f"/api/rigs/{rig_id}/captures/acquire/", {"role": "reference"}, format="json").json()
    unknown = {"session": str(uuid.uuid4())}
    upload = io.BytesIO(b"PK\x05\x06" + b"\x00" * 18)
    upload.name = "stack.zip"
    calls = [
        ("post", "/api/rigs/{rig_id}/agent/heartbeat/", unknown, "json"),
        ("post", "/api/rigs/{rig_id}/agent/disconnect/", unknown, "json"),
        ("post", "/api/rigs/{rig_id}/agent/take/", unknown, "json"),
        ("post", "/api/rigs/{rig_id}/projector/", {**unknown, "kind": "white"}, "json"),
        ("post", "/api/acquisitions/{acquisition_id}/progress/", unknown, "json"),
        ("post", "/api/acquisitions/{acquisition_id}/fail/", {**unknown, "reason": "x"}, "json"),
        ("post", "/api/acquisitions/{acquisition_id}/upload/", {**unknown, "file": upload}, "multipart"),
    ]
    first = api.post(f"/api/rigs/{rig_id}/agent/register/", {"camera": "virtual"}, format="json")
    assert first.status_code == 201, first.content
    calls.append(("post", "/api/rigs/{rig_id}/agent/register/", {"camera": "virtual"}, "json"))
    answered = set()
    for method, template, body, fmt in calls:
        url = template.format(rig_id=rig_id, acquisition_id=acquisition["id"])
        response = getattr(api, method)(url, body, format=fmt)
        assert response.status_code == 409, (template, response.content)
        assert response.json()["error"]
        operation = operations[(method, template)]
        assert "409" in operation["responses"], (template, operation["operationId"])
        answered.add(operation["operationId"])
    assert answered == set(CONFLICT_OPERATIONS) - {"measurements_acceptance"}
