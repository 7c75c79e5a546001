"""Per-point height uncertainty of the crossed-axes model (issue 12 item 3): the noise estimate,
the propagation through Eqs. 14-17, and the prediction against the scatter of repeated renders."""

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG, height_from_codes
from metrology.core.measure import MeasureOptions, measure, prepare_reference
from metrology.core.precision import (
    crossed_axes_sigma_mm,
    four_step_noise_grey,
    gcps_code_sigma,
    gcps_sigma_mm,
    light_code_sigma,
)
from metrology.core.simulate import SimulationOptions, render_series


def test_four_step_noise_estimate_recovers_the_camera_noise() -> None:
    rng = np.random.default_rng(3)
    h, w, noise = 200, 300, 2.3
    phi = rng.uniform(0, 2 * np.pi, (h, w))
    frames = np.stack([100 + 60 * np.cos(phi - i * np.pi / 2) for i in range(4)])
    frames += noise * rng.standard_normal(frames.shape)
    assert four_step_noise_grey(frames) == pytest.approx(noise, rel=0.01)  # 60,000 samples: ~0.3 % s.d.


def test_propagation_matches_finite_differences_of_eqs_14_to_17() -> None:
    rig = PAPER_RIG
    r = np.array([[10.0, 40.0], [70.0, 100.0]])
    l = r + np.array([[3.0, 5.0], [8.0, 1.5]])
    s_r, s_l = 0.002, 0.003
    eps = 1e-5
    dz_dl = (height_from_codes(rig, r, l + eps) - height_from_codes(rig, r, l - eps)) / (2 * eps)
    dz_dr = (height_from_codes(rig, r + eps, l) - height_from_codes(rig, r - eps, l)) / (2 * eps)
    expected = np.hypot(dz_dl * s_l, dz_dr * s_r)
    got = crossed_axes_sigma_mm(rig, r, l, s_r, s_l)
    assert got.dtype == np.float32 and got.shape == (2, 2)
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_nan_codes_and_zero_modulation_give_nan() -> None:
    sigma = gcps_code_sigma(np.array([[0.0, 50.0]]), 1.5)
    assert np.isnan(sigma[0, 0]) and sigma[0, 1] == pytest.approx(2 / np.pi * 1.5 * np.sqrt(2) / 50)
    out = crossed_axes_sigma_mm(
        PAPER_RIG, np.array([[np.nan, 10.0]]), np.array([[10.0, 12.0]]), sigma[:, ::-1], sigma[:, ::-1]
    )
    assert np.isnan(out).all()  # the first by its code, the second by its sigma
    assert np.isfinite(
        crossed_axes_sigma_mm(PAPER_RIG, 10.0 * np.ones((1, 1)), 12.0 * np.ones((1, 1)), 0.01, 0.01)
    ).all()


def test_codec_coordinate_sigma_scales_to_light_codes() -> None:
    got = light_code_sigma(PAPER_RIG, np.array([0.5, 2.0]), 1024)
    np.testing.assert_allclose(got, np.array([0.5, 2.0]) * PAPER_RIG.nlp / 1024, rtol=1e-6)
    with pytest.raises(ValueError, match="projector_width"):
        light_code_sigma(PAPER_RIG, 1.0, 0)


@pytest.mark.slow
def test_predicted_sigma_matches_the_scatter_of_30_realistic_renders_of_a_plane() -> None:
    """Issue 12 must-show: 30 realistic 8-bit renders (different noise seeds) of a reference and a
    plane 20 mm above it; the per-pixel standard deviation of the heights over the renders against
    the predicted sigma (its rms over the renders): median ratio within 15 %."""
    rig = PAPER_RIG
    captures: dict[float, list[np.ndarray]] = {}
    for z, _repeat, rendered in render_series(rig, [0.0, 20.0], 30, SimulationOptions.realistic_8bit(seed=5)):
        captures.setdefault(z, []).append(rendered.images)
    heights, sigmas = [], []
    for ref_images, obj_images in zip(captures[0.0], captures[20.0], strict=True):
        reference = prepare_reference(rig, ref_images)
        result = measure(rig, obj_images, reference=reference, options=MeasureOptions(gray_only=False))
        heights.append(result.z_mm)
        sigmas.append(gcps_sigma_mm(rig, reference.codes, result.codes, ref_images, obj_images))
    z = np.array(heights)
    sigma = np.array(sigmas)
    assert sigma.dtype == np.float32
    valid = np.isfinite(z).all(axis=0) & np.isfinite(sigma).all(axis=0)
    assert valid.mean() > 0.9
    observed = z[:, valid].std(axis=0, ddof=1)
    predicted = np.sqrt(np.mean(sigma[:, valid].astype(np.float64) ** 2, axis=0))
    ratio = float(np.median(observed / predicted))
    assert 0.85 <= ratio <= 1.15, f"observed / predicted sigma: median {ratio:.3f}"
    assert 0.05 < float(np.median(predicted)) < 0.2  # ~0.11 mm on this rig
