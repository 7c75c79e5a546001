"""The 2-D match's kernels (``metrology.core.geometry.match_2d_kernels``) against analytic truths:
camera 1's maps given as polynomials of the pixel position, each query pair's true position known.
Small grids: each test takes well under a second once the kernels are compiled."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from metrology.core.distortion import Distortion, undistort_pixels
from metrology.core.geometry.match_2d_kernels import cell_buckets, match_2d_tile, undistort_tile
from metrology.core.geometry.stereo_match import prepare_stereo
from tests.stereo_rig import RIG

H, W = 40, 48
BUCKET = 2.0


def _maps(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera 1's ``(u, v)`` at pixel positions ``(x, y)``: a cubic map with bending fringes (``u'' / u'``
    about 0.01 / px, as on a curved surface), monotone in both axes."""
    u = 20.0 + 1.6 * x + 0.1 * y + 0.008 * x * x - 0.002 * x * y + 3e-5 * x**3
    v = 10.0 + 0.05 * x + 1.5 * y + 0.006 * y * y + 0.001 * x * y - 2e-5 * y**3
    return u, v


def _match(u0: np.ndarray, v0: np.ndarray, u1: np.ndarray, v1: np.ndarray, cubic: bool) -> tuple[np.ndarray, ...]:
    nu = math.ceil((float(np.nanmax(u1)) + 2.0) / BUCKET)
    nv = math.ceil((float(np.nanmax(v1)) + 2.0) / BUCKET)
    start, cells = cell_buckets(u1, v1, BUCKET, nu, nv)
    x1 = np.empty(u0.shape, np.float32)
    y1 = np.empty(u0.shape, np.float32)
    slopes = np.empty((*u0.shape, 5), np.float32)
    match_2d_tile(u0, v0, u1, v1, start, cells, BUCKET, nu, nv, cubic, x1, y1, slopes)
    return x1, y1, slopes


def _queries(rng: np.random.Generator, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """True positions inside camera 1's grid, away from its border (the bicubic needs a pixel around the cell)."""
    return rng.uniform(2.0, W - 3.0, (1, n)), rng.uniform(2.0, H - 3.0, (1, n))


def test_the_2d_match_finds_a_cubic_maps_positions_without_the_bilinear_bias() -> None:
    """The bilinear inverse of a cell misplaces a match by up to ``u'' / (8 u')`` px; the bicubic
    refinement (Lagrange cubics through 4 x 4 pixels, exact for a cubic map) finds the true position
    to float32 rounding, and its slopes are the map's derivatives there."""
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float64)
    u1, v1 = (m.astype(np.float32) for m in _maps(gx, gy))
    xt, yt = _queries(np.random.default_rng(3))
    u0, v0 = (m.astype(np.float32) for m in _maps(xt, yt))
    truth_u, truth_v = _maps(xt, yt)
    errors = {}
    for cubic in (False, True):
        x1, y1, slopes = _match(u0, v0, u1, v1, cubic)
        assert np.isfinite(x1).all(), "every query lies in one cell: all matched"
        errors[cubic] = np.hypot(x1 - xt, y1 - yt)
    # bilinear: the chord's error, s (1 - s) u_xx / (2 u_x) with u_xx = 0.016 + 1.8e-4 x, u_x >= 1.6: up to ~1e-3 px
    print(f"bilinear max {errors[False].max():.2e} px, bicubic max {errors[True].max():.2e} px")
    assert errors[False].max() > 5e-4
    # the float32 inputs (u near 100 carries 4e-6 of rounding, 3e-6 px) and the float32 output (2e-6 px near 40)
    assert errors[True].max() < 2e-5
    # the slopes at the match: du/dx, du/dy, dv/dx, dv/dy of the cubic map (exact to its cubic term's rounding)
    x1, y1, slopes = _match(u0, v0, u1, v1, True)
    eps = 1e-4
    du_dx = (_maps(xt + eps, yt)[0] - truth_u) / eps
    dv_dy = (_maps(xt, yt + eps)[1] - truth_v) / eps
    assert np.allclose(slopes[..., 0], du_dx, atol=1e-3) and np.allclose(slopes[..., 3], dv_dy, atol=1e-3)
    # the noise gain of the bicubic value: sqrt(sum L_i(s)^2 sum L_j(t)^2), 1 at a pixel, 0.633 at a centre
    # (taken before Newton's last step, within 1e-3 px of the match: its slope is below 1.2 per px)
    s, t = x1 - np.floor(x1), y1 - np.floor(y1)

    def lagrange_sq(a: np.ndarray) -> np.ndarray:
        w = [
            -a * (a - 1) * (a - 2) / 6,
            (a + 1) * (a - 1) * (a - 2) / 2,
            -(a + 1) * a * (a - 2) / 2,
            (a + 1) * a * (a - 1) / 6,
        ]
        return sum(wi * wi for wi in w)

    assert np.allclose(slopes[..., 4], np.sqrt(lagrange_sq(s) * lagrange_sq(t)), atol=1.2e-3)


