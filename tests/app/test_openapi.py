"""The OpenAPI schema validates, and a bounded schemathesis run against a loopback server finds no 500."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from django.core.management import call_command

from metrology.accounts.services import create_user_with_token


def test_schema_validates_without_warnings(tmp_path):
    out = tmp_path / "schema.yml"
    call_command("spectacular", "--validate", "--fail-on-warn", "--file", str(out))
    text = out.read_text()
    for path in (
        "/api/rigs/",
        "/api/rigs/{rig_id}/captures/",
        "/api/rigs/{rig_id}/captures/simulate/",
        "/api/measurements/",
        "/api/measurements/{measurement_id}/height.npy",
        "/api/measurements/{measurement_id}/mesh.ply",
        "/api/calibrations/",
        "/api/characterizations/",
        "/api/characterizations/{characterization_id}/positions.csv",
    ):
        assert f"  {path}:" in text, path


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_schemathesis_finds_no_server_error(live_server, tmp_path):
    _user, key = create_user_with_token(username="fuzzer")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "schemathesis.cli",
            "run",
            f"{live_server.url}/api/schema/",
            "--header",
            f"Authorization: Token {key}",
            "--checks",
            "not_a_server_error",
            "--max-examples",
            "5",
            "--max-time",
            "60",
            "--seed",
            "4",
            "--request-timeout",
            "30",
            "--workers",
            "1",
            "--report",
            "junit",
            "--report-dir",
            str(tmp_path),
        ],
        cwd=tmp_path,  # schemathesis keeps a cache folder in its working directory
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-6000:]
    summary = re.search(r"(\d+) generated, (\d+) passed", output)
    assert summary and summary.group(1) == summary.group(2) and int(summary.group(1)) > 100, output[-3000:]


@pytest.fixture
def schema(db) -> dict:
    from rest_framework.test import APIClient

    response = APIClient().get("/api/schema/", HTTP_ACCEPT="application/vnd.oai.openapi+json")
    assert response.status_code == 200
    return response.json()


def test_every_operation_documents_its_error_answers(schema):
    assert schema["components"]["schemas"]["Error"]["required"] == ["error"]
    operations = [
        (path, method, operation)
        for path, item in schema["paths"].items()
        if path.startswith("/api/") and not path.startswith(("/api/schema", "/api/docs"))
        for method, operation in item.items()
    ]
    assert len(operations) > 20
    for path, method, operation in operations:
        responses = operation["responses"]
        expected = {"401", "429"} | ({"404"} if "{" in path else set())
        expected |= {"400", "413"} if method == "post" else set()
        assert expected <= set(responses), (path, method, sorted(responses))
        assert "Retry-After" in responses["429"]["headers"]
        assert responses["401"]["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/Error"}


def test_request_examples_are_documented_and_valid(schema):
    from metrology.calibrations.api import CalibrationRequestSerializer
    from metrology.captures.api import SessionSerializer, SimulateSerializer
    from metrology.characterizations.api import CharacterizationRequestSerializer
    from metrology.measurements.api import MeasurementRequestSerializer
    from metrology.rigs.api import RigInputSerializer

    serializers = {
        ("/api/rigs/", "post"): RigInputSerializer,
        ("/api/rigs/{rig_id}/captures/simulate/", "post"): SimulateSerializer,
        ("/api/rigs/{rig_id}/sessions/", "post"): SessionSerializer,
        ("/api/measurements/", "post"): MeasurementRequestSerializer,
        ("/api/calibrations/", "post"): CalibrationRequestSerializer,
        ("/api/characterizations/", "post"): CharacterizationRequestSerializer,
    }
    for (path, method), serializer in serializers.items():
        body = schema["paths"][path][method]["requestBody"]["content"]["application/json"]
        assert body["examples"], path
        for name, example in body["examples"].items():
            checked = serializer(data=example["value"])
            assert checked.is_valid(), (path, name, checked.errors)
    simulate = schema["paths"]["/api/rigs/{rig_id}/captures/simulate/"]["post"]["requestBody"]["content"]
    assert all("name" in example["value"]["scene"] for example in simulate["application/json"]["examples"].values())
    request = schema["components"]["schemas"]["SimulateRequest"]
    assert request["properties"]["scene"]["required"] == ["name"]
    assert request["properties"]["preset"]["default"] == "realistic"
