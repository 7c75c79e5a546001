"""What every pipeline result carries: its options, the software version, per-phase timings, and
its JSON-safe form (:func:`json_safe`, from the light :mod:`.jsonsafe`) for the files and the database."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field


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
