"""Per-point uncertainty from each pixel's phase noise: the decoded coordinate's sigma.

An N-step least-squares phase of period P (projector units) with independent camera noise
``sigma_I`` per frame and modulation B (grey levels) has the coordinate standard deviation

    sigma_x = P / (2 pi) * sqrt(2 / N) * sigma_I / B                      (projector units)

(docs/codecs.md, "Coordinate noise"); a heterodyne beat of two sequences ending the chain adds
their phase variances over the beat's period. ``sigma_I`` is the decoder's fit-residual noise
estimate ``sqrt(R / (N - 3))``, which has only N - 3 degrees of freedom per pixel (one for
gcps-v1's 4 steps): it is pooled over a ``POOL_PX x POOL_PX`` window, ``sigma_I^2`` averaged over
the window's decoded pixels, so that its median is unbiased.

The geometric model propagates it to the point (``sigma_in`` / ``sigma_out`` of
:meth:`~metrology.core.geometry.base.PreparedGeometry.triangulate_rows`): on the crossed-axes rig
``sigma_z = |dz/dl| sigma_l`` with ``sigma_l = sigma_u nlp / width`` and the analytic derivative
of Eqs. 14, 16, 17; on a pinhole rig along the camera ray. The reference's own noise is not
included (it is common to every measurement against that reference).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec

POOL_PX = 7
"""Side of the window over which the per-pixel noise estimate is pooled, px."""


def coordinate_sigma(
    period: float, steps: int, noise: npt.ArrayLike, modulation: npt.ArrayLike
) -> npt.NDArray[np.float32]:
    """``P / (2 pi) * sqrt(2 / N) * sigma_I / B``: an N-step phase's coordinate sigma, projector units.

    ``noise`` and ``modulation`` are maps (or scalars) in grey levels; NaN where ``B <= 0``.
    """
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"period must be > 0, got {period!r}")
    if steps < 3:
        raise ValueError(f"steps must be >= 3, got {steps!r}")
    return _phase_coordinate_sigma(period, 2.0 / steps, noise, modulation)


def _phase_coordinate_sigma(
    period: float, variance_factor: float, noise: npt.ArrayLike, modulation: npt.ArrayLike
) -> npt.NDArray[np.float32]:
    """``P / (2 pi) * sqrt(k) * sigma_I / B``, with ``var(theta) = k sigma_I^2 / B^2`` (``k = 2 / N`` for
    an N-step phase, ``sum_i 2 / N_i`` for a beat of several); float32, NaN where ``B <= 0``."""
    b = np.asarray(modulation, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.float32(period / (2 * math.pi) * math.sqrt(variance_factor)) * np.asarray(noise, np.float32) / b
    return np.where(b > 0, sigma, np.float32(np.nan)).astype(np.float32)


def pooled_noise(noise: npt.ArrayLike, window: int = POOL_PX) -> npt.NDArray[np.float32]:
    """``sqrt(mean of noise^2)`` over the ``window x window`` neighbourhood's finite values, (H, W) float32.

    NaN where the window holds no finite value.
    """
    n = np.asarray(noise, dtype=np.float32)
    finite = np.isfinite(n)
    squares = np.where(finite, n * n, np.float32(0)).astype(np.float32)
    total = cv2.boxFilter(squares, cv2.CV_32F, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(
        finite.astype(np.float32), cv2.CV_32F, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        pooled = np.sqrt(total / count)
    pooled[count < 0.5] = np.nan
    return pooled.astype(np.float32)


def stage_coordinate_sigma(
    codec: Codec, axis: str, noise: npt.ArrayLike, modulation: npt.ArrayLike
) -> npt.NDArray[np.float32]:
    """Coordinate sigma (projector units) of ``axis`` for the final stage of its unwrapping chain,
    from the decoder's per-pixel noise estimate (pooled, :func:`pooled_noise`) and modulation maps.

    An N-step phase (N >= 4) gives :func:`coordinate_sigma`; a beat of two sequences,
    ``theta_b = theta_s - theta_l``, adds their phase variances over the beat's period:
    ``sigma_b = P_b / (2 pi) * sqrt(sum_i 2 / N_i) * sigma_I / B``; a beat of beats with phase
    weights ``w_i`` (:meth:`~metrology.core.codecs.model.Stage.phase_weights`, e.g. 1, -2, 1)
    ``sigma_b = P_b / (2 pi) * sqrt(sum_i w_i^2 2 / N_i) * sigma_I / B``.

    Raises
    ------
    ValueError
        When the chain ends on a gray code or on a sequence of 3 steps (no noise estimate).
    """
    stage = codec.axes[axis].chain()[-1]
    phase = codec.axes[axis].phase
    weights = stage.phase_weights()
    steps = [len(phase[i].frames) for i in weights]
    if stage.kind == "gray" or min(steps, default=0) < 4:
        raise ValueError(
            f"a per-point uncertainty needs the {axis} axis to end on a phase sequence of N >= 4 steps "
            "(its fit residual is the noise estimate)"
        )
    pooled = pooled_noise(noise)
    if stage.kind == "phase":
        return coordinate_sigma(stage.period, steps[0], pooled, modulation)
    # a beat (of beats): theta = sum_i w_i theta_i, var = sum_i w_i^2 (2 / N_i) (sigma_I / B)^2
    variance_factor = sum(w * w * 2.0 / len(phase[i].frames) for i, w in weights.items())
    return _phase_coordinate_sigma(stage.period, variance_factor, pooled, modulation)
