"""Camera blur: estimated from a reference capture, and its phase bias removed (blur.py)."""

import cv2
import numpy as np
import pytest

from metrology.core.blur import code_laplacian, correct_blur_bias, estimate_blur_variance
from metrology.core.decode import decode_stack
from metrology.core.rig import Rig
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


def test_estimate_refuses_too_little_data():
    with pytest.raises(ValueError, match="too few"):
        estimate_blur_variance(np.full((10, 10), np.nan), np.ones((10, 10)))
