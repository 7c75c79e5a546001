"""Signals of the measurements app.

``measurement_done`` is sent (``sender=Measurement``, ``measurement=...``) by the measurement job
once its result is published, so that other apps act on new results (the inspection plan of the
rig, :mod:`metrology.inspections`) without this app importing them.
"""

from __future__ import annotations

from django.dispatch import Signal

measurement_done = Signal()
