"""Camera blur: estimated from a reference capture, and its phase bias removed (blur.py)."""

import cv2
import numpy as np
import pytest

from metrology.core.blur import blur_bias_exceeds, code_laplacian, correct_blur_bias, estimate_blur_variance
from metrology.core.decode import decode_stack
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack

RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=640, height_px=120)


def effective_blur_variance(blur_px: float, supersample: int = 3) -> float:
    """Variance of the virtual rig's blur: the sampled Gaussian kernel that cv2.GaussianBlur uses
    for float images (size round(8 sigma + 1) | 1) plus the area average of the sub-samples."""
    area = (1 - 1 / supersample**2) / 12
    if blur_px == 0:
        return area
    size = round(8 * blur_px + 1) | 1
    kernel = cv2.getGaussianKernel(size, blur_px, cv2.CV_64F).ravel()
    offsets = np.arange(size) - size // 2
    return float(np.sum(kernel * offsets**2)) + area


@pytest.mark.parametrize("blur_px", [0.0, 0.5, 0.7, 1.0])
def test_blur_variance_from_the_reference(blur_px):
    """The fit recovers the camera blur plus the pixel's own area within 12 % at realistic noise."""
    options = SimulationOptions.realistic_8bit(camera_defocus_px=blur_px, seed=5)
    decoded = decode_stack(render_stack(RIG, make_scene("reference", RIG), options).images)
    expected = effective_blur_variance(blur_px)
    assert estimate_blur_variance(decoded.codes, decoded.visibility) == pytest.approx(expected, rel=0.12)


@pytest.mark.parametrize("blur_px", [0.5, 0.7])
def test_blur_variance_of_a_centre_sampled_camera(blur_px):
    """camera_sampling="centre": no pixel area, the blur is the Gaussian alone (0.49 px^2 at 0.7 px)."""
    options = SimulationOptions.realistic_8bit(camera_defocus_px=blur_px, camera_sampling="centre", seed=5)
    decoded = decode_stack(render_stack(RIG, make_scene("reference", RIG), options).images)
    expected = effective_blur_variance(blur_px, supersample=1)
    assert estimate_blur_variance(decoded.codes, decoded.visibility) == pytest.approx(expected, rel=0.12)


def test_blur_bias_bound_on_a_quadratic_and_at_a_crease():
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    out = np.empty((40, 50), bool)
    # a quadratic: laplacian 0.008 code/px^2 everywhere, bias s2/2 * 0.008 = 0.002 code at s2 = 0.5
    codes = (0.2 * x + 0.003 * x**2 + 0.001 * y**2).astype(np.float32)
    assert blur_bias_exceeds(codes, 0.5, 0.0019, out)[2:-2, 2:-2].all()
    assert not out[:2].any() and not out[-2:].any() and not out[:, :2].any() and not out[:, -2:].any()
    assert not blur_bias_exceeds(codes, 0.5, 0.0021, out).any()
    assert not blur_bias_exceeds(codes, 0.0, 0.0019, out).any()  # no blur, no bias
    # a crease: the slope goes from 0.2 to 0.7 code/px at x = 20.5. The 5x5 Savitzky-Golay
    # second derivative [2, -1, -2, -1, 2] / 7 sees it in columns 19-22 only (0.179 code/px^2
    # in columns 20 and 21: bias 0.045 code at s2 = 0.5); a plane on each side of it
    crease = (0.2 * x + 0.5 * np.maximum(x - 20.5, 0)).astype(np.float32)
    mask = blur_bias_exceeds(crease, 0.5, 0.015, out)
    assert mask[2:-2, 19:23].all() and not mask[:, :19].any() and not mask[:, 23:].any()
    holed = crease.copy()
    holed[20, 20] = np.nan  # its 5x5 window is incomplete: not tested
    assert not blur_bias_exceeds(holed, 0.5, 0.015, out)[18:23, 18:23].any()


def test_laplacian_of_a_quadratic_and_the_correction():
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    codes = (0.2 * x + 0.003 * x**2 + 0.001 * y**2).astype(np.float32)  # laplacian 0.008
    lap = code_laplacian(codes)
    np.testing.assert_allclose(lap[2:-2, 2:-2], 0.008, atol=1e-4)
    assert np.isnan(lap[:2]).all() and np.isnan(lap[:, -2:]).all()
    corrected = correct_blur_bias(codes.copy(), 0.5)
    np.testing.assert_allclose((codes - corrected)[5:-5, 5:-5], 0.25 * 0.008, atol=1e-4)
    holed = codes.copy()
    holed[20, 25] = np.nan
    out = correct_blur_bias(holed, 0.5)
    assert np.isnan(out[20, 25])
    assert out[20, 24] == pytest.approx(codes[20, 24] - 0.002, abs=1e-4)  # carried next to the hole
    with pytest.raises(ValueError, match="blur_variance_px2"):
        correct_blur_bias(codes, -1.0)


def test_correction_on_row_tiles_equals_the_whole_frame(monkeypatch):
    # 256 x 512 px: one tile on one thread, four tiles of 64 rows on two or three (tiling.run_tiled);
    # each tile reads 8 rows either side, what the 5x5 Laplacian and the 13-tap smoothing reach
    y, x = np.mgrid[0:256, 0:512].astype(np.float64)
    codes = (0.2 * x + 0.003 * x**2 + 0.001 * y**2).astype(np.float32)  # laplacian 0.008 everywhere
    rng = np.random.default_rng(3)
    codes += rng.normal(0, 0.01, codes.shape).astype(np.float32)
    codes[rng.random(codes.shape) < 0.02] = np.nan
    codes[60:70, 100:140] = np.nan  # a hole across the first tiles' boundary (row 64)
    whole = correct_blur_bias(codes.copy(), 0.5, threads=1)
    for threads in (2, 3):
        assert np.array_equal(correct_blur_bias(codes.copy(), 0.5, threads=threads), whole, equal_nan=True)
    import metrology.core.blur as blur_module

    monkeypatch.setattr(blur_module, "_HALO_ROWS", blur_module._HALO_ROWS - 1)  # one row less is not enough
    assert not np.array_equal(correct_blur_bias(codes.copy(), 0.5, threads=2), whole, equal_nan=True)
    monkeypatch.undo()
    # and the correction is s2 / 2 * laplacian = 0.002 code, noise averaged over 1.5 px, away from holes
    diff = (codes - whole)[120:250, 200:500]
    assert np.nanmedian(diff) == pytest.approx(0.002, abs=2e-4)


def test_estimate_refuses_too_little_data():
    with pytest.raises(ValueError, match="too few"):
        estimate_blur_variance(np.full((10, 10), np.nan), np.ones((10, 10)))
