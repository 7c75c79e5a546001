"""The production topology (issue 23 item 2): docker-compose.yml, the systemd units and the
supervisord configuration hold the same processes, each restarted when it exits and (compose)
health-checked. ``docker compose config`` validates the compose file where Docker Compose is
installed; the YAML checks below run everywhere."""

from __future__ import annotations

import configparser
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
SYSTEMD = ROOT / "deploy" / "systemd"
SUPERVISORD = ROOT / "deploy" / "supervisord.conf"
ASGI_SERVER = "gunicorn metrology.asgi:application -k uvicorn_worker.UvicornWorker"


def compose() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def _command(service: dict) -> str:
    command = service.get("command", "")
    return " ".join(command.split()) if isinstance(command, str) else " ".join(command)


def test_every_compose_service_restarts_and_has_a_health_check():
    services = compose()["services"]
    assert set(services) >= {"nginx", "web", "worker", "beat", "postgres", "redis", "minio", "minio-init", "migrate"}
    for name, service in services.items():
        assert service.get("restart") in ("unless-stopped", "always", "on-failure"), name
        check = service.get("healthcheck")
        assert check and check.get("test") and not check.get("disable"), f"{name} has no health check"


def test_compose_runs_the_documented_processes():
    services = compose()["services"]
    assert ASGI_SERVER in _command(services["web"]) and "--workers 3" in _command(services["web"])
    assert "celery -A workers worker" in _command(services["worker"])
    assert "DatabaseScheduler" in _command(services["beat"])
    assert "--appendonly yes" in _command(services["redis"])
    assert "./deploy/nginx/gcps.conf:/etc/gcps/nginx.conf:ro" in services["nginx"]["volumes"]
    assert "static:/var/lib/gcps/static:ro" in services["nginx"]["volumes"]
    assert "ports" not in services["web"], "only the proxy is published"
    env = services["worker"]["environment"]
    for key in ("GCPS_S3_BUCKET", "GCPS_S3_ENDPOINT_URL", "GCPS_S3_ACCESS_KEY_ID", "GCPS_S3_SECRET_ACCESS_KEY"):
        assert key in env, key
    assert "GCPS_S3_REGION" in env
    # workers share no volume with the web server: results go through the object storage
    assert "volumes" not in services["worker"]
    for name in ("web", "worker", "beat"):
        assert services[name]["depends_on"]["minio-init"]["condition"] == "service_completed_successfully"
        assert services[name]["depends_on"]["migrate"]["condition"] == "service_completed_successfully"


@pytest.mark.skipif(shutil.which("docker") is None, reason="docker is not installed")
def test_docker_compose_config_accepts_the_file(tmp_path):
    probe = subprocess.run(["docker", "compose", "version"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"Docker Compose is not installed: {probe.stderr.strip()[:200]}")
    env = {**os.environ, "SECRET_KEY": "x" * 50, "GCPS_S3_SECRET_ACCESS_KEY": "y" * 20}
    result = subprocess.run(
        ["docker", "compose", "-f", str(COMPOSE), "config", "--quiet"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr


def _unit(path: Path) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(path.read_text())
    return parser


def test_systemd_units_restart_always_and_hold_the_topology():
    units = {path.name: _unit(path) for path in SYSTEMD.glob("*.service")}
    assert set(units) >= {"gcps-web.service", "gcps-worker@.service", "gcps-beat.service", "gcps-migrate.service"}
    assert (SYSTEMD / "gcps.target").exists()
    for name, unit in units.items():
        if unit["Service"].get("Type") == "oneshot":
            continue
        assert unit["Service"]["Restart"] == "always", name
        assert unit["Service"]["EnvironmentFile"] == "/etc/gcps/gcps.env", name
    assert ASGI_SERVER in units["gcps-web.service"]["Service"]["ExecStart"]
    assert "celery -A workers worker" in units["gcps-worker@.service"]["Service"]["ExecStart"]
    assert "%i" in units["gcps-worker@.service"]["Service"]["ExecStart"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_systemd_analyze_verifies_the_units(tmp_path):
    """The units as installed at the checkout's path (so that their commands exist here)."""
    for path in [*SYSTEMD.glob("*.service"), *SYSTEMD.glob("*.target")]:
        (tmp_path / path.name).write_text(path.read_text().replace("/opt/gcps", str(ROOT)))
    units = sorted(str(path) for path in tmp_path.iterdir())
    result = subprocess.run(["systemd-analyze", "verify", "--man=no", *units], capture_output=True, text=True)
    assert result.returncode == 0 and not result.stderr.strip(), result.stdout + result.stderr


def test_supervisord_restarts_every_program():
    parser = configparser.ConfigParser(interpolation=None)
    parser.read_string(SUPERVISORD.read_text())
    sections = [section for section in parser.sections() if section.startswith("program:")]
    programs = {section.split(":", 1)[1]: parser[section] for section in sections}
    assert set(programs) == {"web", "worker", "beat"}
    for name, program in programs.items():
        assert program["autorestart"] == "true", name
        assert program.get("killasgroup") == "true", name
    assert ASGI_SERVER in " ".join(programs["web"]["command"].split())
    assert programs["worker"]["numprocs"] == "%(ENV_GCPS_WORKERS)s"


def test_compose_nginx_puts_the_containers_addresses_into_the_documented_config():
    """The nginx container runs its command's sed over deploy/nginx/gcps.conf: the result proxies to
    web:8000 and minio:9000 and is otherwise the file as written."""
    command = _command(compose()["services"]["nginx"])
    expressions = re.findall(r"-e '([^']+)'", command)
    assert len(expressions) == 2, command
    original = (ROOT / "deploy" / "nginx" / "gcps.conf").read_text()
    rendered = subprocess.run(
        ["sed", *(arg for e in expressions for arg in ("-e", e))],
        input=original,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert rendered.count("server web:8000;") == 1 and "server 127.0.0.1:8000;" not in rendered
    assert rendered.count("proxy_pass http://minio:9000/;") == 1 and "http://127.0.0.1:9000/;" not in rendered
    assert len(rendered.splitlines()) == len(original.splitlines())
    env = compose()["services"]["web"]["environment"]
    assert env["GCPS_ACCEL_REDIRECT"] == "1", "downloads go through nginx: MinIO is not published"
    assert "ports" not in compose()["services"]["minio"]
