"""Options of a characterization report: the virtual stage's settings and the drift tolerances, checked.

Every check raises :class:`~metrology.errors.BadInput` naming the option and the value, so the
API answers 400 and the form shows the message; nothing is stored before the options pass.
"""

from __future__ import annotations

import math
from typing import Any

from django.conf import settings

from metrology.errors import BadInput
from metrology.reports.models import Report
from metrology.reports.selectors import latest_uploaded_stage_session
from metrology.rigs.models import Rig

SOURCES = ("auto", Report.Source.VIRTUAL_STAGE, Report.Source.UPLOADED_SERIES)

# The virtual stage: a reduced version of the paper's section 5 series, with a realistic 8-bit camera.
VIRTUAL_STAGE_DEFAULTS: dict[str, Any] = {
    "z_start_mm": 0.0,
    "z_stop_mm": 80.0,
    "z_step_mm": 8.0,
    "repeats": 2,
    "bit_depth": 8,
    "noise_grey": 1.5,
    "camera_defocus_px": 0.5,
    "seed": None,  # None: derived from the report's id, so successive reports see fresh noise
}
MAX_STAGE_CAPTURES = 400
TOLERANCE_KINDS = ("mm", "pct_fs", "slope")


def checked_number(name: str, value: Any, *, integer: bool = False, minimum: float | None = None) -> float | int:
    """``value`` as a finite float (or int with ``integer``) of at least ``minimum``; else BadInput naming it."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise BadInput(f"options.{name} must be a finite number, got {value!r}")
    if integer and not float(value).is_integer():
        raise BadInput(f"options.{name} must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise BadInput(f"options.{name} must be at least {minimum:g}, got {value!r}")
    return int(value) if integer else float(value)


def check_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """Virtual-stage options and drift tolerances, validated and completed with the defaults.

    Raises
    ------
    BadInput
        Naming the option and the value.
    """
    options = dict(options or {})
    tolerances = options.pop("tolerances", None) or {}
    unknown = sorted(set(options) - set(VIRTUAL_STAGE_DEFAULTS))
    if unknown:
        raise BadInput(
            f"options: unknown option(s) {', '.join(unknown)}; accepted: "
            f"{', '.join([*VIRTUAL_STAGE_DEFAULTS, 'tolerances'])}"
        )
    checked = {**VIRTUAL_STAGE_DEFAULTS, **options}
    for name in ("z_start_mm", "z_stop_mm"):
        checked[name] = checked_number(name, checked[name])
    checked["z_step_mm"] = checked_number("z_step_mm", checked["z_step_mm"])
    if checked["z_step_mm"] <= 0:
        raise BadInput(f"options.z_step_mm must be positive, got {checked['z_step_mm']}")
    checked["repeats"] = checked_number("repeats", checked["repeats"], integer=True, minimum=1)
    if checked["bit_depth"] not in (8, 16):
        raise BadInput(f"options.bit_depth must be 8 or 16, got {checked['bit_depth']!r}")
    checked["noise_grey"] = checked_number("noise_grey", checked["noise_grey"], minimum=0)
    checked["camera_defocus_px"] = checked_number("camera_defocus_px", checked["camera_defocus_px"], minimum=0)
    if checked["seed"] is not None:
        checked["seed"] = checked_number("seed", checked["seed"], integer=True, minimum=0)
    positions = stage_positions(checked)
    if len(positions) < 2:
        raise BadInput(
            f"options: the stage range {checked['z_start_mm']:g} to {checked['z_stop_mm']:g} mm in steps of "
            f"{checked['z_step_mm']:g} mm gives {len(positions)} position(s); a characterization needs two or more"
        )
    if len(positions) * checked["repeats"] > MAX_STAGE_CAPTURES:
        raise BadInput(
            f"options: {len(positions)} positions x {checked['repeats']} repeats exceeds {MAX_STAGE_CAPTURES} captures"
        )
    if not isinstance(tolerances, dict):
        raise BadInput(f"options.tolerances must be an object like {{'mm': 0.01}}, got {tolerances!r}")
    bad = sorted(set(tolerances) - set(TOLERANCE_KINDS))
    if bad:
        raise BadInput(f"options.tolerances: unknown kind(s) {', '.join(bad)}; accepted: {', '.join(TOLERANCE_KINDS)}")
    checked["tolerances"] = {
        **settings.GCPS_REPORT_DRIFT_TOLERANCE,
        **{kind: checked_number(f"tolerances.{kind}", value, minimum=0) for kind, value in tolerances.items()},
    }
    return checked


def stage_positions(options: dict[str, Any]) -> list[float]:
    """Stage positions Z_in (mm) from ``z_start_mm`` to ``z_stop_mm`` inclusive, every ``z_step_mm``."""
    from metrology.core.simulate import stage_positions as positions

    start, stop, step = options["z_start_mm"], options["z_stop_mm"], options["z_step_mm"]
    if stop < start:
        return []
    if (stop - start) / step > MAX_STAGE_CAPTURES:
        return positions(start, start + MAX_STAGE_CAPTURES * step, step)  # too many: the caller refuses
    return positions(start, stop, step)


def resolve_source(rig: Rig, source: str) -> str:
    """``auto`` becomes an uploaded series when the rig has one, else the virtual stage."""
    if source not in SOURCES:
        raise BadInput(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    if source == "auto":
        has_series = latest_uploaded_stage_session(rig) is not None
        return Report.Source.UPLOADED_SERIES if has_series else Report.Source.VIRTUAL_STAGE
    return source
