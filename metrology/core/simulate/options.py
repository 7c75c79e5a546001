"""Options of the virtual rig: radiometry, camera, noise (:class:`SimulationOptions`) and the two
presets (noise-free 16-bit, realistic 8-bit). Every renderer of :mod:`metrology.core.simulate`
reads them."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

CAMERA_SAMPLINGS = ("area", "centre")
"""Values of :attr:`SimulationOptions.camera_sampling`: a pixel's mean over its area, or its centre ray."""


# --------------------------------------------------------------------------- options
@dataclass(frozen=True)
class SimulationOptions:
    """Radiometric and camera options of the virtual rig.

    Parameters
    ----------
    bit_depth : {8, 16}
        Output image depth; full scale is ``2**bit_depth - 1``. Default 16.
    noise_grey : float
        Standard deviation of additive Gaussian camera noise, in grey levels of the output
        depth, >= 0. Default 0.
    ambient : float
        Ambient illumination, fraction of full scale on albedo 1, >= 0. Default 0.05.
    projector_gain : float
        Camera signal of a white pattern on albedo 1, fraction of full scale, > 0. Default 0.8.
        ``ambient + projector_gain > 1`` saturates (values are clipped).
    projector_gamma : float
        Projector response ``emitted = value ** gamma``, > 0. Default 1.
    projector_defocus_codes : float
        Gaussian sigma of the projector blur across the fringes, code units, >= 0. Default 0.
    camera_defocus_px : float
        Gaussian sigma of the camera blur, pixels, >= 0. Default 0.
    square : bool
        Project square-wave phase patterns instead of sinusoids. Default False.
    smoothing_codes : float
        Gaussian sigma, in code units, applied to the phase patterns only (projector side):
        the smoothing that turns square fringes into near-sinusoids (sigma ~ 0.8-1 code
        leaves a third harmonic below 1e-3 of the fundamental), >= 0. Default 0.
    supersample : int
        Sub-rays per pixel along each axis (1 to 8); > 1 renders mixed pixels at
        discontinuities. Default 1 (exact pixel-centre rendering). With
        ``camera_sampling="centre"`` the sub-rays only find the depth edges inside each pixel
        (:attr:`RenderedStack.edges`); the images take the centre ray.
    camera_sampling : {"area", "centre"}
        How a pixel gathers light before the camera blur. ``"area"`` (default): the mean of its
        ``supersample x supersample`` sub-rays, i.e. the pixel's area (a box of one pixel, variance
        1/12 px^2 per axis, plus ``camera_defocus_px``). ``"centre"``: the light of the ray through
        the pixel's centre only, then the Gaussian of ``camera_defocus_px``: a camera whose whole
        blur is Gaussian (no box), which makes the mixing at a depth step a Gaussian-weighted blend
        of the two sides instead of a sharp area split. With ``supersample=1`` both are the same.
    seed : int
        Seed of the camera noise, >= 0. Default 0.

    Raises
    ------
    ValueError
        Naming the option and the value, when an option is out of range.

    Notes
    -----
    ``SimulationOptions()`` equals :meth:`noise_free_16bit`; :meth:`realistic_8bit` is the
    acceptance tests' realistic camera.
    """

    bit_depth: int = 16
    noise_grey: float = 0.0
    ambient: float = 0.05
    projector_gain: float = 0.8
    projector_gamma: float = 1.0
    projector_defocus_codes: float = 0.0
    camera_defocus_px: float = 0.0
    square: bool = False
    smoothing_codes: float = 0.0
    supersample: int = 1
    seed: int = 0
    camera_sampling: str = "area"

    def __post_init__(self) -> None:
        if _is_bool(self.bit_depth) or self.bit_depth not in (8, 16):
            raise ValueError(f"option bit_depth must be 8 or 16, got {self.bit_depth!r}")
        object.__setattr__(self, "bit_depth", int(self.bit_depth))
        for name in ("noise_grey", "ambient", "projector_defocus_codes", "camera_defocus_px", "smoothing_codes"):
            self._check_real(name, lower=0.0, strict=False)
        for name in ("projector_gain", "projector_gamma"):
            self._check_real(name, lower=0.0, strict=True)
        if not isinstance(self.square, (bool, np.bool_)):
            raise ValueError(f"option square must be a bool, got {self.square!r}")
        object.__setattr__(self, "square", bool(self.square))
        if not _is_int(self.supersample) or not 1 <= self.supersample <= 8:
            raise ValueError(f"option supersample must be an integer in 1..8, got {self.supersample!r}")
        object.__setattr__(self, "supersample", int(self.supersample))
        if not _is_int(self.seed) or self.seed < 0:
            raise ValueError(f"option seed must be a non-negative integer, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))
        if not isinstance(self.camera_sampling, str) or self.camera_sampling not in CAMERA_SAMPLINGS:
            expected = " or ".join(repr(v) for v in CAMERA_SAMPLINGS)
            raise ValueError(f"option camera_sampling must be {expected}, got {self.camera_sampling!r}")

    def _check_real(self, name: str, lower: float, strict: bool) -> None:
        value = getattr(self, name)
        if _is_bool(value) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"option {name} must be a real number, got {value!r}")
        value = float(value)
        if not math.isfinite(value) or value < lower or (strict and value == lower):
            relation = ">" if strict else ">="
            raise ValueError(f"option {name} must be finite and {relation} {lower:g}, got {value!r}")
        object.__setattr__(self, name, value)

    def to_dict(self) -> dict[str, Any]:
        """Every option by name (JSON types); ``SimulationOptions(**d)`` rebuilds the same options."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def full_scale(self) -> int:
        """Largest grey level: 255 or 65535."""
        return (1 << self.bit_depth) - 1

    @property
    def dtype(self) -> type[np.unsignedinteger[Any]]:
        """Image dtype: ``np.uint8`` or ``np.uint16``."""
        return np.uint8 if self.bit_depth == 8 else np.uint16

    def with_changes(self, **changes: Any) -> SimulationOptions:
        """A validated copy with some options replaced."""
        unknown = sorted(set(changes) - {f.name for f in fields(self)})
        if unknown:
            raise ValueError(f"unknown simulation option(s): {', '.join(unknown)}")
        return replace(self, **changes)

    @classmethod
    def noise_free_16bit(cls, **changes: Any) -> SimulationOptions:
        """Exact rendering: 16-bit, no noise, no blur, sinusoids, one ray per pixel."""
        return cls().with_changes(**changes)

    @classmethod
    def realistic_8bit(cls, **changes: Any) -> SimulationOptions:
        """A realistic camera: 8-bit, 1.5 grey levels of noise, slight camera and projector
        defocus (0.7 px, 0.15 code), 3 x 3 sub-rays per pixel."""
        base = cls(
            bit_depth=8,
            noise_grey=1.5,
            camera_defocus_px=0.7,
            projector_defocus_codes=0.15,
            supersample=3,
        )
        return base.with_changes(**changes)


def noise_free_16bit(**changes: Any) -> SimulationOptions:
    """Shorthand for :meth:`SimulationOptions.noise_free_16bit`."""
    return SimulationOptions.noise_free_16bit(**changes)


def realistic_8bit(**changes: Any) -> SimulationOptions:
    """Shorthand for :meth:`SimulationOptions.realistic_8bit`."""
    return SimulationOptions.realistic_8bit(**changes)


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not _is_bool(value)


def camera_image(intensity: np.ndarray, height: int, width: int, opts: SimulationOptions) -> np.ndarray:
    """What the virtual camera's pixels see of a light field sampled on its sensor.

    ``intensity`` (any shape ``(height * s, width * s)``, float64, s >= 1 sub-rays per side) is
    averaged over each pixel's area (``cv2.INTER_AREA``) when ``s > 1``, then blurred by a Gaussian
    of ``opts.camera_defocus_px`` pixels (replicated borders) when that is positive. Returns
    ``(height, width)`` float64, same units as ``intensity``.
    """
    import cv2

    img = intensity
    if img.shape != (height, width):
        img = cv2.resize(intensity, (width, height), interpolation=cv2.INTER_AREA)
    if opts.camera_defocus_px > 0:
        sigma = opts.camera_defocus_px
        img = cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REPLICATE)
    return img


DIRECT_BLUR_TAPS = 129
"""Longest Gaussian kernel :func:`blur_line` applies directly; longer ones go through an FFT."""


def blur_line(values: np.ndarray, sigma: float, truncate: float, mode: str) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter1d(values, sigma, mode=mode, truncate=truncate)`` of a 1-D float64
    array (``mode`` ``"nearest"`` or ``"constant"``, zeros beyond the ends), for the renderers' long
    tables of blurred patterns.

    The kernel is scipy's: ``w_j = exp(-j^2 / (2 sigma^2)) / sum``, ``|j| <= r = int(truncate sigma + 0.5)``.
    Up to :data:`DIRECT_BLUR_TAPS` taps it is scipy's own direct sum; beyond, the same kernel applied by
    FFT to the line padded by ``r`` on each side (edge values or zeros), ``O(n log n)`` instead of
    ``O(n r)``: equal to the direct sum to float64 rounding (about ``1e-16`` of the values' range).
    """
    from scipy.ndimage import gaussian_filter1d

    r = int(truncate * float(sigma) + 0.5)
    if 2 * r + 1 <= DIRECT_BLUR_TAPS:
        return gaussian_filter1d(values, sigma, mode=mode, truncate=truncate)
    import scipy.fft

    j = np.arange(-r, r + 1)
    weights = np.exp(-0.5 / (sigma * sigma) * j**2)
    weights = weights / weights.sum()
    padded = np.pad(values, r, mode="edge" if mode == "nearest" else "constant")
    size = scipy.fft.next_fast_len(padded.size + 2 * r, real=True)
    full = scipy.fft.irfft(scipy.fft.rfft(padded, size) * scipy.fft.rfft(weights, size), size)
    return np.ascontiguousarray(full[2 * r : 2 * r + values.size])