def test_a_missing_pixel_of_the_4x4_falls_back_to_the_bilinear_cell() -> None:
    """A query whose cell is complete but one of the 12 pixels around it is undecoded is still matched,
    by the cell's bilinear inverse (the chord's error, 1.4e-3 px here); one whose cell lacks a
    corner is not matched."""
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float64)
    u1, v1 = (m.astype(np.float32) for m in _maps(gx, gy))
    u1[19, 19] = np.nan  # outside the cell (20..21, 20..21), inside its 4 x 4
    u1[30, 30] = np.nan  # a corner of the cells around (29.5, 29.5)
    xt, yt = np.array([[20.4, 29.5]]), np.array([[20.6, 29.5]])
    u0, v0 = (m.astype(np.float32) for m in _maps(xt, yt))
    x1, y1, slopes = _match(u0, v0, u1, v1, True)
    chord = np.hypot(x1[0, 0] - 20.4, y1[0, 0] - 20.6)
    assert 1e-4 < chord < 3e-3  # the bilinear position (the bicubic's would be within 2e-5 px)
    assert np.isnan(x1[0, 1]) and np.isnan(slopes[0, 1]).all()


@pytest.mark.parametrize(
    "dist", [(-0.1, 0.05, 0.0006, -0.0004, 0.0), (0.2, -0.1, 0.001, 0.002, 0.01, 0.05, -0.02, 0.01)]
)
def test_the_compiled_undistortion_agrees_with_undistort_pixels(dist: tuple[float, ...]) -> None:
    """Camera 1's matched pixels to undistorted normalized coordinates: the compiled Newton of the
    2-D match and :func:`undistort_pixels` (damped Newton to 1e-6 px) agree within 1e-6 px over the
    whole image, and the Jacobian is the model's (``distort_with_jacobian``)."""
    distortion = Distortion.from_coeffs(dist)
    K = np.array([[995.0, 0.3, 161.2], [0.0, 996.0, 126.1], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(5)
    x = rng.uniform(-0.5, 319.5, (8, 50)).astype(np.float32)
    y = rng.uniform(-0.5, 255.5, (8, 50)).astype(np.float32)
    x[0, 0] = np.nan
    out = np.empty((8, 50, 6))
    camera = np.array([K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]])
    assert undistort_tile(x, y, camera, distortion.coeffs, 1e-6, out) == 0
    assert np.isnan(out[0, 0]).all()
    ref = undistort_pixels(K, distortion, x.astype(np.float64), y.astype(np.float64))
    ok = np.isfinite(x)
    error_px = np.hypot(out[..., 0] - ref.x, out[..., 1] - ref.y)[ok] * K[0, 0]
    assert error_px.max() < 1e-6
    _, _, jac = distortion.distort_with_jacobian(out[..., 0], out[..., 1])
    for e in range(4):
        assert np.allclose(out[..., 2 + e][ok], jac[e][ok], rtol=0, atol=1e-12)


@pytest.mark.parametrize("tilt", [0.0, 0.01])
def test_camera1s_matched_pixels_are_undistorted_for_any_lens(tilt: float) -> None:
    """The 2-D match's undistortion of camera 1's matched pixels (:class:`PreparedStereo2D`): compiled
    for an untilted lens, through :func:`undistort_pixels` for a tilted sensor (14 coefficients) and
    for a point the compiled Newton leaves unconverged (far outside the image); either way the result
    is :func:`undistort_pixels`'s within 1e-6 px and NaN stays NaN."""
    dist = (-0.08, 0.03, -0.0003, 0.0005, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, tilt, -tilt)
    camera1 = replace(RIG.camera1, dist=dist)
    prepared = prepare_stereo(replace(RIG, camera1=camera1), "u", "2d")
    rng = np.random.default_rng(8)
    x = rng.uniform(-0.5, 319.5, (4, 30)).astype(np.float32)
    y = rng.uniform(-0.5, 255.5, (4, 30)).astype(np.float32)
    x[0, 0] = np.nan
    x[1, 1], y[1, 1] = -4.0e4, 3.0e4  # beyond where the plain Newton converges in its steps
    out = prepared._undistort_camera1(x, y)  # type: ignore[attr-defined]
    K = np.asarray(camera1.K)
    ref = undistort_pixels(K, camera1.distortion, x.astype(np.float64), y.astype(np.float64))
    assert np.isnan(out[0, 0]).all() and np.isfinite(out[2:]).all()
    same = np.isfinite(ref.x)
    assert np.array_equal(np.isfinite(out[..., 0]), same)
    error_px = np.hypot(out[..., 0] - ref.x, out[..., 1] - ref.y)[same] * K[0][0]
    assert error_px.max() < 1e-6
