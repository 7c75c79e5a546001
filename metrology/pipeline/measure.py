"""Measure: reference and object capture stacks to a height map (the ``gcps measure`` command and
the measurement job)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import measure as core_measure
from metrology.core.decode import DecodedStack
from metrology.core.measure import DecodeOptions, Reference, height_statistics
from metrology.core.rig import Rig
from metrology.pipeline.common import PhaseTimer, check_bool, check_keys, decode_options
from metrology.version import software_version


@dataclass(frozen=True)
class MeasureOptions:
    """Options of :func:`measure`.

    Attributes
    ----------
    decode : DecodeOptions
        Decoding and mixed-pixel options (:class:`~metrology.core.measure.DecodeOptions`).
    gray_only : bool
        Also compute the gray-code-only comparison heights (default True).
    """

    decode: DecodeOptions = field(default_factory=DecodeOptions)
    gray_only: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "decode", decode_options(self.decode))
        check_bool("gray_only", self.gray_only)

    def to_dict(self) -> dict[str, Any]:
        return {"decode": self.decode.to_dict(), "gray_only": self.gray_only}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MeasureOptions:
        check_keys("measure", data, {"decode", "gray_only"})
        return cls(**data)


@dataclass(frozen=True)
class MeasureResult:
    """Output of :func:`measure`.

    Attributes
    ----------
    z_mm : (H, W) float32 array
        Height above the reference plane, mm, NaN where not measured.
    gray_z_mm : (H, W) float32 array or None
        Gray-code-only heights, mm (when ``options.gray_only``).
    obj_codes : (H, W) float32 array
        The object's light codes after the filters (and the blur correction), code units.
    options : MeasureOptions
    software_version : str
    timings_s : dict
        Seconds per phase: ``measure`` (the whole call) and the core's sub-phases.
    """

    z_mm: np.ndarray
    gray_z_mm: np.ndarray | None
    obj_codes: np.ndarray
    options: MeasureOptions
    software_version: str
    timings_s: dict[str, float]

    def statistics(self) -> dict[str, Any]:
        """Valid pixels and min/max/mean/std of the heights (and of the gray-code-only heights)."""
        stats: dict[str, Any] = dict(height_statistics(self.z_mm))
        if self.gray_z_mm is not None:
            stats["gray_only"] = height_statistics(self.gray_z_mm)
        return stats

    def to_dict(self) -> dict[str, Any]:
        """Statistics, options, software version and timings (JSON-ready)."""
        return {
            "statistics": self.statistics(),
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
        }


def measure(
    rig: Rig,
    reference: npt.ArrayLike | DecodedStack | Reference,
    obj: npt.ArrayLike,
    options: MeasureOptions | None = None,
    *,
    threads: int | None = None,
) -> MeasureResult:
    """Height map of an object (Eqs. 1-17): decode, filter, correct the blur bias, triangulate.

    Parameters
    ----------
    rig : Rig
    reference : (11, H, W) image stack, DecodedStack or Reference
        The reference plane (a :class:`~metrology.core.measure.Reference` is reused as is).
    obj : (11, H, W) image stack
    options : MeasureOptions, optional
    threads : int, optional
        Threads over row tiles (does not change the result).

    Raises
    ------
    ValueError
        On a malformed stack, a shape that differs from the rig's, or a bad option.
    """
    options = options or MeasureOptions()
    timer = PhaseTimer()
    start = time.perf_counter()
    result = core_measure.measure_height(
        rig, reference, obj, options.decode, gray_only=options.gray_only, threads=threads
    )
    timer.timings_s["measure"] = time.perf_counter() - start
    timer.add(result.timings_s, "measure.")
    return MeasureResult(
        z_mm=result.z_mm,
        gray_z_mm=result.gray_z_mm,
        obj_codes=result.obj_codes,
        options=options,
        software_version=software_version(),
        timings_s=timer.timings_s,
    )
