"""Rig geometry of the crossed-optical-axes profilometer (gcps-v1, DESIGN.md 1.1-1.2).

A :class:`Rig` holds the seven geometric values that every other part of the
core needs, validates them, and derives the constants of the paper's mapping
equation (Eqs. 7, 12, 13, 15) and the pixel-to-reference-plane coordinates.

Geometry (paper Figs. 1 and 3)::

    P (0, 0, L)  projector pupil          C (d, 0, L)  camera pupil
    R: Z = 0, heights positive towards the rig
    camera field on R: X in [d - FW/2, d + FW/2], centred under C
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

REQUIRED_KEYS: tuple[str, ...] = (
    "L_mm",
    "d_mm",
    "alpha_rad",
    "fw_mm",
    "nlp",
    "width_px",
    "height_px",
)


class RigError(ValueError):
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
class Rig:
    """Geometry of a projector-camera rig (DESIGN.md 1.2).

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
        """Build a rig from the JSON object of DESIGN.md 1.2; unknown keys go to ``extra``."""
        if not isinstance(data, Mapping):
            raise RigError(f"rig must be a JSON object, got {type(data).__name__}")
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
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object: the seven required keys, then ``extra``."""
        data = asdict(self)
        extra = data.pop("extra")
        data.update(extra)
        return data

    def with_parameters(self, **changes: Any) -> Rig:
        """A copy with some geometric values replaced (e.g. calibrated L and alpha)."""
        return replace(self, **changes)

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


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _is_integral(value: Any) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    return isinstance(value, (float, np.floating)) and float(value).is_integer()


PAPER_RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=640, height_px=480)
"""The calibrated rig of the paper's section 5, at the VGA size used by the tests."""
