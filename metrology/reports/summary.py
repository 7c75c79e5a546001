"""A report's summary: the characterization's figures as JSON, with the rig and the provenance."""

from __future__ import annotations

from typing import Any

from django.utils import timezone

from metrology.characterizations.models import Characterization
from metrology.reports.models import Report
from metrology.version import software_version


def build_summary(report: Report, characterization: Characterization) -> dict[str, Any]:
    """The report's figures as JSON: overall, per position, rig parameters, provenance."""
    results = characterization.results or {}
    positions = {key: list(results.get(key, [])) for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples")}
    return {
        "overall": dict(results.get("overall", {})),
        "positions": positions,
        "edge_sigma_ratio": results.get("edge_sigma_ratio"),
        "repeats": results.get("repeats"),
        "n_test_points": len(results.get("test_points", [])),
        "rig": {"id": report.rig_id, "name": report.rig.name, **characterization.rig_values},
        "source": report.source,
        "characterization": characterization.pk,
        "session": characterization.session_id,
        "software_version": software_version(),
        "generated_at": timezone.now().isoformat(),
    }
