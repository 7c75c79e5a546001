"""Calibrate: L and alpha (and optionally d) of a crossed-axes rig from captures of a master block
(the ``gcps calibrate`` command and the calibration job).

Both decode the same way: the reference is decoded once, each master is measured against it with
the mixed-pixel filter and the camera-blur correction (:func:`metrology.core.measure.measure_height`),
and the calibration fits the master's filtered, corrected codes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy.typing as npt

from metrology.core import measure as core_measure
from metrology.core.calibrate import CalibrationResult, MasterCapture, calibrate_lsq, calibrate_paper
from metrology.core.measure import DecodeOptions
from metrology.core.rig import Rig
from metrology.pipeline.common import (
    PhaseTimer,
    check_bool,
    check_int,
    check_keys,
    check_positive,
    decode_options,
)
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
    decode : DecodeOptions
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
    decode: DecodeOptions = field(default_factory=DecodeOptions)
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
        object.__setattr__(self, "decode", decode_options(self.decode))
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
    def roi_slices(self) -> tuple[slice, slice] | None:
        if self.roi is None:
            return None
        (r0, r1), (c0, c1) = self.roi
        return slice(r0, r1), slice(c0, c1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "master_height_mm": self.master_height_mm,
            "method": self.method,
            "decode": self.decode.to_dict(),
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
        check_keys("calibration", data, {f for f in cls.__dataclass_fields__})
        values = dict(data)
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
    rig: Rig,
    reference: npt.ArrayLike,
    masters: Sequence[npt.ArrayLike],
    options: CalibrateOptions,
    *,
    threads: int | None = None,
) -> CalibrateResult:
    """Calibrate ``rig`` (the starting values) on captures of a master block.

    Parameters
    ----------
    rig : Rig
        Initial estimates of L, alpha (and d) and the fixed FW, nlp, image size.
    reference : (11, H, W) image stack
        The reference plane.
    masters : sequence of (11, H, W) image stacks
        The master block on the reference plane (one for the paper's method).
    options : CalibrateOptions

    Raises
    ------
    ValueError
        On a bad option, stack or shape, or no master.
    """
    if not masters:
        raise ValueError("masters: at least one master capture is needed")
    if options.method == "paper" and len(masters) != 1:
        raise ValueError(f"method 'paper' takes one master capture, got {len(masters)}")
    timer = PhaseTimer()
    with timer.phase("decode"):
        kept = core_measure.prepare_reference(rig, reference, options.decode)
        ref_codes = kept.decoded.codes
        master_codes = [
            core_measure.measure_height(rig, kept, stack, options.decode, gray_only=False, threads=threads).obj_codes
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
