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

from metrology.core.geometry.crossed_axes import Rig, abscissa_from_codes


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


# --------------------------------------------------------------------------- per-point sigma maps
def four_step_noise_grey(images: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> float:
    """Camera noise of a gcps-v1 capture from its four phase frames, grey levels.

    The 4-step fit ``a + b cos(Phi - i pi/2)`` leaves one residual direction, ``(+1, -1, +1, -1)``:
    ``e = (I0 - I1 + I2 - I3) / 2`` has variance ``sigma^2`` (camera noise plus quantisation)
    and zero mean for sinusoidal fringes, so ``sigma = sqrt(mean(e^2))`` over the pixels of
    ``mask``. One degree of freedom per pixel: the estimate is pooled over the frame.

    Parameters
    ----------
    images : (11, H, W) gcps-v1 stack (frames 7-10 are the phase frames) or (4, H, W) phase frames
    mask : (H, W) bool array, optional
        Pixels to pool (e.g. the decoder's valid mask); default all.

    Returns
    -------
    sigma_grey : float
        Camera noise standard deviation, grey levels of the images.

    Raises
    ------
    ValueError
        If the stack does not have 11 or 4 frames, or the mask selects no pixel.
    """
    stack = np.asarray(images)
    if stack.ndim != 3 or stack.shape[0] not in (4, 11):
        raise ValueError(f"images must be an (11, H, W) or (4, H, W) stack, got shape {stack.shape}")
    i = stack[-4:].astype(np.float32)
    e = (i[0] - i[1] + i[2] - i[3]) * np.float32(0.5)
    if mask is not None:
        e = e[np.asarray(mask, dtype=bool)]
    if e.size == 0:
        raise ValueError("mask selects no pixel for the noise estimate")
    return float(np.sqrt(np.mean(np.square(e, dtype=np.float64))))


def phase_modulation(images: npt.ArrayLike) -> np.ndarray:
    """``B = hypot(I1 - I3, I0 - I2)`` of a gcps-v1 stack's phase frames: (H, W) float32, grey levels."""
    stack = np.asarray(images)
    if stack.ndim != 3 or stack.shape[0] not in (4, 11):
        raise ValueError(f"images must be an (11, H, W) or (4, H, W) stack, got shape {stack.shape}")
    i = stack[-4:].astype(np.float32)
    return np.hypot(i[1] - i[3], i[0] - i[2])


def gcps_code_sigma(modulation: npt.ArrayLike, noise_grey: float) -> np.ndarray:
    """Per-pixel light-code sigma of a 4-step gcps-v1 decoding: ``(2/pi) sigma / (sqrt(2) b)``, ``b = B/2``.

    Parameters
    ----------
    modulation : (H, W) array
        ``B`` of each pixel (:func:`phase_modulation`), grey levels.
    noise_grey : float
        Camera noise, grey levels (:func:`four_step_noise_grey`, which includes quantisation), >= 0.

    Returns
    -------
    sigma_codes : (H, W) float32, code units; NaN where ``B <= 0``.
    """
    if not (np.isfinite(noise_grey) and noise_grey >= 0):
        raise ValueError(f"noise_grey must be finite and >= 0, got {noise_grey!r}")
    b = np.asarray(modulation, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.float32(2 / np.pi * noise_grey * np.sqrt(2)) / b  # (2/pi) sigma / (sqrt(2) B/2)
    return np.where(b > 0, sigma, np.float32(np.nan)).astype(np.float32)


def light_code_sigma(rig: Rig, coordinate_sigma: npt.ArrayLike, projector_width: float) -> np.ndarray:
    """A codec's coordinate sigma (projector units) as light-code sigma: ``sigma_l = sigma_u nlp / width``
    (the map ``l = (u + 0.5) nlp / width`` of a codec on a crossed-axes rig); float32."""
    if not (np.isfinite(projector_width) and projector_width > 0):
        raise ValueError(f"projector_width must be > 0, got {projector_width!r}")
    return (np.asarray(coordinate_sigma, np.float32) * np.float32(rig.nlp / projector_width)).astype(np.float32)


def crossed_axes_sigma_mm(
    rig: Rig,
    ref_codes: npt.ArrayLike,
    obj_codes: npt.ArrayLike,
    ref_sigma_codes: npt.ArrayLike,
    obj_sigma_codes: npt.ArrayLike,
) -> np.ndarray:
    """Per-point height uncertainty of a crossed-axes measurement, Eqs. 14-17 to first order.

    ``z = L D / (d + D)`` (Eq. 17) with ``D = x(l) - x(r)`` (Eq. 16) and ``x`` the Mobius map of
    Eq. 14, ``dx/dl = L (p - q t) / (1 + q l)^2``. Reference and object captures are independent:

    ``sigma_z = L d / (d + D)^2 * hypot(x'(l) sigma_l, x'(r) sigma_r)``.

    Parameters
    ----------
    rig : Rig
    ref_codes, obj_codes : (H, W) float arrays
        Light codes of reference and object, code units; NaN where invalid.
    ref_sigma_codes, obj_sigma_codes : (H, W) float arrays or scalars
        Their standard deviations, code units (:func:`gcps_code_sigma`, or
        :func:`light_code_sigma` of a codec decoder's coordinate sigma).

    Returns
    -------
    sigma_mm : (H, W) float32 array
        One-sigma height uncertainty, mm; NaN where a code or sigma is NaN.
    """
    r = np.asarray(ref_codes, dtype=np.float64)
    l = np.asarray(obj_codes, dtype=np.float64)
    if r.shape != l.shape:
        raise ValueError(f"ref_codes {r.shape} and obj_codes {l.shape} differ in shape")
    d_r = abscissa_from_codes(rig, l) - abscissa_from_codes(rig, r)
    gain = rig.L_mm * rig.d_mm / (rig.d_mm + d_r) ** 2  # dz / dD, Eq. 17
    s_obj = abscissa_per_code(rig, l) * np.asarray(obj_sigma_codes, dtype=np.float64)
    s_ref = abscissa_per_code(rig, r) * np.asarray(ref_sigma_codes, dtype=np.float64)
    return (np.abs(gain) * np.hypot(s_obj, s_ref)).astype(np.float32)


def gcps_sigma_mm(
    rig: Rig,
    ref_codes: npt.ArrayLike,
    obj_codes: npt.ArrayLike,
    ref_images: npt.ArrayLike,
    obj_images: npt.ArrayLike,
) -> np.ndarray:
    """Per-point height sigma (mm) of a gcps-v1 measurement on a crossed-axes rig, from the captures.

    Each capture's camera noise is estimated from its own phase frames (:func:`four_step_noise_grey`
    over the pixels with a valid code), each pixel's code sigma from its modulation
    (:func:`gcps_code_sigma`), and both propagate through Eqs. 14-17 (:func:`crossed_axes_sigma_mm`).

    Parameters
    ----------
    rig : Rig
    ref_codes, obj_codes : (H, W) float32 light codes (NaN where invalid)
    ref_images, obj_images : (11, H, W) gcps-v1 stacks

    Returns
    -------
    sigma_mm : (H, W) float32 array, mm; NaN where either code is NaN.
    """
    sigmas = []
    for codes, images in ((ref_codes, ref_images), (obj_codes, obj_images)):
        valid = np.isfinite(np.asarray(codes))
        noise = four_step_noise_grey(images, valid) if valid.any() else 0.0
        sigmas.append(gcps_code_sigma(phase_modulation(images), noise))
    return crossed_axes_sigma_mm(rig, ref_codes, obj_codes, sigmas[0], sigmas[1])
