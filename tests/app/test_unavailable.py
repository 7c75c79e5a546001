"""A broker or database that is away answers 503 with Retry-After, and leaves nothing half-made."""

from __future__ import annotations

import socket

import pytest

from metrology.captures.models import Capture
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from tests.app.test_measurement_job import captures as uploaded_captures


@pytest.fixture
def broker_down(settings):
    """The Celery app pointed at a loopback port where nothing listens (a real, refused connection)."""
    from workers import app

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    saved = app.conf.broker_url
    settings.CELERY_TASK_ALWAYS_EAGER = False
    app.conf.broker_url = f"redis://127.0.0.1:{port}/0"
    yield
    app.conf.broker_url = saved


def test_a_simulation_request_answers_503_when_the_broker_is_down_and_creates_nothing(api, rig, broker_down):
    before = (Capture.objects.count(), Job.objects.count())
    response = api.post(
        f"/api/rigs/{rig['id']}/captures/simulate/",
        {"role": "reference", "scene": {"name": "reference"}},
        format="json",
    )
    assert response.status_code == 503, response.content
    assert int(response["Retry-After"]) > 0
    assert "queue" in response.json()["error"] and "unreachable" in response.json()["error"]
    assert (Capture.objects.count(), Job.objects.count()) == before


captures = uploaded_captures  # the fixture, under its own name


def test_a_measurement_request_answers_503_when_the_broker_is_down(api, rig, captures, broker_down):
    reference, obj = captures
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    assert response.status_code == 503, response.content
    assert response.json()["error"].startswith("The job queue (broker) is unreachable")
    assert Measurement.objects.count() == 0 and Job.objects.count() == 0


def test_outside_the_api_the_503_is_a_page():
    from django.http import HttpRequest

    from metrology.unavailable import ServiceUnavailableError, TransientErrorMiddleware

    request = HttpRequest()
    request.path = "/rigs/1/"
    response = TransientErrorMiddleware(lambda r: None).process_exception(  # type: ignore[arg-type]
        request, ServiceUnavailableError("The job queue (broker) is unreachable.", retry_after_s=30)
    )
    assert response is not None and response.status_code == 503 and response["Retry-After"] == "30"
    assert b"broker" in response.content and response["Content-Type"].startswith("text/html")
