"""Calibrate: L and alpha (and optionally d) of a rig from captures of a master block (paper
section 4; the ``gcps calibrate`` command and the calibration job).

The paper's calibration adjusts the model's :attr:`~metrology.core.geometry.base.GeometryModel.calibration_parameters`
(the crossed-axes rig's L, alpha and d); a model without any is refused with what to use instead.
The reference is decoded once, each master is measured against it as any measurement is (the
mixed-pixel filter and the camera-blur correction, :func:`metrology.core.measure.measure`), and
the calibration fits the master's filtered, corrected light codes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy.typing as npt

from metrology.core.calibrate import CalibrationResult, MasterCapture, calibrate_lsq, calibrate_paper
from metrology.core.codecs.model import Codec
from metrology.core.decode import GcpsV1Options
from metrology.core.filters import FilterOptions
from metrology.core.geometry.base import GeometryModel, GeometryOptions
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.measure import (
    MeasureOptions,
    check_settings,
    decode_block,
    measure,
    prepare_reference,
    split_decode_block,
)
from metrology.core.option_checks import check_bool, check_int, check_keys, check_positive
from metrology.pipeline.common import PhaseTimer
from metrology.version import software_version

METHODS = ("lsq", "paper")
RowsCols = tuple[tuple[int, int], tuple[int, int]]


@dataclass(frozen=True)
class CalibrateOptions:
    """Options of :func:`calibrate`.

    Attributes
    ----------
    master_height_mm : float
        Known height of the master block's top face, mm, > 0.
    method : {'lsq', 'paper'}
        Joint least squares (default) or the paper's iteration (section 4; one master).
    filters, gcps_v1
        How the captures are decoded and filtered (JSON: ``decode``).
    roi : ((row0, row1), (col0, col1)) or None
        Where the top face is looked for, pixels, half-open (default: found automatically).
    fit_d, use_floor, max_iterations, tolerance
        lsq: also fit d; use the floor around the block; Gauss-Newton iterations (default 8);
        convergence tolerance (default 1e-10).
    delta_z_mm, m_hat, w, max_iterations
        paper: required accuracy, mm (0.025); slope threshold (1e-4); the paper's w (None:
        its default); profiles evaluated (default 30).
    """

    master_height_mm: float
    method: str = "lsq"
    filters: FilterOptions = field(default_factory=FilterOptions)
    gcps_v1: GcpsV1Options = field(default_factory=GcpsV1Options)
    roi: RowsCols | None = None
    fit_d: bool = False
    use_floor: bool = True
    max_iterations: int | None = None
    tolerance: float | None = None
    delta_z_mm: float = 0.025
    m_hat: float = 1e-4
    w: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        check_positive("master_height_mm", self.master_height_mm)
        check_settings(self)
        if self.roi is not None:
            try:
                (r0, r1), (c0, c1) = self.roi
                ok = all(isinstance(v, int) and not isinstance(v, bool) for v in (r0, r1, c0, c1))
            except (TypeError, ValueError):
                ok = False
            if not ok or not (0 <= r0 < r1 and 0 <= c0 < c1):
                raise ValueError(f"roi must be ((row0, row1), (col0, col1)) with 0 <= start < stop, got {self.roi!r}")
            object.__setattr__(self, "roi", ((r0, r1), (c0, c1)))
        check_bool("fit_d", self.fit_d)
        check_bool("use_floor", self.use_floor)
        if self.max_iterations is not None:
            check_int("max_iterations", self.max_iterations, 1, 1000)
        check_positive("tolerance", self.tolerance, allow_none=True)
        check_positive("delta_z_mm", self.delta_z_mm)
        check_positive("m_hat", self.m_hat)
        if self.w is not None and (
            isinstance(self.w, bool) or not isinstance(self.w, (int, float)) or not math.isfinite(self.w)
        ):
            raise ValueError(f"w must be a finite number or None, got {self.w!r}")

    @property
    def geometry(self) -> GeometryOptions:
        """The paper's calibration measures by the light planes of u (the crossed-axes rig's only way)."""
        return GeometryOptions()

    @property
    def roi_slices(self) -> tuple[slice, slice] | None:
        if self.roi is None:
            return None
        (r0, r1), (c0, c1) = self.roi
        return slice(r0, r1), slice(c0, c1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "master_height_mm": self.master_height_mm,
            "method": self.method,
            "decode": decode_block(self.filters, self.gcps_v1),
            "roi": None if self.roi is None else [list(self.roi[0]), list(self.roi[1])],
            "fit_d": self.fit_d,
            "use_floor": self.use_floor,
            "max_iterations": self.max_iterations,
            "tolerance": self.tolerance,
            "delta_z_mm": self.delta_z_mm,
            "m_hat": self.m_hat,
            "w": self.w,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CalibrateOptions:
        fields = {f for f in cls.__dataclass_fields__} - {"filters", "gcps_v1"}
        check_keys("calibration", data, {*fields, "decode"})
        values = dict(data)
        values["filters"], values["gcps_v1"] = split_decode_block(values.pop("decode", None))
        if values.get("roi") is not None:
            rows, cols = values["roi"]
            values["roi"] = (tuple(rows), tuple(cols))
        return cls(**values)


@dataclass(frozen=True)
class CalibrateResult:
    """Output of :func:`calibrate`: the core's :class:`~metrology.core.calibrate.CalibrationResult`
    with the options, the software version and per-phase timings (``decode``, ``fit``)."""

    calibration: CalibrationResult
    options: CalibrateOptions
    software_version: str
    timings_s: dict[str, float]

    @property
    def rig(self) -> Rig:
        """The calibrated rig."""
        return self.calibration.rig

    def to_dict(self) -> dict[str, Any]:
        return {
            "calibration": self.calibration.to_dict(),
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
        }


def calibrate(
    rig: GeometryModel,
    reference: npt.ArrayLike,
    masters: Sequence[npt.ArrayLike],
    options: CalibrateOptions,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> CalibrateResult:
    """Calibrate ``rig`` (the starting values) on captures of a master block.

    Parameters
    ----------
    rig : GeometryModel
        Initial estimates of L, alpha (and d) and the fixed FW, nlp, image size: a model whose
        :attr:`~metrology.core.geometry.base.GeometryModel.calibration_parameters` name them.
    reference : image stack of ``codec``
        The reference plane.
    masters : sequence of image stacks of ``codec``
        The master block on the reference plane (one for the paper's method).
    options : CalibrateOptions
    codec : Codec, optional
        The captures' codec (None: the paper's gcps-v1).

    Raises
    ------
    ValueError
        On a model the paper's calibration cannot adjust, a bad option, stack or shape, or no master.
    """
    if not rig.calibration_parameters or not isinstance(rig, Rig):
        raise ValueError(
            f"the paper's master-block calibration adjusts L and alpha; a {rig.short_label} rig has "
            "none of them (calibrate it from board poses: gcps calibrate-procam)"
        )
    if not masters:
        raise ValueError("masters: at least one master capture is needed")
    if options.method == "paper" and len(masters) != 1:
        raise ValueError(f"method 'paper' takes one master capture, got {len(masters)}")
    timer = PhaseTimer()
    measure_options = MeasureOptions.of(options)
    with timer.phase("decode"):
        kept = prepare_reference(rig, reference, codec, measure_options, threads=threads)
        ref_codes = kept.codes
        master_codes = [
            measure(rig, stack, codec, reference=kept, options=measure_options, threads=threads).codes
            for stack in masters
        ]
    roi = options.roi_slices
    with timer.phase("fit"):
        if options.method == "paper":
            paper: dict[str, Any] = {"delta_z_mm": options.delta_z_mm, "m_hat": options.m_hat, "w": options.w}
            if options.max_iterations is not None:
                paper["max_iterations"] = options.max_iterations
            result = calibrate_paper(rig, ref_codes, master_codes[0], options.master_height_mm, roi=roi, **paper)
        else:
            lsq: dict[str, Any] = {"fit_d": options.fit_d, "use_floor": options.use_floor}
            if options.max_iterations is not None:
                lsq["max_iterations"] = options.max_iterations
            if options.tolerance is not None:
                lsq["tolerance"] = options.tolerance
            captures = [MasterCapture(ref_codes, codes, options.master_height_mm, roi=roi) for codes in master_codes]
            result = calibrate_lsq(rig, captures, **lsq)
    return CalibrateResult(
        calibration=result, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
