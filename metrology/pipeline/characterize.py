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
from metrology.core.codecs.decode import decode_codec, validate_codec_stack
from metrology.core.codecs.model import Codec
from metrology.core.distortion import undistort_pixels
from metrology.core.geometry.pinhole import PinholeReference, PinholeRig
from metrology.core.measure import DecodeOptions
from metrology.core.pinhole_measure import measure_pinhole
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


def pinhole_test_point_frame(rig: PinholeRig, reference: PinholeReference) -> core.TestPointFrame:
    """Test-point coordinates of a pinhole rig: camera-frame ``(X, Y)`` (mm) of the point of the
    reference plane each pixel's ray meets.

    Ray of pixel ``(r, c)``: ``t (x_n, y_n, 1)`` (undistorted normalized coordinates); on the
    plane ``n . (p - c0) = 0`` at ``t = n . c0 / n . (x_n, y_n, 1)``. The field centre is the
    principal point's ray, ``t (0, 0, 1)``.
    """
    h, w = rig.shape
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = undistort_pixels(np.asarray(rig.camera.K, np.float64), rig.camera.distortion, cols, rows)
    xn, yn = np.asarray(rays.x, np.float64), np.asarray(rays.y, np.float64)
    n, c0 = np.asarray(reference.normal, np.float64), np.asarray(reference.centroid, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(n @ c0) / (n[0] * xn + n[1] * yn + n[2])
    return core.TestPointFrame(x_mm=t * xn, y_mm=t * yn, centre_x_mm=0.0)


def heights_above(points_mm: np.ndarray, reference: PinholeReference) -> np.ndarray:
    """``(H, W)`` float32 heights (mm) of ``(H, W, 3)`` camera-frame points above the reference
    plane: ``n . (p - c0)``, positive towards the camera, NaN where a point is NaN."""
    n, c0 = np.asarray(reference.normal, np.float64), np.asarray(reference.centroid, np.float64)
    return ((points_mm.astype(np.float64) - c0) @ n).astype(np.float32)


def _pinhole_check(stack: npt.ArrayLike, codec: Codec, rig: PinholeRig, label: str) -> np.ndarray:
    checked = validate_codec_stack(np.asarray(stack), codec)
    if tuple(checked.shape[1:]) != rig.shape:
        h, w = checked.shape[1:]
        cam = f"{rig.camera.width_px}x{rig.camera.height_px}"
        raise ValueError(f"the {label} frames are {w}x{h} px but the rig's camera is {cam} px")
    return checked


def _uv(decoding: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    u = decoding.axes["u"].coordinate if "u" in decoding.axes else None
    v = decoding.axes["v"].coordinate if "v" in decoding.axes else None
    return u, v


def characterize_pinhole(
    rig: PinholeRig,
    reference: npt.ArrayLike,
    series: SeriesStacks,
    codec: Codec,
    options: CharacterizeOptions | None = None,
    *,
    triangulate: str = "auto",
    threads: int | None = None,
) -> CharacterizeResult:
    """Section 5's figures for a pinhole rig (docs/pinhole.md): each stage capture's heights above
    the total-least-squares plane of the reference capture (positive towards the camera) feed
    :func:`metrology.core.characterize.characterize`, with test points along camera columns of the
    chosen rows and their ``x_mm``, ``y_mm`` the camera-frame point of the reference plane each
    patch centre sees (:func:`pinhole_test_point_frame`).

    The stage must move the plane along the reference plane's normal: the heights are distances
    along that normal, so a stage inclined by ``a`` to it reads slopes ``cos a``.

    Parameters
    ----------
    rig : PinholeRig
    reference : (frames, H, W) image stack of ``codec``
        The reference plane, decoded once.
    series : iterable of (z_in_mm, repeat, (frames, H, W) image stack of ``codec``)
    codec : Codec
    options : CharacterizeOptions, optional
        ``decode`` (the crossed-axes decoder's options) is not used by the codec decoder.
    triangulate : {'auto', 'u', 'v'}

    Returns
    -------
    CharacterizeResult
        The report of :func:`metrology.core.characterize.characterize` plus ``model``
        (``"pinhole"``), ``triangulate`` (the axis used) and ``reference_plane`` (``centroid_mm``,
        unit ``normal`` towards the camera, ``points``).

    Raises
    ------
    ValueError
        On a bad option, stack, shape or stage position.
    """
    options = options or CharacterizeOptions()
    timer = PhaseTimer()
    size = (codec.projector_width, codec.projector_height)
    with timer.phase("reference"):
        ref_uv = _uv(decode_codec(_pinhole_check(reference, codec, rig, "reference"), codec, threads=threads))
        prepared = rig.prepare(rig.shape, size, axis=triangulate)
        plane = prepared.reference(*ref_uv, threads=threads)
        frame = pinhole_test_point_frame(rig, plane)

    def heights() -> Iterable[tuple[float, int, np.ndarray]]:
        for z_in, repeat, stack in series:
            if not math.isfinite(z_in):
                raise ValueError(f"z_in_mm must be finite, got {z_in!r}")
            with timer.phase("measure series"):
                checked = _pinhole_check(stack, codec, rig, f"stage capture at z_in_mm = {z_in}")
                u, v = _uv(decode_codec(checked, codec, threads=threads))
                points = measure_pinhole(rig, u, v, axis=triangulate, projector_size=size, threads=threads).points_mm
                z = heights_above(points, plane)
            yield float(z_in), repeat, z

    rows = list(options.rows) if isinstance(options.rows, tuple) else options.rows
    with timer.phase("statistics"):
        report = core.characterize(
            frame,
            heights(),
            n_points=options.n_points,
            rows=rows,
            patch_px=options.patch_px,
            margin_frac=options.margin_frac,
        )
    report["model"] = "pinhole"
    report["triangulate"] = prepared.axis
    report["reference_plane"] = {
        "centroid_mm": plane.centroid.tolist(),
        "normal": plane.normal.tolist(),
        "points": plane.n_points,
    }
    return CharacterizeResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
