"""The self-contained HTML report: plotly.js inlined once, figures, summary, drift, rig, provenance."""

from __future__ import annotations

import json
from typing import Any

from django.template.loader import render_to_string
from django.utils import timezone

from metrology.characterizations.models import Characterization
from metrology.reports.models import Report


def _figures_html(results: dict[str, Any]) -> list[dict[str, str]]:
    """Each plotly figure of the characterization as an HTML fragment (no plotly.js: it is inlined once)."""
    from django.utils.html import format_html

    from metrology.figures import empty_message, is_empty, plot_config
    from metrology.figures.characterization import FIGURE_TITLES, characterization_figures

    fragments = []
    for key, figure in characterization_figures(results).items():
        title = FIGURE_TITLES.get(key, key.replace("_", " "))
        if is_empty(figure):  # nothing to draw or to save: say why
            html = format_html(
                '<p class="empty" id="figure-{}"><strong>{}</strong>: {}</p>', key, title, empty_message(figure)
            )
        else:
            config = plot_config(f"characterization-{key}", "svg")
            html = figure.to_html(full_html=False, include_plotlyjs=False, config=config, div_id=f"figure-{key}")
        fragments.append({"key": key, "title": title, "html": html})
    return fragments


# Summary rows (by the start of their label) -> the drift item that concerns them.
SUMMARY_DRIFT_KEYS: tuple[tuple[str, str], ...] = (
    ("Mean error (all", "overall.mean_error_mm"),
    ("Variability (standard", "overall.std_error_mm"),
    ("RMS error sqrt", "overall.rms_error_mm"),
    ("RMS error, %", "overall.error_pct_fs"),
    ("Largest |mean error|", "overall.max_abs_mean_error_mm"),
    ("Largest |slope - 1|", "overall.max_abs_slope_deviation"),
)


def uncertainty_text(key: str | None, u: float | None) -> str:
    """A standard uncertainty in the unit its figure is shown in: µm, % (of full scale) or plain (slopes)."""
    if key is None or u is None:
        return ""
    if "_mm" in key:  # overall.<figure>_mm and positions.mean_error_mm@<Z_in>
        return f"± {1000 * u:.1f} µm"
    if key.endswith("pct_fs"):
        return f"± {u:.3f} %"
    return f"± {u:.1g}"


def _summary_rows(
    results: dict[str, Any], beyond_keys: set[str], uncertainties: dict[str, float | None]
) -> list[dict[str, Any]]:
    """The dashboard's summary table rows with their standard uncertainty, ``beyond`` when the figure drifted."""
    from metrology.figures.characterization import summary_rows

    rows = []
    for label, value in summary_rows(results):
        key = next((key for prefix, key in SUMMARY_DRIFT_KEYS if label.startswith(prefix)), None)
        u = uncertainties.get(key) if key else None
        rows.append(
            {"label": label, "value": value, "key": key, "beyond": key in beyond_keys, "u": uncertainty_text(key, u)}
        )
    return rows


def _scaled(value: float | None, factor: float) -> float | None:
    return None if value is None else factor * value


def render_report_html(
    report: Report, characterization: Characterization, summary: dict[str, Any], drift: dict[str, Any]
) -> str:
    """The self-contained HTML report: plotly.js inlined, figures, summary, rig, drift, provenance."""
    from plotly.offline import get_plotlyjs

    from metrology.reports.summary import standard_uncertainties

    beyond_keys = {item["key"] for item in drift.get("items", []) if item["beyond"]}
    uncertainties = summary.get("uncertainty") or standard_uncertainties(summary)
    positions = summary.get("positions", {})
    position_rows = []
    for z_in, mean, std, n in zip(
        positions.get("z_in_mm", []),
        positions.get("mean_error_mm", []),
        positions.get("std_error_mm", []),
        positions.get("n_samples", []),
        strict=False,
    ):
        position_rows.append(
            {
                "z_in_mm": z_in,
                "mean_um": None if mean is None else 1000 * mean,
                "std_um": None if std is None else 1000 * std,
                "u_um": _scaled(uncertainties.get(f"positions.mean_error_mm@{z_in:g}"), 1000.0),
                "n": n,
                "beyond": f"positions.mean_error_mm@{z_in:g}" in beyond_keys,
            }
        )
    changed = {change["name"] for change in drift.get("rig_changes", [])}
    rig_rows = [
        {"name": name, "value": _rig_value(value), "changed": name in changed}
        for name, value in summary["rig"].items()
        if name not in ("id", "name", "model")
    ]
    context = {
        "report": report,
        "characterization": characterization,
        "summary": summary,
        "drift": drift,
        "summary_rows": _summary_rows(characterization.results or {}, beyond_keys, uncertainties),
        "drift_rows": [
            {**item, "u": uncertainty_text(item["key"], item.get("uncertainty"))} for item in drift.get("items", [])
        ],
        "position_rows": position_rows,
        "rig_rows": rig_rows,
        "figures": _figures_html(characterization.results or {}),
        "plotly_js": get_plotlyjs(),
        "parameters_json": json.dumps(report.parameters, indent=2, sort_keys=True),
        "generated_at": timezone.now(),
    }
    return render_to_string("reports/report.html", context)


def _rig_value(value: Any) -> str:
    """A rig file's value for the report's table: numbers with six significant digits (matrices
    and nested values likewise, a nested object as ``key value`` pairs)."""
    from metrology.core.geometry.base import short_number

    if isinstance(value, dict):
        return ", ".join(f"{key} {_rig_value(item)}" for key, item in value.items())
    return short_number(value)
