"""Projector gamma: measure the response, pre-compensate patterns, correct phases already taken.

A projector with response ``E = s^g`` (``s`` in 0..1 the pattern value, ``g`` its gamma) turns
the sine ``s = (1 + cos phi) / 2`` into a periodic waveform with harmonics. An N-step phase
shift reads harmonic ``m`` as the fundamental when ``m = k N +- 1``, so the decoded phase
carries a periodic error ``theta(phi) - phi`` (period ``P / N`` in the coordinate); heights
measured on a plane ripple with it.

- :func:`gamma_from_ramp`: ``g`` from a grey-ramp capture (the camera's mean grey for each
  projected level), by least squares on ``I = a + b (level / 255)^g``;
  :func:`response_table`: the 256-entry table ``(level / 255)^g``.
- :func:`precompensate`: pattern values ``s^(1/g)``, so that the projector emits ``s``.
- :func:`phase_error_table` and :func:`correct_coordinate`: the error of the N-step
  estimator for a response ``s^g`` seen through a Gaussian projector blur of sigma (the blur
  scales harmonic ``m`` by ``exp(-2 pi^2 sigma^2 m^2 / P^2)``), and its removal from decoded
  coordinates: ``x' = x - P / (2 pi) err(theta)``, ``theta`` the decoded wrapped phase,
  ``err`` tabulated over ``theta`` and inverted by interpolation.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

FloatArray = npt.NDArray[np.float64]
TABLE_SIZE = 4096


def _check_gamma(gamma: float) -> float:
    g = float(gamma)
    if not (math.isfinite(g) and 0.2 <= g <= 5.0):
        raise ValueError(f"gamma must be within 0.2..5, got {gamma!r}")
    return g


def gamma_from_ramp(levels: npt.ArrayLike, grey: npt.ArrayLike) -> float:
    """Fit ``grey = a + b (levels / 255)^g``; returns ``g``.

    Parameters
    ----------
    levels : (n,) projected 8-bit levels (n >= 4, distinct)
    grey : (n,) camera mean grey at each level (any unit, unsaturated)
    """
    x = np.asarray(levels, dtype=np.float64) / 255.0
    y = np.asarray(grey, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1 or x.size < 4 or np.unique(x).size < 4:
        raise ValueError("a grey ramp needs at least 4 distinct levels and one grey value per level")
    span = float(y.max() - y.min()) or 1.0

    def residual(p: FloatArray) -> FloatArray:
        a, b, g = p
        return (a + b * np.power(x, g) - y) / span

    fit = least_squares(residual, x0=[float(y.min()), span, 1.5], bounds=([-np.inf, 0, 0.2], [np.inf, np.inf, 5.0]))
    return float(fit.x[2])


def response_table(gamma: float) -> list[float]:
    """The 256-entry response ``(level / 255)^g``, 0..1 (a rig file's ``projector.response``)."""
    g = _check_gamma(gamma)
    return [float((k / 255.0) ** g) for k in range(256)]


def precompensate(values: npt.ArrayLike, gamma: float) -> FloatArray:
    """Pattern values ``s^(1/g)`` (``s`` in 0..1) so that a projector of gamma ``g`` emits ``s``."""
    g = _check_gamma(gamma)
    return np.power(np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0), 1.0 / g)


def phase_error_table(
    gamma: float, steps: int, shift: int = 1, blur_px: float = 0.0, period: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """The N-step estimator's phase under a response ``s^g``: ``(phi, theta)`` over one turn.

    ``I_k = E(phi + 2 pi shift k / N)`` with ``E`` the blurred ``((1 + cos)/2)^g`` (Fourier
    series of 64 harmonics, harmonic m scaled by ``exp(-2 pi^2 blur^2 m^2 / period^2)``),
    ``theta = atan2(-S, C)``, ``C = sum I_k cos(2 pi shift k / N)``, ``S = sum I_k sin(...)``.
    ``theta`` is unwrapped to stay near ``phi``. Both ``(TABLE_SIZE,)`` float64, radians.
    """
    g = _check_gamma(gamma)
    if steps < 3:
        raise ValueError(f"steps must be >= 3, got {steps}")
    fine = np.linspace(0.0, 2 * np.pi, 4096, endpoint=False)
    wave = ((1 + np.cos(fine)) / 2) ** g
    coeffs = np.fft.rfft(wave) / wave.size
    m = np.arange(coeffs.size)
    coeffs = coeffs * np.exp(-2 * math.pi**2 * blur_px**2 * m**2 / period**2)
    coeffs[65:] = 0.0
    phi = np.linspace(0.0, 2 * np.pi, TABLE_SIZE, endpoint=False)
    C = np.zeros_like(phi)
    S = np.zeros_like(phi)
    for k in range(steps):
        delta = 2 * np.pi * shift * k / steps
        arg = phi + delta
        value = np.real(coeffs[0]) + 2 * np.sum(
            np.real(coeffs[1:65, None] * np.exp(1j * m[1:65, None] * arg[None, :])), axis=0
        )
        C += value * math.cos(delta)
        S += value * math.sin(delta)
    theta = np.arctan2(-S, C)
    theta = phi + np.angle(np.exp(1j * (theta - phi)))
    return phi, theta


def correct_coordinate(
    x: npt.ArrayLike,
    period: float,
    origin: float,
    steps: int,
    gamma: float,
    *,
    shift: int = 1,
    blur_px: float = 0.0,
) -> FloatArray:
    """Decoded coordinates with the gamma phase error of their last phase stage removed.

    ``theta = 2 pi (x - origin) / period`` (mod 2 pi) is the decoded phase; ``phi`` the true one
    is found by inverting :func:`phase_error_table` (monotonic for gammas the estimator can
    unwrap), and ``x' = x + period / (2 pi) (phi - theta)``. NaN stays NaN.
    """
    xs = np.asarray(x, dtype=np.float64)
    phi, theta = phase_error_table(gamma, steps, shift, blur_px, period)
    err = theta - phi
    # tabulate err against theta (periodic), invert by interpolation
    order = np.argsort(np.mod(theta, 2 * np.pi))
    th = np.mod(theta, 2 * np.pi)[order]
    er = err[order]
    th = np.concatenate([th[-1:] - 2 * np.pi, th, th[:1] + 2 * np.pi])
    er = np.concatenate([er[-1:], er, er[:1]])
    measured = np.mod(2 * np.pi * (xs - origin) / period, 2 * np.pi)
    correction = np.interp(measured, th, er)
    return xs - period / (2 * np.pi) * correction
