"""Characterize: linearity and accuracy from a stage series (paper section 5; the ``gcps
characterize`` command and the characterization job)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import characterize as core
from metrology.core import measure as core_measure
from metrology.core.measure import DecodeOptions
from metrology.core.rig import Rig
from metrology.pipeline.common import PhaseTimer, check_int, check_keys, decode_options
from metrology.version import software_version

SeriesStacks = Iterable[tuple[float, int, npt.ArrayLike]]
"""``(z_in_mm, repeat, stack)`` of each capture of a stage series; may load stacks lazily."""


@dataclass(frozen=True)
class CharacterizeOptions:
    """Options of :func:`characterize` (see :func:`metrology.core.characterize.characterize`).

    Attributes
    ----------
    decode : DecodeOptions
    n_points : int
        Test points along X per row, in [1, 1000] (default 21).
    rows : int, tuple of int or None
        None: the middle row; an int: that many rows spread over the image; a tuple: those rows.
    patch_px : int
        Test-point patch size, odd, >= 1 (default 5).
    margin_frac : float
        Fraction of the width left free at each side, in [0, 0.5) (default 0.08).
    """

    decode: DecodeOptions = field(default_factory=DecodeOptions)
    n_points: int = 21
    rows: int | tuple[int, ...] | None = None
    patch_px: int = 5
    margin_frac: float = 0.08

    def __post_init__(self) -> None:
        object.__setattr__(self, "decode", decode_options(self.decode))
        check_int("n_points", self.n_points, 1, 1000)
        check_int("patch_px", self.patch_px, 1, 99)
        if self.patch_px % 2 == 0:
            raise ValueError(f"patch_px must be odd, got {self.patch_px!r}")
        margin = self.margin_frac
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not (0 <= margin < 0.5):
            raise ValueError(f"margin_frac must be a number in [0, 0.5), got {margin!r}")
        rows = self.rows
        if isinstance(rows, (list, tuple)):
            for row in rows:
                check_int("rows", row, 0, 1_000_000)
            if not rows:
                raise ValueError(f"rows must list at least one row, got {rows!r}")
            object.__setattr__(self, "rows", tuple(rows))
        elif rows is not None:
            check_int("rows", rows, 1, 1000)

    def to_dict(self) -> dict[str, Any]:
        return {
            "decode": self.decode.to_dict(),
            "n_points": self.n_points,
            "rows": list(self.rows) if isinstance(self.rows, tuple) else self.rows,
            "patch_px": self.patch_px,
            "margin_frac": self.margin_frac,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CharacterizeOptions:
        check_keys("characterization", data, {f for f in cls.__dataclass_fields__})
        return cls(**data)


@dataclass(frozen=True)
class CharacterizeResult:
    """Output of :func:`characterize`: the section 5 report (see
    :func:`metrology.core.characterize.characterize`), with the options, the software version and
    per-phase timings (``reference``, ``measure series``, ``statistics``)."""

    report: dict[str, Any]
    options: CharacterizeOptions
    software_version: str
    timings_s: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.report,
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
        }


def characterize(
    rig: Rig,
    reference: npt.ArrayLike | core_measure.Reference,
    series: SeriesStacks,
    options: CharacterizeOptions | None = None,
    *,
    threads: int | None = None,
) -> CharacterizeResult:
    """Measure every capture of a stage series against the reference and compute section 5's figures.

    Parameters
    ----------
    rig : Rig
    reference : (11, H, W) image stack or Reference
        The reference plane (a kept :class:`~metrology.core.measure.Reference`, prepared with
        ``options.decode``, is reused as is).
    series : iterable of (z_in_mm, repeat, (11, H, W) image stack)
        Consumed once, capture by capture (a generator may load each stack when asked; an
        exception it raises stops the run).
    options : CharacterizeOptions, optional

    Raises
    ------
    ValueError
        On a bad option, stack, shape or stage position.
    """
    options = options or CharacterizeOptions()
    timer = PhaseTimer()
    with timer.phase("reference"):
        if isinstance(reference, core_measure.Reference):
            kept = reference
        else:
            kept = core_measure.prepare_reference(rig, reference, options.decode)

    def heights() -> Iterable[tuple[float, int, np.ndarray]]:
        for z_in, repeat, stack in series:
            if not math.isfinite(z_in):
                raise ValueError(f"z_in_mm must be finite, got {z_in!r}")
            with timer.phase("measure series"):
                z = core_measure.measure_height(rig, kept, stack, options.decode, gray_only=False, threads=threads).z_mm
            yield float(z_in), repeat, z

    rows = list(options.rows) if isinstance(options.rows, tuple) else options.rows
    report = core.characterize(
        rig, heights(), n_points=options.n_points, rows=rows, patch_px=options.patch_px, margin_frac=options.margin_frac
    )
    return CharacterizeResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
