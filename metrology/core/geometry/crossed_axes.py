"""The paper's crossed-optical-axes model (gcps-v1; docs/conventions.md, "Crossed-axes rig").

Everything that knows the paper's geometry lives here: the rig's seven values and their
derived constants (Eqs. 7, 12, 13, 15), the code-to-abscissa map (Eq. 14, as a Mobius map),
heights from codes (Eqs. 16-17), the camera rays, and the model's implementation of the
geometric seam (:class:`~metrology.core.geometry.base.GeometryModel`).

Geometry (paper Figs. 1 and 3)::

    P (0, 0, L)  projector pupil          C (d, 0, L)  camera pupil
    R: Z = 0, heights positive towards the rig
    camera field on R: X in [d - FW/2, d + FW/2], centred under C
    pixel (k, j) looks at A = (x_A, Y_A, 0) of R along the camera ray CA:
    x_A = d - FW/2 + (j + 0.5) FW / N,  Y_A = (k + 0.5 - M/2) FW / N
    the point of ray CA at height z: X_H = d + (1 - z/L)(x_A - d),  Y_H = (1 - z/L) Y_A

All array functions are vectorised over arrays of any shape and keep the input's floating
dtype (float32 stays float32: the fast path). NaN propagates, so an invalid code gives a NaN
height.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Collection, Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.base import (
    CameraRays,
    GeometryError,
    GeometryModel,
    GeometryOptions,
    HeightTerms,
    ImageAxes,
    ParameterField,
    PlaneCoordinates,
    PreparedGeometry,
    ReferenceSurface,
    check_axes,
    check_frame,
    subpixel_grid,
)
from metrology.core.geometry.rig_file import MAX_IMAGE_SIDE_PX, MAX_TRANSLATION_MM
from metrology.core.tiling import run_tiled, thread_scratch

FloatArray = npt.NDArray[np.floating]

MODEL = "crossed_axes"

REQUIRED_KEYS: tuple[str, ...] = (
    "L_mm",
    "d_mm",
    "alpha_rad",
    "fw_mm",
    "nlp",
    "width_px",
    "height_px",
)

PARAMETER_FIELDS: tuple[ParameterField, ...] = (
    ParameterField("L_mm", "Height of the pupils above the reference plane", "mm"),
    ParameterField("d_mm", "Projector-camera baseline", "mm"),
    ParameterField("alpha_rad", "Tilt of the projector sensor plane", "rad"),
    ParameterField("fw_mm", "Camera field width on the reference plane", "mm"),
    ParameterField("nlp", "Light codes across the field (at most 128)", "", integer=True),
    ParameterField("width_px", "Camera image width", "px", integer=True),
    ParameterField("height_px", "Camera image height", "px", integer=True),
)
"""The seven values of the rig file, as forms show them (:attr:`Rig.scalar_parameters`)."""


class RigError(GeometryError):
    """A rig description is missing a key or holds a value out of range."""


@dataclass(frozen=True)
class MobiusMap:
    """Eq. 14 written as a Mobius (linear fractional) map of the light code.

    ``x(l) = L * (t + p * l) / (1 + q * l)`` with ``t = tan(gamma)``,
    ``p = t * b + a``, ``q = b - a * t``, ``a = C1 cos(gamma - alpha)`` and
    ``b = C1 sin(gamma - alpha)``. Expanding ``tan(gamma + atan(u))`` with the
    tangent addition formula gives this form exactly, so triangulation needs no
    trigonometry.
    """

    L_mm: float
    t: float
    p: float
    q: float


@dataclass(frozen=True)
class Rig(GeometryModel):
    """Geometry of a crossed-optical-axes projector-camera rig (docs/conventions.md, "Rig file").

    The paper's model: a :class:`~metrology.core.geometry.base.GeometryModel` whose rig file has
    no ``model`` key (or ``"model": "crossed_axes"``).

    Parameters
    ----------
    L_mm : float
        Height of both pupils above the reference plane R, mm, > 0.
    d_mm : float
        Baseline: X of the camera pupil C, measured from Q (foot of P), mm, > 0.
    alpha_rad : float
        Tilt of the projector sensor plane to R, rad, in (0, pi/2).
    fw_mm : float
        Width of the camera field on R along X, mm, > 0.
    nlp : int
        Number of light codes spanning the field (l = 0 on ray PS, nlp on PT), > 0.
    width_px, height_px : int
        Camera image size N x M, pixels, > 0. Pixels are square.
    extra : dict
        Further keys of the rig file (name, notes, calibration...), kept verbatim.

    Raises
    ------
    RigError
        If a value is out of range.
    """

    L_mm: float
    d_mm: float
    alpha_rad: float
    fw_mm: float
    nlp: int
    width_px: int
    height_px: int
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    model: ClassVar[str] = MODEL
    label: ClassVar[str] = "Crossed optical axes (the paper's model)"
    short_label: ClassVar[str] = "crossed-axes"
    requires_reference: ClassVar[bool] = True
    unreferenced_result: ClassVar[str] = "height"
    frame: ClassVar[str] = "paper"
    sigma_direction: ClassVar[str] = "height"
    calibration_parameters: ClassVar[tuple[str, ...]] = ("L_mm", "alpha_rad", "d_mm")
    scalar_parameters: ClassVar[tuple[ParameterField, ...]] = PARAMETER_FIELDS

    def __post_init__(self) -> None:
        for name in ("L_mm", "d_mm", "fw_mm"):
            value = getattr(self, name)
            if not _is_real(value) or not math.isfinite(value) or value <= 0:
                raise RigError(f"rig {name} must be a positive finite number, got {value!r}")
        if not _is_real(self.alpha_rad) or not (0.0 < self.alpha_rad < math.pi / 2):
            raise RigError(f"rig alpha_rad must lie in (0, pi/2), got {self.alpha_rad!r}")
        for name in ("nlp", "width_px", "height_px"):
            value = getattr(self, name)
            if not _is_integral(value) or value <= 0:
                raise RigError(f"rig {name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("L_mm", "d_mm", "alpha_rad", "fw_mm"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.nlp > 128:
            raise RigError(f"rig nlp must be at most 128 (7-bit gray code), got {self.nlp}")
        # the pinhole model's bounds (rig_file.py): lengths as its translations, sides as its camera's
        for name in ("L_mm", "d_mm", "fw_mm"):
            if getattr(self, name) > MAX_TRANSLATION_MM:
                raise RigError(f"rig {name} must be at most {MAX_TRANSLATION_MM:g} mm, got {getattr(self, name)!r}")
        for name in ("width_px", "height_px"):
            if getattr(self, name) > MAX_IMAGE_SIDE_PX:
                raise RigError(f"rig {name} must be at most {MAX_IMAGE_SIDE_PX} pixels, got {getattr(self, name)!r}")
        if self.fw_mm / 2 - self.d_mm >= self.L_mm * 50:
            raise RigError("rig field extends implausibly far behind the projector")
        if not (0.0 < self.theta_tot_rad < math.pi):
            raise RigError(
                "rig alpha_rad, L_mm, d_mm and fw_mm give a degenerate projector plane "
                f"(theta_tot = {self.theta_tot_rad:.4f} rad)"
            )

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Rig:
        """Build a rig from its JSON object (docs/conventions.md); unknown keys go to ``extra``.

        A ``"model"`` key, when present, must be ``"crossed_axes"`` and is not kept.
        """
        if not isinstance(data, Mapping):
            raise RigError(f"rig must be a JSON object, got {type(data).__name__}")
        if "model" in data:
            if data["model"] != MODEL:
                raise RigError(f"rig model must be {MODEL!r} for this rig, got {data['model']!r}")
            data = {key: value for key, value in data.items() if key != "model"}
        missing = [key for key in REQUIRED_KEYS if key not in data]
        if missing:
            raise RigError(f"rig is missing required key(s): {', '.join(missing)}")
        extra = {key: value for key, value in data.items() if key not in REQUIRED_KEYS}
        return cls(**{key: data[key] for key in REQUIRED_KEYS}, extra=extra)

    @classmethod
    def from_json(cls, text: str) -> Rig:
        """Parse a rig file's text."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RigError(f"rig file is not valid JSON: {exc.msg} at line {exc.lineno}") from exc
        except RecursionError:
            raise RigError("rig file is nested too deeply to be a rig file") from None
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object: the seven required keys, then ``extra`` (no ``model`` key:
        a rig file without one is a crossed-axes rig)."""
        data = asdict(self)
        extra = data.pop("extra")
        data.update(extra)
        return data

    def with_parameters(self, **changes: Any) -> Rig:
        """A copy with some geometric values replaced (e.g. calibrated L and alpha)."""
        return replace(self, **changes)

    @property
    def camera_centre_mm(self) -> np.ndarray:
        """C = (d, 0, L)."""
        return np.array([self.d_mm, 0.0, self.L_mm])

    def footprint_mm(self, points_mm: np.ndarray | None = None) -> float:
        """``FW / N``: a pixel's size on R (whatever the points)."""
        return self.pixel_mm

    def check_codec(
        self, projector_size: tuple[float, float], coded_axes: Collection[str], options: GeometryOptions | None = None
    ) -> None:
        """The rig triangulates projector columns: the codec must code u (of any projector size)."""
        _check_options(options)
        if "u" not in coded_axes:
            raise GeometryError(
                "the codec does not code the projector's u axis (columns), which a crossed-axes rig "
                f"triangulates; it codes {', '.join(sorted(coded_axes)) or 'no axis'}"
            )

    def value_rows(self) -> list[tuple[str, str]]:
        """L, d (0.1 um), alpha (1 urad), FW (1 um): finer than a calibration moves them, without
        float noise (trailing zeros dropped: ``1022 mm``); nlp and the image size."""
        return [
            ("L", f"{_decimals(self.L_mm, 4)} mm"),
            ("d", f"{_decimals(self.d_mm, 4)} mm"),
            ("alpha", f"{_decimals(self.alpha_rad, 6)} rad"),
            ("FW", f"{_decimals(self.fw_mm, 3)} mm"),
            ("nlp", str(self.nlp)),
            ("image", f"{self.width_px} x {self.height_px} px"),
        ]

    def parameters(self) -> dict[str, Any]:
        """The seven values (``extra`` is not a parameter of the model)."""
        return {key: getattr(self, key) for key in REQUIRED_KEYS}

    def image_axes(self) -> ImageAxes:
        """X of each column's point A on R and Y of each row's, mm (:meth:`column_x_mm`, :meth:`row_y_mm`)."""
        return ImageAxes(x=self.column_x_mm(), y=self.row_y_mm(), x_label="X (mm)", y_label="Y (mm)", unit="mm")

    def scene_distance_mm(self, field_width_mm: float) -> float:
        """``L``: the scenes stand on R."""
        return self.L_mm

    @property
    def scene_centre_x_mm(self) -> float:
        """``d``: the camera field is centred under C."""
        return self.d_mm

    @classmethod
    def example_parameters(cls) -> dict[str, Any]:
        """The paper's calibrated rig (section 5) at 320 x 240 px: a small frame, quick to simulate."""
        return {
            "L_mm": 1022.0,
            "d_mm": 352.0,
            "alpha_rad": 0.332,
            "fw_mm": 500.0,
            "nlp": 128,
            "width_px": 320,
            "height_px": 240,
        }

    @property
    def light_codes(self) -> int:
        """``nlp``: prepared without a projector size, the model reads ``u`` as light codes."""
        return self.nlp

    # ------------------------------------------------- derived constants
    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height_px, width_px)``."""
        return (self.height_px, self.width_px)

    @property
    def gamma_rad(self) -> float:
        """Eq. 7: angle between ray PS and the perpendicular PQ, rad (may be negative)."""
        return math.atan((self.d_mm - self.fw_mm / 2) / self.L_mm)

    @property
    def _atan_pt(self) -> float:
        return math.atan((self.L_mm * math.tan(self.gamma_rad) + self.fw_mm) / self.L_mm)

    @property
    def delta_tot_rad(self) -> float:
        """Eq. 12: angle between rays PS and PT, rad."""
        return self._atan_pt - self.gamma_rad

    @property
    def theta_tot_rad(self) -> float:
        """Eq. 13: angle at T' between the line ST' and ray PT, rad."""
        return math.pi / 2 + self.alpha_rad - self._atan_pt

    @property
    def C1(self) -> float:
        """Eq. 15: ``sin(delta_tot) / (nlp sin(theta_tot))``, per code unit."""
        return math.sin(self.delta_tot_rad) / (self.nlp * math.sin(self.theta_tot_rad))

    @property
    def mobius(self) -> MobiusMap:
        """Coefficients of Eq. 14 as a Mobius map of the code (see :class:`MobiusMap`)."""
        g = self.gamma_rad
        a = self.C1 * math.cos(g - self.alpha_rad)
        b = self.C1 * math.sin(g - self.alpha_rad)
        t = math.tan(g)
        return MobiusMap(L_mm=self.L_mm, t=t, p=t * b + a, q=b - a * t)

    @property
    def pixel_mm(self) -> float:
        """Size of one camera pixel projected on R, mm."""
        return self.fw_mm / self.width_px

    def column_x_mm(self, dtype: type = np.float64) -> np.ndarray:
        """X of point A on R seen by each column j: ``(width_px,)`` array, mm."""
        j = np.arange(self.width_px, dtype=np.float64)
        x = self.d_mm - self.fw_mm / 2 + (j + 0.5) * self.pixel_mm
        return x.astype(dtype)

    def row_y_mm(self, dtype: type = np.float64) -> np.ndarray:
        """Y of point A on R seen by each row k: ``(height_px,)`` array, mm."""
        k = np.arange(self.height_px, dtype=np.float64)
        y = (k + 0.5 - self.height_px / 2) * self.pixel_mm
        return y.astype(dtype)

    # ------------------------------------------------------ geometric seam
    def prepare(
        self,
        shape: tuple[int, int] | None = None,
        projector_size: tuple[float, float] | None = None,
        options: GeometryOptions | None = None,
    ) -> PreparedCrossedAxes:
        """This rig prepared for frames of ``shape`` (see :meth:`GeometryModel.prepare`).

        ``projector_size = (width, height)``: the projector coordinates passed to the prepared
        model are a codec's, mapped to light codes by ``l = (u + 0.5) nlp / width``; None: they
        are light codes already (the gcps-v1 decoder's output). Cached per rig and sizes.
        ``options``: the rig triangulates its u axis by its light planes only (``triangulate``
        ``auto`` or ``u``, ``method`` ``plane``).
        """
        _check_options(options)
        shape = self.shape if shape is None else (int(shape[0]), int(shape[1]))
        if shape != self.shape:
            raise GeometryError(
                f"frames are {shape[1]}x{shape[0]} px but the rig is {self.width_px}x{self.height_px} px"
            )
        if projector_size is not None:
            width, height = (float(v) for v in projector_size)
            if not (math.isfinite(width) and math.isfinite(height) and width > 0 and height > 0):
                raise GeometryError(f"projector_size must be two positive numbers, got {projector_size!r}")
            projector_size = (width, height)
        return _prepare(self, projector_size)


def _check_options(options: GeometryOptions | None) -> None:
    if options is not None and (
        options.triangulate not in ("auto", "u") or options.method != "plane" or options.match != "epipolar"
    ):
        raise GeometryError(
            "a crossed-axes rig triangulates the projector's u axis by its light planes "
            f"(triangulate auto or u, method plane), got triangulate {options.triangulate!r}, "
            f"method {options.method!r}, match {options.match!r}"
        )


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _is_integral(value: Any) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    return isinstance(value, (float, np.floating)) and float(value).is_integer()


@functools.lru_cache(maxsize=16)
def _prepare(rig: Rig, projector_size: tuple[float, float] | None) -> PreparedCrossedAxes:
    return PreparedCrossedAxes(rig, projector_size)


PAPER_RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=640, height_px=480)
"""The calibrated rig of the paper's section 5, at the VGA size used by the tests."""


def _as_float(values: npt.ArrayLike) -> FloatArray:
    array = np.asarray(values)
    if array.dtype.kind != "f":
        array = array.astype(np.float64)
    return array


def abscissa_from_codes_eq14(rig: Rig, codes: npt.ArrayLike) -> FloatArray:
    """Eq. 14 literally: ``x = L tan(gamma + atan(C1 l cos(g-a) / (1 + C1 l sin(g-a))))``.

    The reference implementation, kept to test the Mobius form against.

    Parameters
    ----------
    rig : Rig
    codes : array_like of float, any shape
        Light codes, code units (0 on ray PS, nlp on ray PT).

    Returns
    -------
    x_mm : ndarray, same shape, float64 unless ``codes`` is float32
        Abscissa on R where the light ray of each code lands, mm from Q.
    """
    l = _as_float(codes)
    g, a = rig.gamma_rad, rig.alpha_rad
    u = rig.C1 * l * math.cos(g - a) / (1 + rig.C1 * l * math.sin(g - a))
    return (rig.L_mm * np.tan(g + np.arctan(u))).astype(l.dtype, copy=False)


def abscissa_from_codes(rig: Rig, codes: npt.ArrayLike) -> FloatArray:
    """Eq. 14 as a Mobius map: ``x = L (t + p l) / (1 + q l)``, no trigonometry.

    Parameters
    ----------
    rig : Rig
    codes : array_like of float, any shape
        Light codes, code units; NaN where invalid.

    Returns
    -------
    x_mm : ndarray, same shape and float dtype as ``codes`` (float64 for ints)
        Abscissa on R, mm from Q. ``x(0) = d - FW/2`` and ``x(nlp) = d + FW/2``.

    Examples
    --------
    >>> from metrology.core.geometry.crossed_axes import PAPER_RIG as rig
    >>> [round(float(x), 9) for x in abscissa_from_codes(rig, [0.0, rig.nlp])]
    [102.0, 602.0]
    """
    l = _as_float(codes)
    m = rig.mobius
    dt = l.dtype.type
    return dt(m.L_mm) * (dt(m.t) + dt(m.p) * l) / (dt(1.0) + dt(m.q) * l)


def codes_from_abscissa(rig: Rig, x_mm: npt.ArrayLike) -> FloatArray:
    """Inverse of Eq. 14: the light code whose ray lands at abscissa ``x_mm`` on R.

    Parameters
    ----------
    rig : Rig
    x_mm : array_like of float, any shape
        Abscissa on R, mm from Q.

    Returns
    -------
    codes : ndarray, same shape
        Light codes, code units (may fall outside [0, nlp] off the coded field).
    """
    x = _as_float(x_mm)
    m = rig.mobius
    s = x / m.L_mm
    return (s - m.t) / (m.p - m.q * s)


def height_from_abscissae(rig: Rig, x_ref_mm: npt.ArrayLike, x_obj_mm: npt.ArrayLike) -> FloatArray:
    """Eqs. 5 and 17: ``z = L D / (d + D)`` with ``D = x_obj - x_ref``.

    Parameters
    ----------
    x_ref_mm, x_obj_mm : array_like of float, broadcastable
        Abscissae of the reference and object codes, mm.

    Returns
    -------
    z_mm : ndarray
        Height above R, mm.
    """
    return height_from_displacement(rig, _as_float(x_obj_mm) - _as_float(x_ref_mm))


def height_from_displacement(rig: Rig, displacement_mm: npt.ArrayLike) -> FloatArray:
    """Eqs. 5 and 17: ``z = L D / (d + D)`` from the displacement ``D = x_obj - x_ref`` on R, mm."""
    d_r = _as_float(displacement_mm)
    dt = d_r.dtype.type
    return dt(rig.L_mm) * d_r / (dt(rig.d_mm) + d_r)


def reference_slope_mm(rig: Rig, ref_codes: npt.ArrayLike, out: np.ndarray | None = None) -> FloatArray:
    """``L (p - t q) / (1 + q r)`` of reference codes ``r``, mm per code (Eq. 14 as a Mobius map).

    Times ``(l - r) / (1 + q l)`` it is the displacement ``x(l) - x(r)`` on R: the
    difference of two Mobius values, ``L (p - t q)(l - r) / ((1 + q l)(1 + q r))``,
    without subtracting two abscissae of ~500 mm (in float32 that alone costs 0.4 um
    of height). Written into ``out`` when given (same shape, float dtype).
    """
    r = _as_float(ref_codes)
    dt = (out if out is not None else r).dtype.type
    m = rig.mobius
    den = np.multiply(r, dt(m.q), out=out)
    den += dt(1)
    return np.divide(dt(m.L_mm * (m.p - m.t * m.q)), den, out=den)


def displacement_from_codes(rig: Rig, ref_codes: npt.ArrayLike, obj_codes: npt.ArrayLike) -> FloatArray:
    """Eq. 16: the displacement ``D_R = x(OBJ) - x(REF)`` on R of each pixel, mm, from its codes
    (see :func:`reference_slope_mm`); NaN where either code is NaN."""
    r, l = _as_float(ref_codes), _as_float(obj_codes)
    dt = np.result_type(r, l).type
    return reference_slope_mm(rig, r) * (l - r) / (dt(1) + dt(rig.mobius.q) * l)


def height_from_codes(rig: Rig, ref_codes: npt.ArrayLike, obj_codes: npt.ArrayLike) -> FloatArray:
    """Eqs. 16-17: heights from the reference (REF) and object (OBJ) code maps.

    Parameters
    ----------
    rig : Rig
    ref_codes, obj_codes : array_like of float, shape (H, W) (or broadcastable)
        Light codes in code units, NaN where invalid.

    Returns
    -------
    z_mm : ndarray, shape (H, W), float32 when both inputs are float32
        Height above R, mm; NaN where either code is NaN.
    """
    return height_from_displacement(rig, displacement_from_codes(rig, ref_codes, obj_codes))


def camera_ray_point(
    rig: Rig, x_a_mm: npt.ArrayLike, y_a_mm: npt.ArrayLike, z_mm: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """The point at height ``z`` of the camera ray CA through A = ``(x_A, Y_A, 0)`` of R.

    ``X_H = d + (1 - z/L)(x_A - d)``, ``Y_H = (1 - z/L) Y_A`` (the camera pupil C is at
    ``(d, 0, L)``).

    Parameters
    ----------
    x_a_mm, y_a_mm, z_mm : array_like of float, broadcastable
        Foot of the ray on R and height, mm.

    Returns
    -------
    (X_H, Y_H) : ndarrays, broadcast shape, float64 unless all inputs are float32
    """
    z = _as_float(z_mm)
    dt = np.result_type(z, _as_float(x_a_mm), _as_float(y_a_mm)).type
    scale = dt(1) - z / dt(rig.L_mm)
    d = dt(rig.d_mm)
    return d + scale * (_as_float(x_a_mm) - d), scale * _as_float(y_a_mm)


def projector_abscissa(rig: Rig, x_mm: npt.ArrayLike, z_mm: npt.ArrayLike) -> FloatArray:
    """Where the projector's light ray through a point ``(X, ., z)`` lands on R: ``x_B = X L / (L - z)``, mm.

    The projector pupil P is at ``(0, 0, L)``; the light planes are parallel to Y.
    """
    x, z = _as_float(x_mm), _as_float(z_mm)
    return x * rig.L_mm / (rig.L_mm - z)


def codes_of_points(rig: Rig, x_mm: npt.ArrayLike, z_mm: npt.ArrayLike) -> FloatArray:
    """The light code lighting a point ``(X, ., z)``: the inverse of Eq. 14 at :func:`projector_abscissa`."""
    return codes_from_abscissa(rig, projector_abscissa(rig, x_mm, z_mm))


def codes_on_camera_rays(rig: Rig, z_mm: npt.ArrayLike) -> FloatArray:
    """The light code each pixel sees on a surface of heights ``z`` (camera ray, then projector ray).

    Parameters
    ----------
    z_mm : float or (height_px, width_px) array_like
        Height seen by each pixel, mm (a scalar: a plane parallel to R).

    Returns
    -------
    codes : (height_px, width_px) float64 array, code units (outside [0, nlp] off the coded field).
    """
    z = np.broadcast_to(np.asarray(z_mm, dtype=np.float64), rig.shape)
    x_h, _ = camera_ray_point(rig, rig.column_x_mm()[None, :], 0.0, z)
    return codes_of_points(rig, x_h, z)


def light_codes_from_projector(rig: Rig, u: npt.ArrayLike, projector_width: float) -> FloatArray:
    """A codec's projector coordinate ``u`` (projector units, column j centred at j) as the
    paper's light code: ``l = (u + 0.5) nlp / width``."""
    x = _as_float(u)
    dt = x.dtype.type
    scale = dt(rig.nlp / projector_width)
    return (x + dt(0.5)) * scale


def points_from_heights(rig: Rig, z_mm: npt.ArrayLike) -> FloatArray:
    """3D coordinates of every pixel (docs/conventions.md): ``(X_H, Y_H, z)``.

    ``X_H = d + (1 - z/L)(x_A - d)`` and ``Y_H = (1 - z/L) Y_A`` place each
    measured point on its camera ray CA (:func:`camera_ray_point`).

    Parameters
    ----------
    rig : Rig
    z_mm : array_like, shape (height_px, width_px)
        Height map, mm, NaN where not measured.

    Returns
    -------
    xyz_mm : ndarray, shape (height_px, width_px, 3), float64
        X, Y, Z of each pixel's point, mm; NaN rows where ``z`` is NaN.
    """
    z = np.asarray(z_mm, dtype=np.float64)
    if z.shape != rig.shape:
        raise ValueError(f"z_mm must have the rig's shape {rig.shape}, got {z.shape}")
    xyz = np.empty((*z.shape, 3), dtype=np.float64)
    xyz[..., 0], xyz[..., 1] = camera_ray_point(rig, rig.column_x_mm()[None, :], rig.row_y_mm()[:, None], z)
    xyz[..., 2] = z
    return xyz


# --------------------------------------------------------------------------- the prepared model
@dataclass(frozen=True)
class CrossedAxesReference(ReferenceSurface):
    """The reference plane R as captured: its light codes and their Eq. 14 slopes.

    Attributes
    ----------
    codes : (H, W) float32 array
        Reference light codes ``r`` (REF of Eq. 16), code units, NaN where invalid.
    slope_mm : (H, W) float32 array
        :func:`reference_slope_mm` of each code, ``L (p - t q) / (1 + q r)``, mm per code:
        times ``(l - r) / (1 + q l)`` it is the displacement ``D_R = x(l) - x(r)`` on R
        without subtracting two abscissae of ~500 mm (in float32 a 0.4 um height error).
    """

    codes: np.ndarray
    slope_mm: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.codes.shape[0]), int(self.codes.shape[1]))


