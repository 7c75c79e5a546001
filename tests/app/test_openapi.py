"""The OpenAPI schema validates, and a bounded schemathesis run against a loopback server finds no 500."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from django.core.management import call_command

from metrology.accounts.services import create_user_with_token
from tests.shared_run import run_folder, run_lock

UNICODE_TABLES = (
    "from hypothesis.internal.charmap import charmap, intervals_from_codec; charmap(); intervals_from_codec('utf-8')"
)
"""What a schemathesis run computes before its first string: Hypothesis's tables of the Unicode
categories and of the characters UTF-8 encodes (1.1 million code points each, 1.3 s of CPU),
which Hypothesis keeps in ``.hypothesis/unicode_data`` of the working directory."""


@pytest.fixture
def schemathesis_dir(request, tmp_path) -> Path:
    """The working directory of one schemathesis run: empty (its Hypothesis examples database starts
    empty, as before), except for the Unicode tables of :data:`UNICODE_TABLES`, computed once per
    test run in the run's shared folder (under a lock: the API parts run on several workers) and
    copied here, instead of once per schemathesis run. The tables depend only on Hypothesis's
    version and Python's Unicode data; should Hypothesis's functions move, nothing is copied and
    schemathesis computes them as before."""
    shared = run_folder(request.config) / "hypothesis-home"
    with run_lock(run_folder(request.config), "hypothesis-home"):
        if not (shared / "unicode_data").is_dir():
            env = {**os.environ, "HYPOTHESIS_STORAGE_DIRECTORY": str(shared)}
            subprocess.run([sys.executable, "-c", UNICODE_TABLES], env=env, capture_output=True, check=False)
    if (shared / "unicode_data").is_dir():
        shutil.copytree(shared / "unicode_data", tmp_path / ".hypothesis" / "unicode_data")
    return tmp_path


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
def test_schemathesis_finds_no_server_error(live_server, schemathesis_dir, monkeypatch, settings):
    """An 8 s budget of five examples per operation: a quick first pass over the API (the whole-API
    test below covers every operation with its stored objects). The budget was 10 s while it held
    the computation of Hypothesis's Unicode tables (1.3 s of CPU, several seconds of a loaded run),
    now made before it (:func:`schemathesis_dir`)."""
    monkeypatch.setattr("metrology.acquisition.longpoll.MAX_WAIT_S", 0.5)  # as in the whole-API test
    settings.GCPS_MAX_SIMULATION_BYTES = 32 * 1024 * 1024
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
            "8",
            "--seed",
            "4",
            "--request-timeout",
            "30",
            "--workers",
            "1",
            "--report",
            "junit",
            "--report-dir",
            str(schemathesis_dir),
        ],
        cwd=schemathesis_dir,  # Hypothesis keeps its examples and tables in its working directory
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-6000:]
    summary = re.search(r"(\d+) generated, (\d+) passed", output)
    # not a vacuous run: 476 cases in its 10 s at load 0.8, at load 7-14 only 6-98 (schemathesis
    # spends its budget whatever the load), so the floor is low; 365-485 in 10 s at load 8-10 with
    # the tables computed in the budget, 295-583 in 7-10 s without
    assert summary and summary.group(1) == summary.group(2) and int(summary.group(1)) >= 5, output[-3000:]
    print(f"schemathesis in 8 s: {summary.group(0)}")


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
    # an acquisition's exposures (docs/acquisition.md): "auto" or up to 8 times in ms
    acquire = schema["components"]["schemas"]["AcquireRequest"]["properties"]
    assert [choice.get("enum") for choice in acquire["exposures"]["oneOf"]] == [["auto"], None]
    assert acquire["exposures"]["oneOf"][1]["maxItems"] == 8 and acquire["max_exposures"]["maximum"] == 8


def schema_operations(schema: dict) -> set[str]:
    """``METHOD /path`` of every API operation in the schema (the schema and docs views excluded)."""
    return {
        f"{method.upper()} {path}"
        for path, item in schema["paths"].items()
        if path.startswith("/api/") and not path.startswith(("/api/schema", "/api/docs"))
        for method in item
    }


API_PARTS = {
    "rigs": r"^/api/rigs/",
    "measurements": r"^/api/measurements/",
    "other": r"^/api/(?!rigs/|measurements/|schema|docs)",
}
"""The whole API in three parts, each one schemathesis run (one xdist worker each): every operation
falls in exactly one part (:func:`test_the_api_parts_cover_every_operation_once`)."""


def test_the_api_parts_cover_every_operation_once(schema):
    for operation in schema_operations(schema):
        path = operation.split(" ", 1)[1]
        assert sum(bool(re.match(pattern, path)) for pattern in API_PARTS.values()) == 1, operation


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
@pytest.mark.parametrize("part", sorted(API_PARTS))
def test_schemathesis_over_the_whole_api_authenticated_finds_no_server_error(
    live_server, schemathesis_dir, settings, schema, part, monkeypatch
):
    """Every operation, authenticated, with stored objects to find (ids 1, 2, ...): examples, coverage
    and fuzzing phases; rates raised (tests/conftest.py) and simulations kept small. The API is
    covered in the three parts of :data:`API_PARTS` so that parallel workers share it (188 s as
    one run in the parallel suite); each part checks that it tested every operation of its part.

    Six examples per operation in the fuzzing phase (25, then 10 before; the serial suite's 19.5 min
    held 202 s of it at 25), besides the examples and coverage phases. The assertions are unchanged."""
    import xml.etree.ElementTree as ET

    from tests.app.stacks import SMALL_RIG, plane_zip

    settings.GCPS_MAX_SIMULATION_BYTES = 32 * 1024 * 1024  # renders the fuzzer asks for stay small
    # the projector's long-poll answers within 0.5 s instead of 25 (the fuzzer's waits are not what is tested)
    monkeypatch.setattr("metrology.acquisition.longpoll.MAX_WAIT_S", 0.5)
    user, key = create_user_with_token(username="fuzzer")
    from django.core.files.uploadedfile import SimpleUploadedFile

    from metrology.captures.services import upload_capture
    from metrology.measurements.services import request_measurement
    from metrology.rigs.services import create_rig

    rig = create_rig(owner=user, data={**SMALL_RIG, "name": "fuzzed"})
    reference = upload_capture(
        owner=user, rig=rig, upload=SimpleUploadedFile("r.zip", plane_zip(), "application/zip"), role="reference"
    )
    obj = upload_capture(
        owner=user, rig=rig, upload=SimpleUploadedFile("o.zip", plane_zip(z_mm=10.0), "application/zip"), role="object"
    )
    request_measurement(owner=user, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    junit = schemathesis_dir / "junit.xml"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "schemathesis.cli",
            "run",
            f"{live_server.url}/api/schema/",
            "--header",
            f"Authorization: Token {key}",
            "--include-path-regex",
            API_PARTS[part],
            "--checks",
            "not_a_server_error",
            "--phases",
            "examples,coverage,fuzzing",
            "--max-examples",
            "6",
            "--seed",
            "9",
            "--request-timeout",
            "60",
            "--workers",
            "1",
            "--continue-on-failure",
            "--report",
            "junit",
            "--report-junit-path",
            str(junit),
        ],
        cwd=schemathesis_dir,
        capture_output=True,
        text=True,
        timeout=1500,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-8000:]
    summary = re.search(r"(\d+) generated, (\d+) passed", output)
    operations = {op for op in schema_operations(schema) if re.match(API_PARTS[part], op.split(" ", 1)[1])}
    # about 48 cases per operation over the whole API at ten examples (2680 for 55); at least 20 here
    print(f"schemathesis, {part}: {summary.group(0) if summary else output[-500:]} over {len(operations)} operations")
    assert summary and summary.group(1) == summary.group(2), output[-3000:]
    assert int(summary.group(1)) >= 20 * len(operations), output[-3000:]
    assert re.search(r"Tested: (\d+)", output).group(1) == str(len(operations)), output[-3000:]
    tested = {case.get("name", "") for case in ET.parse(junit).getroot().iter("testcase")}
    missing = sorted(op for op in operations if op not in tested)
    assert not missing, (missing, sorted(tested))
