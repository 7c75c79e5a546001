"""A report's summary: the characterization's figures as JSON, their standard uncertainties, the rig, provenance.

Standard uncertainties (one sigma) come from each report's own scatter, repeat count and sample
counts, so the drift check can tell a move of the rig from the noise of two finite samples.

Every capture of a report is measured against the same reference capture, so the reference's
noise is common to all positions and repeats at a test point: the independent units are the test
points, not the samples. At a stage position with ``n`` samples (test points x ``R`` repeats) of
standard deviation ``s``, the mean error has ``u = s / sqrt(n / R)``; over all positions, the
effective count is the number of test points ``N_eff = N / (R P)`` (``N`` samples, ``P``
positions). Measured on the virtual stage (12 reports, 6 positions, 2 repeats, 21 test points):
position means scattered by 3.9-5.7 µm against this model's 5.2-5.7 µm (``s / sqrt(n)`` would say
3.7-4.0 µm), the overall mean by 4.3 µm against 5.3 µm (``s / sqrt(N)``: 1.5 µm). Then:

- overall mean error ``m``: ``u(m) = s / sqrt(N_eff)``; overall standard deviation:
  ``u(s) = s / sqrt(2 (N_eff - 1))`` (normal samples);
- RMS error ``r = sqrt(m^2 + s^2)``: ``u(r) = sqrt((m u(m))^2 + (s u(s))^2) / r``; as % of the
  full scale FS: ``100 u(r) / FS``;
- largest |mean error| over the positions: the ``u`` of the position where it occurs;
- largest |slope - 1|: the slope's ``u`` of the test point where it occurs,
  ``sigma_tp / sqrt(R * sum_i (Z_i - mean Z)^2)`` (a straight-line fit through position means of
  ``R`` repeats each, ``sigma_tp`` the point's repeatability).

Where the test points also share a systematic error, ``s`` overstates the noise, which errs on
the side of not calling noise drift.
"""

from __future__ import annotations

import math
from typing import Any

from django.utils import timezone

from metrology.characterizations.models import Characterization
from metrology.reports.models import Report
from metrology.version import software_version


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def slope_uncertainty(results: dict[str, Any]) -> float | None:
    """Standard uncertainty of the slope at the test point with the largest |slope - 1| (None if unknown).

    ``u(slope) = sigma_tp / sqrt(R * sum_i (Z_i - mean Z)^2)`` over the stage positions ``Z_i``
    (mm), ``R`` repeats per position, ``sigma_tp`` the point's repeatability (mm).
    """
    z_in = [z for z in (_finite(v) for v in results.get("z_in_mm", [])) if z is not None]
    repeats = _finite(results.get("repeats"))
    fitted = [
        p for p in results.get("test_points", []) if _finite(p.get("slope")) is not None and _finite(p.get("sigma_mm"))
    ]
    if len(z_in) < 2 or not repeats or not fitted:
        return None
    worst = max(fitted, key=lambda p: abs(float(p["slope"]) - 1.0))
    mean_z = sum(z_in) / len(z_in)
    spread = sum((z - mean_z) ** 2 for z in z_in)
    return float(worst["sigma_mm"]) / math.sqrt(repeats * spread) if spread > 0 else None


def standard_uncertainties(summary: dict[str, Any]) -> dict[str, float | None]:
    """One-sigma standard uncertainty of each compared figure, keyed like the drift items.

    Keys ``overall.<figure>`` and ``positions.mean_error_mm@<Z_in>``; None where the summary lacks
    the scatter or the counts (a report made before uncertainties were recorded lacks the slope's).
    """
    overall = summary.get("overall") or {}
    positions = summary.get("positions") or {}
    repeats = _finite(summary.get("repeats")) or 1.0
    out: dict[str, float | None] = {}
    per_position: list[tuple[float, float | None]] = []  # (|mean error|, u)
    total, counted = 0.0, 0
    for z_in, mean, std, n in zip(
        positions.get("z_in_mm", []),
        positions.get("mean_error_mm", []),
        positions.get("std_error_mm", []),
        positions.get("n_samples", []),
        strict=False,
    ):
        s, count = _finite(std), _finite(n)
        units = count / repeats if count else 0.0  # independent test points at this position
        u = s / math.sqrt(units) if s is not None and units > 0 else None
        if _finite(z_in) is not None:
            out[f"positions.mean_error_mm@{z_in:g}"] = u
        if _finite(mean) is not None:
            per_position.append((abs(float(mean)), u))
        if count:
            total, counted = total + count, counted + 1
    n_eff = total / (repeats * counted) if counted else 0.0
    m, s = _finite(overall.get("mean_error_mm")), _finite(overall.get("std_error_mm"))
    u_m = s / math.sqrt(n_eff) if s is not None and n_eff > 0 else None
    u_s = s / math.sqrt(2 * (n_eff - 1)) if s is not None and n_eff > 1 else None
    out["overall.mean_error_mm"] = u_m
    out["overall.std_error_mm"] = u_s
    u_rms = None
    if m is not None and s is not None and u_m is not None and u_s is not None and math.hypot(m, s) > 0:
        u_rms = math.hypot(m * u_m, s * u_s) / math.hypot(m, s)
    out["overall.rms_error_mm"] = u_rms
    full_scale = _finite(overall.get("full_scale_mm"))
    out["overall.error_pct_fs"] = 100 * u_rms / full_scale if u_rms is not None and full_scale else None
    out["overall.max_abs_mean_error_mm"] = max(per_position, key=lambda item: item[0])[1] if per_position else None
    out["overall.max_abs_slope_deviation"] = _finite(summary.get("slope_uncertainty"))
    return out


def build_summary(report: Report, characterization: Characterization) -> dict[str, Any]:
    """The report's figures as JSON: overall, per position, their uncertainties, rig parameters, provenance."""
    results = characterization.results or {}
    positions = {key: list(results.get(key, [])) for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples")}
    summary: dict[str, Any] = {
        "overall": dict(results.get("overall", {})),
        "positions": positions,
        "edge_sigma_ratio": results.get("edge_sigma_ratio"),
        "repeats": results.get("repeats"),
        "n_test_points": len(results.get("test_points", [])),
        "slope_uncertainty": slope_uncertainty(results),
        "rig": {"id": report.rig_id, "name": report.rig.name, **characterization.rig_values},
        "source": report.source,
        "characterization": characterization.pk,
        "session": characterization.session_id,
        "software_version": software_version(),
        "generated_at": timezone.now().isoformat(),
    }
    summary["uncertainty"] = standard_uncertainties(summary)
    return summary
