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
