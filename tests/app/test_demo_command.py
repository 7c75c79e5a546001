"""The demo command (scripts/demo.sh): run twice, it adds nothing the second time; its hint uses PORT."""

from __future__ import annotations

import io

import pytest
from django.core.management import call_command

from metrology.calibrations.models import Calibration
from metrology.captures.models import Capture
from metrology.characterizations.models import Characterization
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
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