def reference_from_codes(rig: Rig, codes: np.ndarray, threads: int | None = None) -> CrossedAxesReference:
    """:class:`CrossedAxesReference` of a (H, W) float32 map of reference light codes, tile by tile."""
    height, width = codes.shape
    slope = np.empty((height, width), np.float32)
    run_tiled(lambda rows: reference_slope_mm(rig, codes[rows], out=slope[rows]), height, width, threads)
    return CrossedAxesReference(codes=codes, slope_mm=slope)


class PreparedCrossedAxes(PreparedGeometry):
    """A :class:`Rig` prepared for its frame size (see :class:`~metrology.core.geometry.base.PreparedGeometry`).

    Tables: the foot ``(x_A, Y_A)`` of every camera ray on R, and the *modelled* reference:
    the code ``r_A`` whose light lands at ``x_A`` (inverse of Eq. 14) with its slope, which
    makes the absolute triangulation ``z = L (x(l) - x_A) / (d + x(l) - x_A)`` the same
    cancellation-free float32 kernel as the one against a captured reference.
    """

    def __init__(self, rig: Rig, projector_size: tuple[float, float] | None) -> None:
        self.model = rig
        self.rig = rig
        self.shape = rig.shape
        self.projector_size = projector_size
        self.axis = "u"
        self.method = "plane"
        self.code_scale_u = None if projector_size is None else np.float32(rig.nlp / projector_size[0])
        height, width = rig.shape
        self.x_a_mm = rig.column_x_mm()
        self.y_a_mm = rig.row_y_mm()
        self._x_rel32 = (self.x_a_mm - rig.d_mm).astype(np.float32)[None, :]
        self._y_a32 = self.y_a_mm.astype(np.float32)[:, None]
        r_a = codes_from_abscissa(rig, self.x_a_mm)
        self._model_codes = np.broadcast_to(r_a.astype(np.float32)[None, :], (height, width))
        self._model_slope = np.broadcast_to(reference_slope_mm(rig, r_a).astype(np.float32)[None, :], (height, width))
        m = rig.mobius
        self._L, self._q, self._d = (np.float32(v) for v in (m.L_mm, m.q, rig.d_mm))
        self._inv_L = np.float32(1.0 / rig.L_mm)

    @property
    def required_axes(self) -> tuple[str, ...]:
        return ("u",)

    @property
    def has_model_plane(self) -> bool:
        return True

    def camera_rays(self, supersample: int = 1) -> CameraRays:
        """Rays from C = (d, 0, L) to the points A of R each pixel (or sub-pixel) sees."""
        rig = self.rig
        pitch = rig.pixel_mm
        x_a = rig.d_mm - rig.fw_mm / 2 + (subpixel_grid(rig.width_px, supersample) + 0.5) * pitch
        y_a = (subpixel_grid(rig.height_px, supersample) + 0.5 - rig.height_px / 2) * pitch
        direction = np.empty((y_a.size, x_a.size, 3), np.float64)
        direction[..., 0] = (x_a - rig.d_mm)[None, :]
        direction[..., 1] = y_a[:, None]
        direction[..., 2] = -rig.L_mm
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        return CameraRays(origin_mm=np.array([rig.d_mm, 0.0, rig.L_mm]), direction=direction)

    @property
    def projector_centre_mm(self) -> np.ndarray:
        """P = (0, 0, L)."""
        return np.array([0.0, 0.0, self.rig.L_mm])

    def projector_coordinates(self, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``u = l w / nlp - 0.5`` from the light code ``l`` of each point (the light plane through it,
        :func:`codes_of_points`; ``l`` itself without a projector size) and ``v`` the projector row
        that lights it: from P, a point (X, Y, z) lands on R at ``Y_R = Y L / (L - z)``, and the
        camera field's height ``FH = FW H / W`` on R spans the projector's rows,
        ``v = (Y_R / FH + 0.5) h - 0.5`` (:func:`~metrology.core.codecs.render.crossed_rig_truth`)."""
        rig = self.rig
        p = np.asarray(points_mm, dtype=np.float64)
        X, Y, z = p[..., 0], p[..., 1], p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            l = np.asarray(codes_of_points(rig, X, z), dtype=np.float64)
            behind = ~(z < rig.L_mm)
            if self.projector_size is None:
                return np.where(behind, np.nan, l), np.full(l.shape, np.nan)
            width, height = self.projector_size
            u = l * (width / rig.nlp) - 0.5
            field_h = rig.fw_mm * rig.height_px / rig.width_px
            v = (Y * rig.L_mm / (rig.L_mm - z) / field_h + 0.5) * height - 0.5
        return np.where(behind, np.nan, u), np.where(behind, np.nan, v)

    def code_scale(self, axis: str) -> float:
        """Light codes per projector unit of ``u``: ``nlp / width`` (1 without a projector size)."""
        return 1.0 if self.code_scale_u is None else float(self.code_scale_u)

    def plane_coordinates(self, reference: ReferenceSurface | None = None) -> PlaneCoordinates:
        """The paper's ``(x_A, Y_A)`` of each pixel on R (the captured reference plane is R); the
        field centre is ``x = d``, under the camera."""
        rig = self.rig
        x = np.broadcast_to(self.x_a_mm[None, :], rig.shape)
        y = np.broadcast_to(self.y_a_mm[:, None], rig.shape)
        return PlaneCoordinates(x_mm=x, y_mm=y, centre_x_mm=rig.d_mm)

    def light_codes(self, u: np.ndarray) -> np.ndarray:
        """``u`` as float32 light codes: unchanged without a projector size, else ``(u + 0.5) nlp / width``."""
        if self.projector_size is None:  # (code_scale is None then too)
            return u if u.dtype == np.float32 else u.astype(np.float32)
        return light_codes_from_projector(self.rig, u.astype(np.float32, copy=False), self.projector_size[0])

    def reference(self, u: np.ndarray | None, v: np.ndarray | None, threads: int | None = None) -> CrossedAxesReference:
        check_axes(self, u, v)
        assert u is not None
        check_frame(self, "u", u)
        return reference_from_codes(self.rig, self.light_codes(u), threads)

    def triangulate_rows(
        self,
        rows: slice,
        u: np.ndarray | None,
        v: np.ndarray | None,
        *,
        reference: ReferenceSurface | None = None,
        points_out: np.ndarray | None = None,
        height_out: np.ndarray | None = None,
        sigma_in: np.ndarray | None = None,
        sigma_out: np.ndarray | None = None,
    ) -> None:
        """Eqs. 14, 16, 17 for a tile: heights against ``reference`` (a :class:`CrossedAxesReference`)
        or, without one, against the modelled reference codes (absolute); points on the camera rays;
        with ``sigma_in`` (of ``u``, in its unit) the heights' standard uncertainty
        (:meth:`sigma_rows`). ``v`` is not used (the light planes are parallel to Y)."""
        if points_out is None and height_out is None and sigma_out is None:
            return
        check_axes(self, u, v)
        assert u is not None
        if reference is None:
            ref_codes, slope = self._model_codes[rows], self._model_slope[rows]
        elif isinstance(reference, CrossedAxesReference):
            ref_codes, slope = reference.codes[rows], reference.slope_mm[rows]
        else:
            raise GeometryError(f"a crossed-axes rig needs a crossed-axes reference, got {type(reference).__name__}")
        scratch = thread_scratch()
        if self.code_scale_u is not None:
            l = np.add(u, np.float32(0.5), out=scratch.get("light_codes", u.shape, np.float32))
            l *= self.code_scale_u
        else:
            l = u
        z = height_out if height_out is not None else scratch.get("height", u.shape, np.float32)
        self.height_rows(l, ref_codes, slope, z)
        if points_out is not None:
            self.points_rows(rows, z, points_out)
        if sigma_in is not None and sigma_out is not None:
            self.sigma_rows(l, ref_codes, slope, sigma_in, sigma_out)

    def height_terms(self, reference: ReferenceSurface | None) -> HeightTerms | None:
        """:meth:`height_rows`' terms over the frame (light codes read directly: no code scale)."""
        if self.code_scale_u is not None:
            return None
        if reference is None:
            ref_codes, slope = self._model_codes, self._model_slope
        elif isinstance(reference, CrossedAxesReference):
            ref_codes, slope = reference.codes, reference.slope_mm
        else:
            return None
        return HeightTerms(ref_codes=ref_codes, slope_mm=slope, q=self._q, d_mm=self._d, L_mm=self._L)

    def height_rows(self, l: np.ndarray, ref_codes: np.ndarray, slope_mm: np.ndarray, z_out: np.ndarray) -> None:
        """The in-place float32 kernel of Eqs. 14, 16, 17 on a tile (temporaries in the thread's scratch):
        ``D_R = slope (l - r) / (1 + q l)``, ``z = L D_R / (d + D_R)``; NaN codes give NaN heights."""
        scratch = thread_scratch()
        den = np.multiply(l, self._q, out=scratch.get("denominator", l.shape, np.float32))
        den += np.float32(1)
        num = np.subtract(l, ref_codes, out=scratch.get("numerator", l.shape, np.float32))
        num *= slope_mm
        num /= den  # D_R, mm
        np.add(num, self._d, out=den)
        num *= self._L
        np.divide(num, den, out=z_out)

    def sigma_rows(
        self, l: np.ndarray, ref_codes: np.ndarray, slope_mm: np.ndarray, sigma_in: np.ndarray, sigma_out: np.ndarray
    ) -> None:
        """``|dz/dl| sigma_l``: the height uncertainty of a tile, float32 mm, from the derivative of
        Eqs. 14, 16, 17 (``sigma_l`` is ``sigma_in`` in light codes: times ``nlp / width`` when
        the input is a codec's projector coordinate).

        With ``D = slope (l - r) / (1 + q l)`` and ``z = L D / (d + D)``:
        ``dz/dl = L d / (d + D)^2 * slope (1 + q r) / (1 + q l)^2``.
        """
        scratch = thread_scratch()
        one_ql = np.multiply(l, self._q, out=scratch.get("one_ql", l.shape, np.float32))
        one_ql += np.float32(1)
        disp = np.subtract(l, ref_codes, out=scratch.get("displacement", l.shape, np.float32))
        disp *= slope_mm
        disp /= one_ql  # D, mm
        disp += self._d  # d + D
        disp *= one_ql  # (d + D)(1 + q l)
        np.multiply(disp, disp, out=disp)
        num = np.multiply(ref_codes, self._q, out=scratch.get("one_qr", l.shape, np.float32))
        num += np.float32(1)
        num *= slope_mm
        num *= self._L * self._d
        np.divide(num, disp, out=sigma_out)
        np.abs(sigma_out, out=sigma_out)
        sigma_out *= sigma_in
        if self.code_scale_u is not None:
            sigma_out *= self.code_scale_u

    def points_rows(self, rows: slice, z: np.ndarray, points_out: np.ndarray) -> None:
        """``(X_H, Y_H, z)`` of a tile of heights, float32 (:func:`camera_ray_point`)."""
        scratch = thread_scratch()
        s = np.multiply(z, -self._inv_L, out=scratch.get("ray_scale", z.shape, np.float32))
        s += np.float32(1)
        x = np.multiply(s, self._x_rel32, out=points_out[..., 0])
        x += self._d
        np.multiply(s, self._y_a32[rows], out=points_out[..., 1])
        points_out[..., 2] = z

    def points_from_heights(self, z_mm: np.ndarray, reference: ReferenceSurface | None = None) -> np.ndarray:
        return points_from_heights(self.rig, z_mm)


def equivalent_pinhole(rig: Rig, projector_width: int, projector_height: int) -> GeometryModel:
    """The paper's rig written as the equivalent pinhole rig (docs/pinhole.md), for a codec of
    projector columns ``u`` with ``l = (u + 0.5) nlp / projector_width``.

    Camera frame: ``x_c = X - d``, ``y_c = Y``, ``z_c = L - Z`` (the camera at C looks down; the
    paper's frame mirrored, which the pinhole model does not mind). The camera's pixel ``(k, j)``
    sees ``A = (x_A, Y_A, 0)``: ``K = [[W L / FW, 0, (W - 1) / 2], [0, W L / FW, (H - 1) / 2], [0, 0, 1]]``,
    no distortion. The projector sits at ``P``, ``(-d, 0, 0)`` in the camera frame. Eq. 14 is a
    pinhole projection: with ``s = C1 l``, ``x(l) / L = tan(gamma + atan(s cos b / (1 + s sin b)))``
    (``b = gamma - alpha``, :class:`MobiusMap`), the angle at P of the point ``r + s e`` of the line
    through ``r`` (the unit vector of ray PS) along ``e = sin b r + cos b r_perp``: a projector whose
    image x axis is ``e``, optical axis the unit normal ``a`` of ``e`` (``a . r > 0``), focal length
    ``k (a . r)`` and principal point ``-0.5 - k sin b``, ``k = width / (nlp C1)`` projector units
    per unit of ``s``. Its rows are arbitrary (``fy = fx``, centred): the crossed-axes rig codes
    columns only.

    Returns
    -------
    PinholeRig
        Triangulating ``u`` by the light planes, it gives the crossed-axes rig's heights above a
        captured reference plane.
    """
    from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig

    f_cam = rig.width_px * rig.L_mm / rig.fw_mm
    camera = PinholeCamera(
        width_px=rig.width_px,
        height_px=rig.height_px,
        K=((f_cam, 0.0, (rig.width_px - 1) / 2), (0.0, f_cam, (rig.height_px - 1) / 2), (0.0, 0.0, 1.0)),
    )
    g, b = rig.gamma_rad, rig.gamma_rad - rig.alpha_rad
    r = np.array([math.sin(g), -math.cos(g)])  # (X, Z) of the unit vector of ray PS
    r_perp = np.array([math.cos(g), math.sin(g)])  # the direction of growing codes
    e = math.sin(b) * r + math.cos(b) * r_perp
    a = np.array([-e[1], e[0]])
    if a @ r < 0:
        a = -a
    k = projector_width / (rig.nlp * rig.C1)
    f_proj = k * float(a @ r)
    projector = PinholeProjector(
        width=projector_width,
        height=projector_height,
        K=((f_proj, 0.0, -0.5 - k * math.sin(b)), (0.0, f_proj, (projector_height - 1) / 2), (0.0, 0.0, 1.0)),
    )
    # the projector's axes in the camera frame (x_c = X, z_c = -Z): rows of R
    e_c = np.array([e[0], 0.0, -e[1]])
    a_c = np.array([a[0], 0.0, -a[1]])
    y_c = np.cross(a_c, e_c)  # so that R = [e; y; a] is a rotation (x cross y = z)
    R = np.stack([e_c, y_c, a_c])
    T = -R @ np.array([-rig.d_mm, 0.0, 0.0])
    rows = tuple(tuple(float(v) for v in row) for row in R)
    return PinholeRig(
        camera=camera,
        projector=projector,
        R=(rows[0], rows[1], rows[2]),  # type: ignore[arg-type]
        T=(float(T[0]), float(T[1]), float(T[2])),
    )


def _decimals(value: float, decimals: int) -> str:
    """``value`` rounded to ``decimals`` places, trailing zeros dropped (``1021.98533`` -> ``1021.9853``,
    ``1022.0`` -> ``1022``)."""
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text
