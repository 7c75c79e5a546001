"""What every pipeline result carries: its options, the software version, per-phase timings, and
its JSON-safe form (:func:`json_safe`, from the light :mod:`.jsonsafe`) for the files and the database."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from metrology.core.measure import DecodeOptions
from metrology.pipeline.jsonsafe import json_safe as json_safe  # where the pipelines import it from


@dataclass
class PhaseTimer:
    """Seconds spent per named phase (``timings_s[name]``), accumulated over repeated phases."""

    timings_s: dict[str, float] = field(default_factory=dict)

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[name] = self.timings_s.get(name, 0.0) + time.perf_counter() - start

    def add(self, timings_s: Mapping[str, float], prefix: str = "") -> None:
        """Add the sub-phase timings of a core call (e.g. :attr:`HeightResult.timings_s`)."""
        for name, seconds in timings_s.items():
            key = f"{prefix}{name}"
            self.timings_s[key] = self.timings_s.get(key, 0.0) + float(seconds)


def decode_options(value: Any) -> DecodeOptions:
    """``value`` as :class:`DecodeOptions` (None: defaults; a mapping: :meth:`DecodeOptions.from_dict`)."""
    if value is None:
        return DecodeOptions()
    if isinstance(value, DecodeOptions):
        return value
    if isinstance(value, Mapping):
        return DecodeOptions.from_dict(value)
    raise ValueError(f"decode must be DecodeOptions or an object of decode options, got {value!r}")


def check_keys(kind: str, data: Mapping[str, Any], allowed: set[str]) -> None:
    """ValueError naming the unknown keys of an options object."""
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"unknown {kind} option(s): {', '.join(unknown)}; accepted: {', '.join(sorted(allowed))}")


def check_bool(name: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}")


def check_int(name: str, value: Any, lower: int, upper: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lower <= value <= upper:
        raise ValueError(f"{name} must be an integer in [{lower}, {upper}], got {value!r}")


def check_positive(name: str, value: Any, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number, got {value!r}")
