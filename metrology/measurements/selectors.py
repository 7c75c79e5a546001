"""Reads for measurements, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.measurements.models import Measurement


def measurements_for(user) -> QuerySet[Measurement]:
    return Measurement.objects.filter(owner=user).select_related("job", "rig")


def get_measurement(user, measurement_id) -> Measurement:
    measurement = measurements_for(user).filter(pk=measurement_id).first() if str(measurement_id).isdigit() else None
    if measurement is None:
        raise Http404(f"No measurement {measurement_id} among yours.")
    return measurement
