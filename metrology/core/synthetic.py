"""Exact light-code maps from known geometry: the analytic oracle of the virtual rig.

Calibration and characterization work on decoded light-code maps, and a code
map depends only on the *true* geometry, never on the rig's parameter estimates.
For pixel ``(k, j)`` looking at point A of R (abscissa ``x_A``, docs/conventions.md):

- the reference code is the code of the light plane landing at ``x_A``:
  ``l_ref = codes_from_abscissa(rig, x_A)`` (inverse of Eq. 14);
- a surface point H at height ``z`` on the same camera ray lies at
  ``X_H = d + (1 - z/L)(x_A - d)``; the projector's light plane through H lands on
  R at ``x_B = X_H L / (L - z)``, so ``l_obj = codes_from_abscissa(rig, x_B)``.

Eqs. 16-17 invert this exactly (``x_B - x_A = d z / (L - z)``), so heights
triangulated with the true rig reproduce ``z`` to rounding.

Noise model
-----------
A code measured from one capture stack carries Gaussian noise of standard
deviation ``sigma_code``. The default, :data:`REALISTIC_SIGMA_CODE` = 0.007 code
units, is what 1.5 grey levels of noise on 8-bit fringes of ~100 grey-level
amplitude give: ``sigma_phi = sigma_I / (sqrt(2) b)`` with ``b = 100`` and
``sigma_I = 1.5`` (Eq. 2 with four steps), and ``sigma_l = (2/pi) sigma_phi``
(Eq. 3). ``edge_gain`` optionally lets the noise grow towards the field edges
(paper section 5: about +70 % at the boundaries of the illuminated area).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.crossed_axes import (
    Rig,
    camera_ray_point,
    codes_from_abscissa,
    codes_of_points,
    height_from_codes,
)

REALISTIC_SIGMA_CODE = 0.007
"""Code noise per pixel per capture stack, code units (1.5 grey levels on 8-bit fringes)."""


def _check_z(rig: Rig, z_mm: npt.ArrayLike) -> np.ndarray:
    z = np.asarray(z_mm, dtype=np.float64)
    if z.ndim == 0:
        z = np.full(rig.shape, float(z))
    if z.shape != rig.shape:
        raise ValueError(f"z_mm must be a scalar or have the rig's shape {rig.shape}, got {z.shape}")
    if np.any(z[np.isfinite(z)] >= rig.L_mm):
        raise ValueError(f"z_mm must stay below the pupils' height L = {rig.L_mm} mm")
    return z


def reference_codes(rig: Rig) -> np.ndarray:
    """Exact reference code map (REF): codes of the light planes landing at each ``x_A``.

    Parameters
    ----------
    rig : Rig
        The *true* geometry.

    Returns
    -------
    codes : (height_px, width_px) float64 array, code units in [0, nlp]
        Identical rows (codes do not depend on Y).
    """
    row = codes_from_abscissa(rig, rig.column_x_mm())
    return np.broadcast_to(row, rig.shape).copy()


def exact_codes(rig: Rig, z_mm: npt.ArrayLike) -> np.ndarray:
    """Exact object code map (OBJ) of a surface seen at height ``z_mm`` by each pixel.

    Parameters
    ----------
    rig : Rig
        The *true* geometry.
    z_mm : float or (height_px, width_px) array_like
        Height above R of the surface point each pixel sees, mm; NaN where nothing
        is seen (e.g. projector shadow). Must be below ``rig.L_mm``.

    Returns
    -------
    codes : (height_px, width_px) float64 array, code units in [0, nlp]
        NaN where ``z_mm`` is NaN or the light plane falls outside the coded field
        (the projector emits no light outside [0, nlp]).

    Examples
    --------
    >>> from metrology.core.geometry.crossed_axes import PAPER_RIG as rig
    >>> from metrology.core.geometry.crossed_axes import height_from_codes
    >>> z = height_from_codes(rig, reference_codes(rig), exact_codes(rig, 40.0))
    >>> bool(abs(z[240, 100] - 40.0) < 1e-9)
    True
    """
    z = _check_z(rig, z_mm)
    x_h, _ = camera_ray_point(rig, rig.column_x_mm()[None, :], 0.0, z)
    codes = codes_of_points(rig, x_h, z)
    with np.errstate(invalid="ignore"):
        outside = ~((codes >= 0.0) & (codes <= rig.nlp))
    codes[outside] = np.nan
    return codes


def code_noise_sigma(rig: Rig, sigma_code: float = REALISTIC_SIGMA_CODE, edge_gain: float = 0.0) -> np.ndarray:
    """Per-column code-noise standard deviation, code units.

    ``sigma(j) = sigma_code * (1 + edge_gain * u_j**2)`` with ``u_j`` in [-1, 1] the
    column's position across the field (0 at the centre).

    Returns
    -------
    sigma : (width_px,) float64 array, code units
    """
    if sigma_code < 0 or not np.isfinite(sigma_code):
        raise ValueError(f"sigma_code must be a finite non-negative number, got {sigma_code!r}")
    if edge_gain < 0:
        raise ValueError(f"edge_gain must be non-negative, got {edge_gain!r}")
    u = (rig.column_x_mm() - rig.d_mm) / (rig.fw_mm / 2)
    return sigma_code * (1.0 + edge_gain * u**2)


def add_code_noise(
    rig: Rig,
    codes: npt.ArrayLike,
    rng: np.random.Generator,
    sigma_code: float = REALISTIC_SIGMA_CODE,
    edge_gain: float = 0.0,
) -> np.ndarray:
    """A noisy copy of a code map (one simulated capture stack).

    Parameters
    ----------
    rig : Rig
    codes : (height_px, width_px) array_like, code units, NaN where invalid
    rng : numpy.random.Generator
    sigma_code : float
        Noise standard deviation at the field centre, code units.
    edge_gain : float
        Relative growth of sigma at the field edges (see :func:`code_noise_sigma`).

    Returns
    -------
    noisy : (height_px, width_px) float64 array; NaN stays NaN.
    """
    c = np.asarray(codes, dtype=np.float64)
    if c.shape != rig.shape:
        raise ValueError(f"codes must have the rig's shape {rig.shape}, got {c.shape}")
    sigma = code_noise_sigma(rig, sigma_code, edge_gain)[None, :]
    return c + rng.standard_normal(c.shape) * sigma


def block_heights(
    rig: Rig,
    height_mm: float,
    size_mm: tuple[float, float] = (300.0, 200.0),
    center_mm: tuple[float, float] | None = None,
) -> np.ndarray:
    """Height each pixel sees on a rectangular block (calibration master) standing on R.

    The block's top face is at ``height_mm``, its footprint ``size_mm = (along X,
    along Y)`` centred at ``center_mm = (X, Y)`` (default: under the camera,
    ``(d, 0)``). Pixels whose ray meets a vertical side see that side's height;
    floor pixels in the projector's shadow (the light plane to them crosses the
    block) are NaN.

    Returns
    -------
    z_mm : (height_px, width_px) float64 array, mm; NaN in the projector shadow.
    """
    if not (0.0 < height_mm < rig.L_mm):
        raise ValueError(f"height_mm must lie in (0, L), got {height_mm!r}")
    cx, cy = (rig.d_mm, 0.0) if center_mm is None else center_mm
    x0, x1 = cx - size_mm[0] / 2, cx + size_mm[0] / 2
    y0, y1 = cy - size_mm[1] / 2, cy + size_mm[1] / 2
    L, d = rig.L_mm, rig.d_mm
    x_a = np.broadcast_to(rig.column_x_mm()[None, :], rig.shape)
    y_a = np.broadcast_to(rig.row_y_mm()[:, None], rig.shape)

    # Walk down the camera ray from the top face's level: X_H = d + s (x_A - d), Y_H = s Y_A with
    # s = 1 - z/L. The first s in [1 - H/L, 1] inside the footprint is what the pixel sees.
    s_top = 1.0 - height_mm / L
    s_hit, hits = _first_inside(s_top, d + 0 * x_a, x_a - d, y_a, (x0, x1), (y0, y1))
    z = np.where(hits, np.clip((1.0 - s_hit) * L, 0.0, height_mm), 0.0)

    # Projector shadow on the floor: the ray from P (X = Y = 0, Z = L) to the floor point,
    # (t x_A, t Y_A, (1 - t) L), passes through the block for some t in [1 - H/L, 1).
    _, blocked = _first_inside(s_top, 0 * x_a, x_a, y_a, (x0, x1), (y0, y1))
    z[~hits & blocked] = np.nan
    return z


def sphere_heights(rig: Rig, center_mm: tuple[float, float, float], radius_mm: float, floor: bool = True) -> np.ndarray:
    """Height each pixel sees on a sphere (centre ``(X, Y, Z)``, mm) above R.

    Pixels whose camera ray misses the sphere see the floor (z = 0), or NaN with
    ``floor=False``. Points the projector cannot light (the light ray from P meets
    the sphere first: self-shadow and cast shadow) are NaN.

    Returns
    -------
    z_mm : (height_px, width_px) float64 array, mm; NaN in shadow.
    """
    if not (radius_mm > 0):
        raise ValueError(f"radius_mm must be positive, got {radius_mm!r}")
    cen = np.asarray(center_mm, dtype=np.float64)
    if cen.shape != (3,) or cen[2] + radius_mm >= rig.L_mm or cen[2] - radius_mm < -1e-9:
        raise ValueError(f"center_mm must be (X, Y, Z) with the sphere between R and the pupils, got {center_mm!r}")
    L, d = rig.L_mm, rig.d_mm
    x_a = np.broadcast_to(rig.column_x_mm()[None, :], rig.shape)
    y_a = np.broadcast_to(rig.row_y_mm()[:, None], rig.shape)
    zero = np.zeros(rig.shape)

    def first_hit(origin: tuple[float, float, float], target: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
        # ray origin + s (target - origin): smallest s of the sphere intersection, NaN if none
        v = [t - o for t, o in zip(target, origin, strict=True)]
        w = [o - c for o, c in zip(origin, cen, strict=True)]
        a = v[0] ** 2 + v[1] ** 2 + v[2] ** 2
        b = 2 * (v[0] * w[0] + v[1] * w[1] + v[2] * w[2])
        c = w[0] ** 2 + w[1] ** 2 + w[2] ** 2 - radius_mm**2
        disc = b**2 - 4 * a * c
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(disc)) / (2 * a)
        return np.where(disc >= 0, s, np.nan)

    s_cam = first_hit((d, 0.0, L), (x_a, y_a, zero))
    hit = np.isfinite(s_cam) & (s_cam <= 1.0)
    z = np.where(hit, L * (1.0 - np.where(hit, s_cam, 1.0)), 0.0 if floor else np.nan)
    # surface point seen by each pixel, then the projector ray P -> that point
    s_pt = np.where(hit, s_cam, 1.0)
    px, py, pz = d + s_pt * (x_a - d), s_pt * y_a, z
    s_proj = first_hit((0.0, 0.0, L), (px, py, pz))
    shadow = np.isfinite(s_proj) & (s_proj < 1.0 - 1e-9)
    z = np.where(shadow & (hit | floor), np.nan, z)
    return z


def _first_inside(
    s_min: float,
    x_origin: np.ndarray,
    x_dir: np.ndarray,
    y_dir: np.ndarray,
    x_range: tuple[float, float],
    y_range: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Slab test: smallest s in [s_min, 1] with x_origin + s x_dir in x_range and s y_dir in y_range."""
    s_lo = np.full(x_dir.shape, s_min)
    s_hi = np.ones(x_dir.shape)
    for origin, direction, (lo, hi) in ((x_origin, x_dir, x_range), (0.0 * y_dir, y_dir, y_range)):
        a, b0, b1 = direction, lo - origin, hi - origin
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = b0 / a, b1 / a
        smin = np.where(a > 0, t1, np.where(a < 0, t2, np.where((b0 <= 0) & (b1 >= 0), -np.inf, np.inf)))
        smax = np.where(a > 0, t2, np.where(a < 0, t1, np.inf))
        s_lo = np.maximum(s_lo, smin)
        s_hi = np.minimum(s_hi, smax)
    return s_lo, s_lo <= s_hi


def stage_height_maps(
    true_rig: Rig,
    measure_rig: Rig,
    z_in_mm: Sequence[float],
    repeats: int,
    rng: np.random.Generator,
    sigma_code: float = REALISTIC_SIGMA_CODE,
    edge_gain: float = 0.0,
    dtype: type = np.float32,
) -> Iterator[tuple[float, int, np.ndarray]]:
    """Stream the height maps of a plane moved along Z by a stage (paper section 5).

    One noisy reference capture is drawn first and shared by all positions (as in
    a real session); every repeat draws fresh object noise. Heights are
    triangulated with ``measure_rig`` (the calibrated estimate).

    Yields
    ------
    (z_in_mm, repeat_index, z_mm) : (float, int, (height_px, width_px) array of ``dtype``)
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    ref = add_code_noise(true_rig, reference_codes(true_rig), rng, sigma_code, edge_gain)
    for z_in in z_in_mm:
        clean = exact_codes(true_rig, float(z_in))
        for r in range(repeats):
            obj = add_code_noise(true_rig, clean, rng, sigma_code, edge_gain)
            yield float(z_in), r, height_from_codes(measure_rig, ref, obj).astype(dtype)
