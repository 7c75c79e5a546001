"""A broker or database that is away answers 503 with Retry-After, and leaves nothing half-made."""

from __future__ import annotations

import json
import socket

import pytest

from metrology.captures.models import Capture
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement


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


class FlakyView:
    """A view whose first ``failures`` calls raise what a lost database connection raises."""

    def __init__(self, failures: int, write_first: bool = False) -> None:
        self.failures = failures
        self.write_first = write_first
        self.calls = 0

    def __call__(self, request):
        from django.db import OperationalError
        from django.http import JsonResponse

        self.calls += 1
        if self.write_first:
            Job.objects.filter(pk=-1).update(progress=0)  # an UPDATE statement that succeeded
        if self.calls <= self.failures:
            raise OperationalError("server closed the connection unexpectedly")
        return JsonResponse({"calls": self.calls})


def run_through_middleware(view, request):
    """The middleware around ``view`` as Django's handler runs it: exceptions go to process_exception."""
    from metrology.unavailable import TransientErrorMiddleware

    def get_response(request):
        try:
            return view(request)
        except Exception as exc:
            response = middleware.process_exception(request, exc)
            if response is None:
                raise
            return response

    middleware = TransientErrorMiddleware(get_response)
    return middleware(request)


@pytest.mark.django_db
def test_a_request_that_meets_a_lost_connection_is_retried_once_with_its_body(rf):
    view = FlakyView(failures=1)
    request = rf.post("/api/rigs/", data=b'{"name": "x"}', content_type="application/json")
    response = run_through_middleware(view, request)
    assert response.status_code == 200 and view.calls == 2
    assert request.body == b'{"name": "x"}'  # kept for the retry


@pytest.mark.django_db
def test_a_second_failure_answers_503_json_with_retry_after(rf):
    view = FlakyView(failures=2)
    response = run_through_middleware(view, rf.get("/api/jobs/"))
    assert response.status_code == 503 and view.calls == 2
    assert int(response["Retry-After"]) > 0 and "database is unreachable" in json.loads(response.content)["error"]


@pytest.mark.django_db
def test_a_request_that_wrote_before_failing_is_not_retried(rf):
    view = FlakyView(failures=1, write_first=True)
    response = run_through_middleware(view, rf.post("/api/rigs/", data=b"{}", content_type="application/json"))
    assert response.status_code == 503 and view.calls == 1
