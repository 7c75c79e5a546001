"""The demo command (scripts/demo.sh): run twice, it adds nothing the second time and reports its own
results (not a measurement made on its rig since); its hint uses PORT; its output is its summary."""

from __future__ import annotations

import io

import pytest
from django.core.management import call_command

from metrology.calibrations.models import Calibration
from metrology.captures.models import Capture
from metrology.characterizations.models import Characterization
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.services import request_measurement
from metrology.rigs.models import Rig


def run_demo() -> str:
    out = io.StringIO()
    call_command("demo", "--width", "160", "--height", "120", stdout=out)
    return out.getvalue()


def counts() -> tuple[int, ...]:
    return tuple(model.objects.count() for model in (Rig, Capture, Job, Measurement, Calibration, Characterization))


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_demo_twice_adds_no_duplicate_and_prints_the_port(monkeypatch):
    monkeypatch.setenv("PORT", "8123")
    first = run_demo()
    after_first = counts()
    assert after_first[:1] == (1,) and after_first[3:] == (1, 1, 1), after_first
    assert "http://127.0.0.1:8123/api/measurements/" in first and "http://127.0.0.1:8000" not in first
    second = run_demo()
    assert counts() == after_first
    assert "the demo has run before" in second
    assert "http://127.0.0.1:8123/" in second
    measurement = Measurement.objects.get()
    assert f"measurement {measurement.pk}:" in second
    # a measurement made on the demo rig afterwards is not the demo's
    owner, rig = measurement.owner, measurement.rig
    later = request_measurement(
        owner=owner, rig=rig, reference_id=measurement.reference_id, object_id=measurement.object_id
    )
    assert Job.objects.get(pk=later.job_id).status == Job.Status.DONE
    third = run_demo()
    assert f"measurement {measurement.pk}:" in third and f"measurement {later.pk}:" not in third
    assert f"/api/measurements/{measurement.pk}/" in third


@pytest.mark.slow
@pytest.mark.django_db(transaction=True)
def test_the_demo_prints_its_summary_without_the_jobs_log_lines(caplog):
    """The jobs run in-process (inline here, as in every test) log "Task ... succeeded" at INFO
    through Celery's logger, which the console shows under the demo's summary; the demo keeps those
    lines out (the loggers' levels are restored after it)."""
    import logging

    with caplog.at_level(logging.INFO):
        out = run_demo()
    lines = [record.getMessage() for record in caplog.records if record.levelno < logging.WARNING]
    assert not [line for line in lines if "succeeded in" in line], lines[:5]
    assert out.splitlines()[0].startswith("created user 'demo'") and "succeeded in" not in out
    assert logging.getLogger("celery").level == logging.NOTSET
