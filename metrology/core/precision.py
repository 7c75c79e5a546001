"""Height noise from camera noise: the phase-noise limit of a GCPS measurement.

With camera noise ``sigma`` (grey levels) on fringes ``I_i = a + b cos(Phi - i pi/2)``
the differences ``I1 - I3 = 2b sin Phi`` and ``I0 - I2 = 2b cos Phi`` each carry
noise ``sqrt(2) sigma``, so ``sigma_Phi = sigma / (sqrt(2) b)`` and, from Eq. 3,
``sigma_l = (2/pi) sigma_Phi``. Eq. 14 maps a code error to an abscissa error
``dx/dl``, and Eq. 17 an abscissa error to a height error ``L d / (d + D)^2``.
Reference and object are independent captures, so their contributions add in
quadrature. 8-bit quantisation adds ``1/12`` grey level squared of variance.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.special import erf

from metrology.core.rig import Rig
from metrology.core.triangulate import abscissa_from_codes


def abscissa_per_code(rig: Rig, codes: npt.ArrayLike) -> np.ndarray:
    """Derivative ``dx/dl`` of Eq. 14 (mm per code unit) at ``codes``; same shape, float64."""
    m = rig.mobius
    l = np.asarray(codes, dtype=np.float64)
    return m.L_mm * (m.p - m.q * m.t) / (1 + m.q * l) ** 2


def code_sigma(modulation: npt.ArrayLike, noise_grey: float) -> np.ndarray:
    """Code noise ``(2/pi) sigma / (sqrt(2) b)`` for modulation ``B = 2b`` (grey levels); code units."""
    b = np.asarray(modulation, dtype=np.float64) / 2
    with np.errstate(divide="ignore"):
        return (2 / np.pi) * noise_grey / (np.sqrt(2) * b)


def height_sigma_mm(
    rig: Rig,
    ref_codes: npt.ArrayLike,
    obj_codes: npt.ArrayLike,
    ref_modulation: npt.ArrayLike,
    obj_modulation: npt.ArrayLike,
    noise_grey: float,
    *,
    quantisation: bool = True,
) -> np.ndarray:
    """Standard deviation of the height of each pixel due to camera noise.

    Parameters
    ----------
    rig : Rig
    ref_codes, obj_codes : (H, W) float arrays
        Decoded codes of reference and object, code units (NaN gives NaN).
    ref_modulation, obj_modulation : (H, W) float arrays
        ``B = hypot(I1 - I3, I0 - I2)`` of each capture, grey levels.
    noise_grey : float
        Camera noise standard deviation, grey levels of the images, >= 0.
    quantisation : bool
        Add the variance 1/12 of rounding to integer grey levels.

    Returns
    -------
    sigma_mm : (H, W) float64 array
        One-sigma height noise, mm.
    """
    if noise_grey < 0:
        raise ValueError(f"noise_grey must be >= 0, got {noise_grey}")
    sigma = float(np.sqrt(noise_grey**2 + (1 / 12 if quantisation else 0.0)))
    ref = np.asarray(ref_codes, dtype=np.float64)
    obj = np.asarray(obj_codes, dtype=np.float64)
    d_r = abscissa_from_codes(rig, obj) - abscissa_from_codes(rig, ref)
    gain = rig.L_mm * rig.d_mm / (rig.d_mm + d_r) ** 2  # dz / dD, Eq. 17
    s_obj = abscissa_per_code(rig, obj) * code_sigma(obj_modulation, sigma)
    s_ref = abscissa_per_code(rig, ref) * code_sigma(ref_modulation, sigma)
    return gain * np.hypot(s_obj, s_ref)


def median_abs_error_mm(sigma_mm: npt.ArrayLike) -> float:
    """Median of ``|e|`` over pixels whose errors are ``N(0, sigma_i^2)``: the expected median.

    For one sigma this is ``0.6745 sigma``; for a map, the ``t`` where the mean of
    ``P(|e_i| < t) = erf(t / (sqrt(2) sigma_i))`` is one half (solved by bisection).

    >>> round(median_abs_error_mm([1.0, 1.0]), 4)
    0.6745
    """
    s = np.asarray(sigma_mm, dtype=np.float64)
    s = s[np.isfinite(s) & (s > 0)]
    if s.size == 0:
        raise ValueError("sigma_mm holds no positive finite value")
    low, high = 0.0, float(s.max()) * 10
    for _ in range(60):
        mid = (low + high) / 2
        if np.mean(erf(mid / (np.sqrt(2) * s))) < 0.5:
            low = mid
        else:
            high = mid
    return (low + high) / 2
