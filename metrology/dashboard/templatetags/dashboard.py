"""Template tags of the dashboard: plotly figures, job progress bars, number formatting."""

from __future__ import annotations

import math

from django import template
from django.utils.html import format_html
from django.utils.safestring import mark_safe

from metrology.dashboard.selectors import capture_origin
from metrology.figures import empty_message, figure_json, is_empty, plot_config

register = template.Library()

_ESCAPES = {ord(">"): "\\u003E", ord("<"): "\\u003C", ord("&"): "\\u0026"}


@register.simple_tag
def plotly_figure(fig, name: str, label: str = ""):
    """A figure drawn by ``Plotly.newPlot`` with PNG and SVG download buttons (an empty one: its message only).

    The figure's JSON sits in a ``<script type="application/json">`` (escaped like
    ``json_script``); the dashboard's script draws every ``.js-figure`` on load.
    """
    import json

    title = label or name.replace("_", " ")
    if is_empty(fig):  # nothing to draw or download: say why
        return format_html(
            '<figure class="figure" aria-label="{title}"><div class="empty figure-empty" id="fig-{name}">'
            "<strong>{title}</strong>: {message}</div></figure>",
            title=title,
            name=name,
            message=empty_message(fig) or "nothing to show.",
        )
    data = figure_json(fig).translate(_ESCAPES)
    config = json.dumps(plot_config(name)).translate(_ESCAPES)
    return format_html(
        '<figure class="figure" aria-label="{title}">'
        '<div class="js-figure" id="fig-{name}" data-name="{name}"></div>'
        '<script type="application/json" id="fig-{name}-data">{data}</script>'
        '<script type="application/json" id="fig-{name}-config">{config}</script>'
        '<figcaption class="figure-tools">Download this figure: '
        '<button type="button" class="button small js-download" data-target="fig-{name}" data-format="png">'
        "PNG</button> "
        '<button type="button" class="button small js-download" data-target="fig-{name}" data-format="svg">'
        "SVG</button></figcaption></figure>",
        title=title,
        name=name,
        data=mark_safe(data),
        config=mark_safe(config),
    )


@register.inclusion_tag("dashboard/_progress.html")
def job_progress(job, next_url: str = ""):
    """A progress bar for ``job`` that polls ``/api/jobs/<id>/`` and goes to ``next_url`` when done."""
    return {"job": job, "next_url": next_url}


@register.filter
def origin(capture) -> str:
    """Where a capture came from: uploaded file name, virtual scene name, or source (uploads have no scene)."""
    return capture_origin(capture)


@register.filter
def um(value_mm, digits: int = 1):
    """Millimetres shown as micrometres, µm (``"n/a"`` for None/NaN)."""
    try:
        number = float(value_mm)
    except (TypeError, ValueError):
        return "n/a"
    return "n/a" if not math.isfinite(number) else f"{number * 1000:.{int(digits)}f} µm"


@register.filter
def sig(value, digits: int = 2) -> str:
    """A number with ``digits`` significant digits, positional up to 6 decimals (``"n/a"`` for None/NaN).

    For uncertainties: 0.0213 -> "0.021", 12.34 -> "12", 3.1e-9 -> "3.1e-09".
    """
    try:
        number = float(value)
    except (TypeError, ValueError):
        return "n/a"
    if not math.isfinite(number):
        return "n/a"
    if number == 0:
        return "0"
    decimals = int(digits) - 1 - math.floor(math.log10(abs(number)))
    if decimals > 6:
        return f"{number:.{int(digits) - 1}e}"
    return f"{number:.{max(decimals, 0)}f}"


@register.filter
def num(value, digits: int = 3):
    """A number with ``digits`` decimals (``"n/a"`` for None/NaN)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return "n/a" if value in (None, "") else value
    return "n/a" if not math.isfinite(number) else f"{number:.{int(digits)}f}"


@register.filter
def short(value, digits: int = 6):
    """A number with at most ``digits`` significant digits, no trailing zeros: 0.30000000000000004 -> "0.3"."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return "" if value is None else value
    return "n/a" if not math.isfinite(number) else f"{number:.{int(digits)}g}"


@register.filter
def shortlist(value, digits: int = 6):
    """Numbers, or nested lists of them (a matrix), each with at most ``digits`` significant digits:
    ``[[1000.0000000002, 0, 403.2], ...]`` -> ``"[[1000, 0, 403.2], ...]"``."""
    if isinstance(value, list | tuple):
        return "[" + ", ".join(str(shortlist(item, digits)) for item in value) + "]"
    return short(value, digits)


@register.filter
def pct(value, digits: int = 1):
    """A fraction in [0, 1] as a percentage."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return "n/a" if not math.isfinite(number) else f"{100 * number:.{int(digits)}f} %"


@register.filter
def pct_of(count, capture) -> str:
    """``count`` pixels of ``capture``'s frames in the one format of valid pixels: the percentage
    (:func:`pct`) first, then the count, e.g. ``70.2 % (217,353 of 309,760 px)``."""
    try:
        total = int(capture.width_px) * int(capture.height_px)
        number = int(count)
    except (TypeError, ValueError, AttributeError):
        return "n/a"
    if total <= 0:
        return f"{number:,} px"
    return f"{pct(number / total)} ({number:,} of {total:,} px)"


@register.filter
def pinhole_summary(values) -> str:
    """A pinhole rig file in a line: camera and projector fx, baseline |T| (for the rig's history)."""
    try:
        camera_fx = float(values["camera"]["K"][0][0])
        projector_fx = float(values["projector"]["K"][0][0])
        baseline = math.sqrt(sum(float(t) ** 2 for t in values["T"]))
    except (KeyError, IndexError, TypeError, ValueError):
        return "pinhole rig file"
    return f"pinhole: camera fx {camera_fx:.2f} px, projector fx {projector_fx:.2f}, baseline {baseline:.2f} mm"
