"""Number formatting for the report pages: ``{{ value|num }}``, ``{{ value|num:"+.2f" }}``, em dash for missing."""

from __future__ import annotations

import math

from django import template

register = template.Library()


@register.filter
def num(value, spec: str = ".4g") -> str:
    """``value`` formatted with ``spec``; an em dash for None/NaN and non-numbers shown as they are."""
    if value is None or isinstance(value, bool):
        return "—" if value is None else str(value)
    if not isinstance(value, int | float):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return "—"
    return format(value, spec)


@register.filter
def um(value_mm, spec: str = ".1f") -> str:
    """A length in mm shown in micrometres."""
    if not isinstance(value_mm, int | float) or isinstance(value_mm, bool) or not math.isfinite(value_mm):
        return "—"
    return format(1000.0 * value_mm, spec)
