"""The dashboard's acquisition form (the fields of POST /api/rigs/{id}/captures/acquire/)."""

from __future__ import annotations

from django import forms

from metrology.captures.models import Capture


class AcquireForm(forms.Form):
    role = forms.ChoiceField(choices=Capture.Role.choices, initial=Capture.Role.OBJECT)
    z_in_mm = forms.FloatField(required=False, label="Stage position Z_in (mm)", help_text="Stage captures only")
    repeat = forms.IntegerField(required=False, min_value=0, initial=0)
    exposure = forms.FloatField(
        required=False, min_value=0.001, max_value=60_000, label="Exposure (ms)", help_text="Empty: automatic"
    )
    codec = forms.CharField(
        required=False, initial="gcps-v1", help_text="gcps-v1 (1024x768 projector) or gcps-v1:WIDTHxHEIGHT"
    )
