"""The dashboard's acquisition form (the fields of POST /api/rigs/{id}/captures/acquire/)."""

from __future__ import annotations

import json
from typing import Any

from django import forms

from metrology.acquisition.agent.bracketing import MAX_REQUESTED_EXPOSURES, parse_exposures
from metrology.captures.models import Capture
from metrology.json_input import load_json_text


class AcquireForm(forms.Form):
    role = forms.ChoiceField(choices=Capture.Role.choices, initial=Capture.Role.OBJECT)
    z_in_mm = forms.FloatField(required=False, label="Stage position Z_in (mm)", help_text="Stage captures only")
    repeat = forms.IntegerField(required=False, min_value=0, initial=0)
    exposure = forms.FloatField(
        required=False, min_value=0.001, max_value=60_000, label="Exposure (ms)", help_text="Empty: automatic"
    )
    exposures = forms.CharField(
        required=False,
        max_length=200,
        label="Exposures (multi-exposure)",
        help_text="Empty: one exposure (or the agent's --exposures). auto: the agent brackets; or times, ms: 1,10,100",
    )
    max_exposures = forms.IntegerField(
        required=False,
        min_value=1,
        max_value=MAX_REQUESTED_EXPOSURES,
        label="Most exposures",
        help_text="With auto; empty: the agent's --max-exposures",
    )
    codec = forms.CharField(
        required=False,
        widget=forms.Textarea(attrs={"rows": 2}),
        help_text=(
            "Empty: the rig's default codec. gcps-v1 (1024x768 projector), gcps-v1:WIDTHxHEIGHT, "
            "or a gcps-codec/1 JSON object"
        ),
    )

    def clean_exposures(self) -> Any:
        """``"auto"``, the times (ms, shortest first) or None (:func:`parse_exposures`)."""
        try:
            choice = parse_exposures(self.cleaned_data.get("exposures"))
        except ValueError as exc:
            raise forms.ValidationError(str(exc)) from None
        return list(choice) if isinstance(choice, tuple) else choice

    def clean_codec(self) -> Any:
        """The codec as the API takes it: a name, or the parsed JSON object when the text starts with ``{``."""
        text = (self.cleaned_data.get("codec") or "").strip()
        if not text.startswith("{"):
            return text or None
        try:
            return load_json_text(text)
        except json.JSONDecodeError as exc:
            raise forms.ValidationError(f"codec: not a JSON object ({exc})") from None
        except ValueError as exc:
            raise forms.ValidationError(f"codec refused: {exc}") from None
