"""The noise-aware visibility-dip test of the mixed-pixel filter (metrology.core.filters): the
camera noise pooled by intensity, the visibility's standard deviation, and dips that fire on mixed
pixels but not on noise."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.filters import noise_by_intensity, unreliable_mask, visibility_sigma


@pytest.mark.parametrize("dof", [1, 5])
def test_noise_by_intensity_recovers_the_camera_noise_from_noisy_estimates(dof: int) -> None:
    """Read plus shot noise, sigma^2 = 1 + 0.05 A, estimated per pixel with ``dof`` degrees of
    freedom (s^2 = sigma^2 chi2(dof) / dof): the binned medians give sigma(A) within 4 %."""
    rng = np.random.default_rng(0)
    mean = rng.uniform(5.0, 200.0, (300, 400)).astype(np.float32)
    sigma = np.sqrt(1.0 + 0.05 * mean)
    noise = (sigma * np.sqrt(rng.chisquare(dof, mean.shape) / dof)).astype(np.float32)
    noise[::10, ::10] = 1e3  # 1 % of outliers (saturated pixels' residuals) do not move a median
    mean[0, :10] = np.nan
    estimated = noise_by_intensity(mean, noise, dof)
    assert estimated.dtype == np.float32 and np.isnan(estimated[0, :10]).all()
    inside = (mean > 20) & (mean < 190)
    np.testing.assert_allclose(estimated[inside], sigma[inside], rtol=0.06)
    assert np.isnan(noise_by_intensity(mean[:2, :4], noise[:2, :4], dof)).all()  # too few pixels
    with pytest.raises(ValueError, match="dof"):
        noise_by_intensity(mean, noise, 0)


def test_visibility_sigma_matches_monte_carlo() -> None:
    """V = B / 2A of an 8-step fit at 1.5 grey levels of noise, B = 10, A = 12.5: the spread of
    the fitted V over many draws is the predicted sigma_V within 3 %."""
    rng = np.random.default_rng(1)
    steps, b, a, s = 8, 10.0, 12.5, 1.5
    k = np.arange(steps)
    frames = a + b * np.cos(0.7 - 2 * np.pi * k / steps) + rng.normal(0, s, (20000, steps))
    c = frames @ np.cos(2 * np.pi * k / steps)
    si = frames @ np.sin(2 * np.pi * k / steps)
    v = (2 / steps) * np.hypot(c, si) / (2 * frames.mean(axis=1))
    predicted = visibility_sigma(
        np.full((1, 1), b / (2 * a), np.float32), np.full((1, 1), a, np.float32), np.full((1, 1), s, np.float32), 8, 8
    )
    assert predicted[0, 0] == pytest.approx(np.std(v), rel=0.03)


def test_visibility_dips_fire_on_mixed_pixels_not_on_noise() -> None:
    """A plane of visibility 0.4 with 7.5 % of noise (a modulation of 10 grey levels): the noise-
    blind test seeds a large share of the pixels, the noise-aware one almost none; a column of 50/50
    mixed pixels (77 % of the visibility) with 1 % of noise is found either way."""
    rng = np.random.default_rng(2)
    shape = (120, 160)
    codes = np.tile(np.arange(shape[1], dtype=np.float32) * 0.1, (shape[0], 1))
    v0 = np.float32(0.4)
    noisy = (v0 * (1 + 0.075 * rng.standard_normal(shape))).astype(np.float32)
    sigma = np.full(shape, 0.075 * v0, np.float32)
    blind = unreliable_mask(codes, 1.0, 1, noisy, 0.85)
    aware = unreliable_mask(codes, 1.0, 1, noisy, 0.85, visibility_noise=sigma)
    interior = np.s_[2:-2, 2:-2]
    assert blind[interior].mean() > 0.5
    assert aware[interior].mean() < 0.01
    # a step at column 80: the mixed column keeps 77 % of the visibility; sharp visibility
    clean = (v0 * (1 + 0.01 * rng.standard_normal(shape))).astype(np.float32)
    clean[:, 80] *= np.float32(0.77)
    sharp = np.full(shape, 0.01 * v0, np.float32)
    found = unreliable_mask(codes, 1.0, 1, clean, 0.85, visibility_noise=sharp)
    assert found[interior][:, 80 - 2].all()  # the mixed column (interior columns start at 2)
    assert found[interior][:, 80 - 3 : 80].all() and not found[interior][:, :70].any()
    # NaN sigma (no noise estimate) makes no seed; the tiled run equals the single one
    unknown = unreliable_mask(codes, 1.0, 1, clean, 0.85, visibility_noise=np.full(shape, np.nan, np.float32))
    assert not unknown[interior].any()
    tiled = unreliable_mask(codes, 1.0, 1, noisy, 0.85, threads=2, visibility_noise=sigma)
    np.testing.assert_array_equal(tiled, aware)
