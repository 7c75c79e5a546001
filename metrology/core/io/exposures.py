"""The manifest of a multi-exposure capture, ``exposures.json`` (docs/exposures.md).

A multi-exposure capture is a folder or a zip holding ``exposures.json``, one sub-folder per
exposure (each a complete stack of the codec's frames, as a single capture) and, optionally,
``codec.json`` at its top::

    {"format": "gcps-exposures/1",
     "exposures": [{"name": "exp0", "exposure_us": 2000},
                   {"name": "exp1", "exposure_us": 8000, "gain": 1.0, "projector_brightness": 1.0}]}

Each entry's ``name`` is its sub-folder (required, unique, one path component); ``exposure_us``
(> 0, microseconds) is required; ``gain`` and ``projector_brightness`` (> 0, default 1) are
optional; unknown keys are refused. The order of the entries does not matter:
:func:`parse_exposures` returns them from the least to the most exposed (``exposure_us * gain *
projector_brightness``, then the name), and that order numbers the exposures (0, 1, ...) in the
per-pixel maps ``exposure_u`` / ``exposure_v``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from metrology.core.io.errors import StackError

EXPOSURES_FILE_NAME = "exposures.json"
"""Name of the manifest that marks a multi-exposure capture."""

EXPOSURES_FORMAT = "gcps-exposures/1"
"""The manifest's ``format``."""

MAX_EXPOSURES = 254
"""Most exposures in one capture (the per-pixel index is uint8, 255 meaning none)."""

_TOP_KEYS = {"format", "exposures"}
_ENTRY_KEYS = {"name", "exposure_us", "gain", "projector_brightness"}


@dataclass(frozen=True)
class Exposure:
    """One exposure of a multi-exposure capture.

    Attributes
    ----------
    name : str
        Its sub-folder.
    exposure_us : float
        Exposure time, microseconds, > 0.
    gain : float
        Camera gain relative to the other exposures', > 0 (default 1).
    projector_brightness : float
        Projector brightness relative to the other exposures', > 0 (default 1).
    """

    name: str
    exposure_us: float
    gain: float = 1.0
    projector_brightness: float = 1.0

    @property
    def relative_exposure(self) -> float:
        """``exposure_us * gain * projector_brightness``: what orders the exposures."""
        return self.exposure_us * self.gain * self.projector_brightness

    def to_dict(self) -> dict[str, Any]:
        """The manifest entry (optional keys only where they differ from 1)."""
        entry: dict[str, Any] = {"name": self.name, "exposure_us": self.exposure_us}
        if self.gain != 1.0:
            entry["gain"] = self.gain
        if self.projector_brightness != 1.0:
            entry["projector_brightness"] = self.projector_brightness
        return entry


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise StackError(f"{where} must be a finite number > 0, got {value!r}")
    return float(value)


def parse_exposures(data: bytes | str, label: str = "capture") -> tuple[Exposure, ...]:
    """The exposures of an ``exposures.json``, from the least to the most exposed.

    Parameters
    ----------
    data : bytes or str
        The file's content (UTF-8 JSON).
    label : str
        The capture, for messages.

    Raises
    ------
    StackError
        Naming the file and the entry: not JSON, wrong format, unknown or missing keys, a name
        that is not one path component or is repeated, a non-positive number, no exposure.
    """
    where = f"capture {label} {EXPOSURES_FILE_NAME}"
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise StackError(f"{where} is not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise StackError(f"{where} must hold a JSON object")
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise StackError(f"{where} has unknown key(s) {', '.join(unknown)}; expected format and exposures")
    if doc.get("format") != EXPOSURES_FORMAT:
        raise StackError(f"{where}: format must be {EXPOSURES_FORMAT!r}, got {doc.get('format')!r}")
    entries = doc.get("exposures")
    if not isinstance(entries, list) or not entries:
        raise StackError(f"{where}: exposures must be a non-empty list")
    if len(entries) > MAX_EXPOSURES:
        raise StackError(f"{where} lists {len(entries)} exposures, more than {MAX_EXPOSURES}")
    exposures: list[Exposure] = []
    seen: set[str] = set()
    for index, entry in enumerate(entries):
        at = f"{where} exposures[{index}]"
        if not isinstance(entry, dict):
            raise StackError(f"{at} must be an object")
        name = entry.get("name")
        if isinstance(name, str) and name:
            at = f"{where} exposure {name!r}"
        unknown = sorted(set(entry) - _ENTRY_KEYS)
        if unknown:
            raise StackError(f"{at} has unknown key(s) {', '.join(unknown)}; expected {', '.join(sorted(_ENTRY_KEYS))}")
        if not isinstance(name, str) or not name:
            raise StackError(f"{at}: name is required (the exposure's sub-folder)")
        if name in (".", "..") or "/" in name or "\\" in name:
            raise StackError(f"{at}: name must be one folder name, got {name!r}")
        if name in seen:
            raise StackError(f"{where} lists exposure {name!r} twice; names are unique")
        seen.add(name)
        if "exposure_us" not in entry:
            raise StackError(f"{at}: exposure_us is required")
        exposures.append(
            Exposure(
                name=name,
                exposure_us=_positive(entry["exposure_us"], f"{at}: exposure_us"),
                gain=_positive(entry.get("gain", 1.0), f"{at}: gain"),
                projector_brightness=_positive(entry.get("projector_brightness", 1.0), f"{at}: projector_brightness"),
            )
        )
    return tuple(sorted(exposures, key=lambda e: (e.relative_exposure, e.name)))


def exposures_json(exposures: tuple[Exposure, ...] | list[Exposure]) -> str:
    """The ``exposures.json`` text of ``exposures`` (validated by :func:`parse_exposures`)."""
    text = json.dumps({"format": EXPOSURES_FORMAT, "exposures": [e.to_dict() for e in exposures]}, indent=2) + "\n"
    parse_exposures(text)
    return text
