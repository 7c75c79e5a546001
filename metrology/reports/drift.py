"""Drift of a report against the rig's previous one: which figures moved, by how much, beyond tolerance."""

from __future__ import annotations

from typing import Any

from django.conf import settings

from metrology.reports.models import Report

# Overall figures compared between reports: (key in results["overall"], label, tolerance kind).
DRIFT_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("mean_error_mm", "Overall mean error", "mm"),
    ("std_error_mm", "Overall standard deviation of the error", "mm"),
    ("rms_error_mm", "Overall RMS error", "mm"),
    ("error_pct_fs", "RMS error, % of full scale", "pct_fs"),
    ("max_abs_mean_error_mm", "Largest |mean error| over the positions", "mm"),
    ("max_abs_slope_deviation", "Largest |slope - 1| over the test points", "slope"),
)


def _item(key: str, label: str, kind: str, unit: str, old: Any, new: Any, tolerance: float) -> dict[str, Any]:
    comparable = isinstance(old, int | float) and isinstance(new, int | float)
    change = (new - old) if comparable else None
    return {
        "key": key,
        "label": label,
        "kind": kind,
        "unit": unit,
        "previous": old,
        "current": new,
        "change": change,
        "tolerance": tolerance,
        "beyond": bool(comparable and abs(change) > tolerance),
    }


UNITS = {"mm": "mm", "pct_fs": "% FS", "slope": ""}


def compute_drift(previous: Report | None, summary: dict[str, Any], tolerances: dict[str, float]) -> dict[str, Any]:
    """Changes of the report's figures since ``previous``; ``beyond`` marks moves beyond tolerance.

    Compared: the overall figures of :data:`DRIFT_FIGURES` and the mean error at every stage
    position Z_in found in both reports; the rig parameters that changed are listed too.
    """
    tolerances = {**settings.GCPS_REPORT_DRIFT_TOLERANCE, **(tolerances or {})}
    if previous is None:
        return {"previous": None, "tolerances": tolerances, "items": [], "rig_changes": [], "beyond": 0}
    before = previous.summary or {}
    old_overall, new_overall = before.get("overall", {}), summary.get("overall", {})
    items = [
        _item(f"overall.{key}", label, kind, UNITS[kind], old_overall.get(key), new_overall.get(key), tolerances[kind])
        for key, label, kind in DRIFT_FIGURES
    ]
    old_positions = before.get("positions", {})
    old_by_z = dict(zip(old_positions.get("z_in_mm", []), old_positions.get("mean_error_mm", []), strict=False))
    new_positions = summary.get("positions", {})
    for z_in, error in zip(new_positions.get("z_in_mm", []), new_positions.get("mean_error_mm", []), strict=False):
        if z_in in old_by_z:
            items.append(
                _item(
                    f"positions.mean_error_mm@{z_in:g}",
                    f"Mean error at Z_in = {z_in:g} mm",
                    "mm",
                    "mm",
                    old_by_z[z_in],
                    error,
                    tolerances["mm"],
                )
            )
    old_rig, new_rig = before.get("rig", {}), summary.get("rig", {})
    rig_changes = [
        {"name": name, "previous": old_rig.get(name), "current": new_rig.get(name)}
        for name in ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")
        if old_rig.get(name) != new_rig.get(name)
    ]
    return {
        "previous": previous.pk,
        "previous_created_at": previous.created_at.isoformat(),
        "tolerances": tolerances,
        "items": items,
        "rig_changes": rig_changes,
        "beyond": sum(item["beyond"] for item in items),
    }
