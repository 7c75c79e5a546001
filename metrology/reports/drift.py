"""Drift of a report against the rig's previous one: which figures moved, by how much, beyond tolerance.

A figure is flagged (``beyond``) only when its change exceeds both its tolerance
(``GCPS_REPORT_DRIFT_TOLERANCE`` or the report's ``tolerances``) and :data:`COVERAGE_FACTOR`
times the standard uncertainty of the change, ``u = sqrt(u_previous^2 + u_now^2)`` from each
report's own scatter and sample counts (:func:`metrology.reports.summary.standard_uncertainties`).
Two reports of an unchanged rig differ by noise alone; their difference has that ``u``. Where
one side's uncertainty is unknown (a report made before it was recorded), the other side's is
taken for both; where neither is known, the tolerance alone decides.
"""

from __future__ import annotations

import math
from typing import Any

from django.conf import settings

from metrology.reports.models import Report
from metrology.reports.summary import standard_uncertainties

COVERAGE_FACTOR = 3.0
"""A change must exceed this many standard uncertainties of the change (and the tolerance) to count as drift."""

# Overall figures compared between reports: (key in results["overall"], label, tolerance kind).
DRIFT_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("mean_error_mm", "Overall mean error", "mm"),
    ("std_error_mm", "Overall standard deviation of the error", "mm"),
    ("rms_error_mm", "Overall RMS error", "mm"),
    ("error_pct_fs", "RMS error, % of full scale", "pct_fs"),
    ("max_abs_mean_error_mm", "Largest |mean error| over the positions", "mm"),
    ("max_abs_slope_deviation", "Largest |slope - 1| over the test points", "slope"),
)


def _change_uncertainty(u_old: float | None, u_new: float | None) -> float | None:
    """Standard uncertainty of ``new - old`` (independent reports); one side stands for both if the other is unknown."""
    if u_old is None:
        return None if u_new is None else math.sqrt(2.0) * u_new
    if u_new is None:
        return math.sqrt(2.0) * u_old
    return math.hypot(u_old, u_new)


def _item(
    key: str,
    label: str,
    kind: str,
    unit: str,
    old: Any,
    new: Any,
    tolerance: float,
    uncertainty: float | None,
    coverage_factor: float,
) -> dict[str, Any]:
    comparable = isinstance(old, int | float) and isinstance(new, int | float)
    change = float(new - old) if comparable else None
    beyond = change is not None and abs(change) > tolerance
    if change is not None and uncertainty is not None:
        beyond = beyond and abs(change) > coverage_factor * uncertainty
    return {
        "key": key,
        "label": label,
        "kind": kind,
        "unit": unit,
        "previous": old,
        "current": new,
        "change": change,
        "tolerance": tolerance,
        "uncertainty": uncertainty,
        "beyond": bool(beyond),
    }


UNITS = {"mm": "mm", "pct_fs": "% FS", "slope": ""}


def compute_drift(
    previous: Report | None,
    summary: dict[str, Any],
    tolerances: dict[str, float],
    coverage_factor: float = COVERAGE_FACTOR,
) -> dict[str, Any]:
    """Changes of the report's figures since ``previous``; ``beyond`` marks moves beyond tolerance and noise.

    Compared: the overall figures of :data:`DRIFT_FIGURES` and the mean error at every stage
    position Z_in found in both reports; the rig parameters that changed are listed too. Each
    item carries ``change``, ``tolerance`` and ``uncertainty`` (one sigma of the change, same
    unit as the figure, None when unknown); ``beyond`` when ``|change| > tolerance`` and
    ``|change| > coverage_factor * uncertainty``.
    """
    tolerances = {**settings.GCPS_REPORT_DRIFT_TOLERANCE, **(tolerances or {})}
    if previous is None:
        return {
            "previous": None,
            "tolerances": tolerances,
            "coverage_factor": coverage_factor,
            "items": [],
            "rig_changes": [],
            "beyond": 0,
        }
    before = previous.summary or {}
    u_before = before.get("uncertainty") or standard_uncertainties(before)
    u_now = summary.get("uncertainty") or standard_uncertainties(summary)

    def item(key: str, label: str, kind: str, old: Any, new: Any) -> dict[str, Any]:
        u = _change_uncertainty(u_before.get(key), u_now.get(key))
        return _item(key, label, kind, UNITS[kind], old, new, tolerances[kind], u, coverage_factor)

    old_overall, new_overall = before.get("overall", {}), summary.get("overall", {})
    items = [
        item(f"overall.{key}", label, kind, old_overall.get(key), new_overall.get(key))
        for key, label, kind in DRIFT_FIGURES
    ]
    old_positions = before.get("positions", {})
    old_by_z = dict(zip(old_positions.get("z_in_mm", []), old_positions.get("mean_error_mm", []), strict=False))
    new_positions = summary.get("positions", {})
    for z_in, error in zip(new_positions.get("z_in_mm", []), new_positions.get("mean_error_mm", []), strict=False):
        if z_in in old_by_z:
            items.append(
                item(
                    f"positions.mean_error_mm@{z_in:g}",
                    f"Mean error at Z_in = {z_in:g} mm",
                    "mm",
                    old_by_z[z_in],
                    error,
                )
            )
    old_rig, new_rig = before.get("rig", {}), summary.get("rig", {})
    rig_changes = [
        {"name": name, "previous": old_rig.get(name), "current": new_rig.get(name)}
        for name in sorted(set(old_rig) | set(new_rig))
        if old_rig.get(name) != new_rig.get(name)
    ]
    return {
        "previous": previous.pk,
        "previous_created_at": previous.created_at.isoformat(),
        "tolerances": tolerances,
        "coverage_factor": coverage_factor,
        "items": items,
        "rig_changes": rig_changes,
        "beyond": sum(item["beyond"] for item in items),
    }
