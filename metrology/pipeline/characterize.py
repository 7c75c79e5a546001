"""Characterize: linearity and accuracy from a stage series (paper section 5; the ``gcps
characterize`` command and the characterization job), for every codec and geometric model.

Each stage capture is measured against the reference capture, kept once
(:func:`metrology.pipeline.measure.measure`: the same decoding, filters and triangulation as a
measurement), and its heights above the reference plane feed
:func:`metrology.core.characterize.characterize`, with the test points where the model says each
pixel's ray meets the reference plane (:meth:`~metrology.core.geometry.base.PreparedGeometry.plane_coordinates`).

The stage must move the plane along the reference plane's normal: the heights are distances
along that normal, so a stage inclined by ``a`` to it reads slopes ``cos a``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import characterize as core
from metrology.core.codecs.model import Codec
from metrology.core.decode import GcpsV1Options
from metrology.core.filters import FilterOptions
from metrology.core.geometry.base import GeometryModel, GeometryOptions
from metrology.core.measure import (
    SETTINGS_KEYS,
    MeasureOptions,
    Reference,
    check_settings,
    prepare_reference,
    settings_from_dict,
    settings_to_dict,
)
from metrology.core.measure import measure as measure_capture
from metrology.core.option_checks import check_int, check_keys
from metrology.pipeline.common import PhaseTimer
from metrology.version import software_version

SeriesStacks = Iterable[tuple[float, int, npt.ArrayLike]]
"""``(z_in_mm, repeat, stack)`` of each capture of a stage series; may load stacks lazily."""


@dataclass(frozen=True)
class CharacterizeOptions:
    """Options of :func:`characterize` (see :func:`metrology.core.characterize.characterize`).

    Attributes
    ----------
    filters, gcps_v1, geometry
        How each capture is measured (:class:`~metrology.core.measure.MeasureOptions`); JSON:
        ``decode``, ``triangulate``, ``method``.
    n_points : int
        Test points along X per row, in [1, 1000] (default 21).
    rows : int, tuple of int or None
        None: the middle row; an int: that many rows spread over the image; a tuple: those rows.
    patch_px : int
        Test-point patch size, odd, >= 1 (default 5).
    margin_frac : float
        Fraction of the width left free at each side, in [0, 0.5) (default 0.08).
    """

    filters: FilterOptions = field(default_factory=FilterOptions)
    gcps_v1: GcpsV1Options = field(default_factory=GcpsV1Options)
    geometry: GeometryOptions = field(default_factory=GeometryOptions)
    n_points: int = 21
    rows: int | tuple[int, ...] | None = None
    patch_px: int = 5
    margin_frac: float = 0.08

    def __post_init__(self) -> None:
        check_settings(self)
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
            **settings_to_dict(self.filters, self.gcps_v1, self.geometry),
            "n_points": self.n_points,
            "rows": list(self.rows) if isinstance(self.rows, tuple) else self.rows,
            "patch_px": self.patch_px,
            "margin_frac": self.margin_frac,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CharacterizeOptions:
        own = ("n_points", "rows", "patch_px", "margin_frac")
        check_keys("characterization", data, {*SETTINGS_KEYS, *own})
        return cls(**settings_from_dict(data), **{k: data[k] for k in own if k in data})


@dataclass(frozen=True)
class CharacterizeResult:
    """Output of :func:`characterize`: the section 5 report (see
    :func:`metrology.core.characterize.characterize`) plus ``model``, ``triangulate`` (the axis)
    and ``reference_plane`` (a fitted plane's centroid, normal and point count, else null), with
    the options, the software version and per-phase timings (``reference``, ``measure series``,
    ``statistics``)."""

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
    model: GeometryModel,
    reference: npt.ArrayLike | Reference,
    series: SeriesStacks,
    options: CharacterizeOptions | None = None,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> CharacterizeResult:
    """Measure every capture of a stage series against the reference and compute section 5's figures.

    Parameters
    ----------
    model : GeometryModel
    reference : image stack of ``codec`` or Reference
        The reference plane (a kept :class:`~metrology.core.measure.Reference`, prepared with
        the options' settings, is reused as is).
    series : iterable of (z_in_mm, repeat, image stack of ``codec``)
        Consumed once, capture by capture (a generator may load each stack when asked; an
        exception it raises stops the run).
    options : CharacterizeOptions, optional
    codec : Codec, optional
        The stacks' codec (None: the paper's gcps-v1).

    Raises
    ------
    ValueError
        On a bad option, stack, shape or stage position.
    """
    options = options or CharacterizeOptions()
    measure_options = MeasureOptions.of(options)
    timer = PhaseTimer()
    with timer.phase("reference"):
        if isinstance(reference, Reference):
            kept = reference
        else:
            kept = prepare_reference(model, reference, codec, measure_options, threads=threads)

    def heights() -> Iterable[tuple[float, int, np.ndarray]]:
        for z_in, repeat, stack in series:
            if not math.isfinite(z_in):
                raise ValueError(f"z_in_mm must be finite, got {z_in!r}")
            with timer.phase("measure series"):
                try:
                    measured = measure_capture(
                        model, stack, codec, reference=kept, options=measure_options, threads=threads
                    )
                except ValueError as exc:
                    raise ValueError(f"stage capture at z_in_mm = {z_in}: {exc}") from exc
            yield float(z_in), repeat, measured.z_mm

    rows = list(options.rows) if isinstance(options.rows, tuple) else options.rows
    prepared = kept.prepared_geometry()
    with timer.phase("statistics"):
        report = core.characterize(
            prepared.plane_coordinates(kept.surface),
            heights(),
            n_points=options.n_points,
            rows=rows,
            patch_px=options.patch_px,
            margin_frac=options.margin_frac,
        )
    report["model"] = model.model
    report["triangulate"] = prepared.axis
    report["reference_plane"] = kept.surface.describe()
    return CharacterizeResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
