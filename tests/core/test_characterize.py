"""Linearity and accuracy characterization (paper section 5) on exact noisy code maps."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrology.core.calibrate import MasterCapture, calibrate_lsq
from metrology.core.characterize import characterize, heights_from_code_series, patch_means, place_test_points
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.synthetic import (
    add_code_noise,
    block_heights,
    exact_codes,
    reference_codes,
    stage_height_maps,
)

TRUTH = PAPER_RIG.with_parameters(width_px=160, height_px=120)
Z_IN = np.arange(0.0, 81.0, 4.0)  # the paper's 0..80 mm in 4 mm steps


def test_noise_free_exact_model_is_perfectly_linear() -> None:
    rng = np.random.default_rng(0)
    out = characterize(TRUTH, stage_height_maps(TRUTH, TRUTH, Z_IN, 2, rng, sigma_code=0.0))
    assert out["z_in_mm"] == Z_IN.tolist()
    assert len(out["test_points"]) >= 20
    for tp in out["test_points"]:
        assert tp["slope"] == pytest.approx(1.0, abs=1e-6)
        assert tp["intercept_mm"] == pytest.approx(0.0, abs=1e-4)
        assert tp["r2"] == pytest.approx(1.0, abs=1e-12)
    assert np.max(np.abs(out["mean_error_mm"])) < 1e-5
    assert out["overall"]["full_scale_mm"] == 80.0


@pytest.fixture(scope="module")
def lsq_rig():
    """The rig calibrated by least squares from the paper's rough start on a noisy 40 mm master."""
    rng = np.random.default_rng(10)
    ref = add_code_noise(TRUTH, reference_codes(TRUTH), rng)
    master = add_code_noise(TRUTH, exact_codes(TRUTH, block_heights(TRUTH, 40.0)), rng)
    start = TRUTH.with_parameters(L_mm=1080.0, alpha_rad=0.4871)
    return calibrate_lsq(start, MasterCapture(ref, master, 40.0)).rig


@pytest.mark.slow
def test_realistic_noise_paper_series_with_lsq_calibrated_rig(lsq_rig) -> None:
    rng = np.random.default_rng(11)
    out = characterize(TRUTH, stage_height_maps(TRUTH, lsq_rig, Z_IN, 30, rng))
    json.dumps(out, allow_nan=False)
    slopes = np.array([tp["slope"] for tp in out["test_points"]])
    assert np.all(np.abs(slopes - 1.0) < 5e-4)
    assert np.all(np.abs(out["mean_error_mm"]) < 0.015)
    assert all(0.005 < s < 0.05 for s in out["std_error_mm"])  # ~ 0.11 mm / 5 px per pixel patch
    overall = out["overall"]
    assert abs(overall["mean_error_mm"]) < 0.015
    assert overall["error_pct_fs"] == pytest.approx(
        100 * np.hypot(overall["mean_error_mm"], overall["std_error_mm"]) / 80.0
    )
    assert out["repeats"] == 30 and out["n_samples"] == [30 * len(slopes)] * len(Z_IN)


def test_sigma_grows_towards_edges_with_edge_noise() -> None:
    rng = np.random.default_rng(2)
    out = characterize(TRUTH, stage_height_maps(TRUTH, TRUTH, [0.0, 40.0, 80.0], 12, rng, edge_gain=0.7))
    assert out["edge_sigma_ratio"] > 1.3
    flat = characterize(
        TRUTH, stage_height_maps(TRUTH, TRUTH, [0.0, 40.0, 80.0], 12, np.random.default_rng(2), edge_gain=0.0)
    )
    assert flat["edge_sigma_ratio"] < out["edge_sigma_ratio"]


def test_mapping_input_equals_stream_and_code_series() -> None:
    rng = np.random.default_rng(3)
    items = list(stage_height_maps(TRUTH, TRUTH, [0.0, 20.0, 40.0], 3, rng))
    by_z: dict[float, list[np.ndarray]] = {}
    for z, _, m in items:
        by_z.setdefault(z, []).append(m)
    a = characterize(TRUTH, iter(items))
    b = characterize(TRUTH, by_z)
    assert a == b
    ref = reference_codes(TRUTH)
    codes = ((z, 0, exact_codes(TRUTH, z)) for z in (0.0, 8.0, 16.0))
    c = characterize(TRUTH, heights_from_code_series(TRUTH, ref, codes))
    assert c["overall"]["max_abs_slope_deviation"] < 1e-6


def test_several_rows_and_coordinates() -> None:
    centers = place_test_points(TRUTH, n_points=21, rows=3)
    assert len(centers) == 63 and len({r for r, _ in centers}) == 3
    out = characterize(TRUTH, {0.0: [np.zeros(TRUTH.shape)], 10.0: [np.full(TRUTH.shape, 10.0)]}, rows=3)
    tp = out["test_points"][0]
    r, c = centers[0]
    assert tp["x_mm"] == pytest.approx(TRUTH.column_x_mm()[c]) and tp["y_mm"] == pytest.approx(TRUTH.row_y_mm()[r])
    assert set(tp) >= {"x_mm", "y_mm", "slope", "intercept_mm", "r2"}


def test_nan_patches() -> None:
    z = np.full((20, 20), 5.0)
    z[0:5, 0:5] = np.nan
    z[10, 10] = np.nan
    means = patch_means(z, [(2, 2), (10, 10)], 5)
    assert np.isnan(means[0]) and means[1] == 5.0
    maps = {0.0: [np.zeros(TRUTH.shape)], 4.0: [np.full(TRUTH.shape, 4.0)], 8.0: [np.full(TRUTH.shape, np.nan)]}
    out = characterize(TRUTH, maps)
    assert out["test_points"][0]["n_positions"] == 2
    assert out["mean_error_mm"][2] is None
    json.dumps(out, allow_nan=False)


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match="two stage positions"):
        characterize(TRUTH, {0.0: [np.zeros(TRUTH.shape)]})
    with pytest.raises(ValueError, match="shape"):
        characterize(TRUTH, [(0.0, 0, np.zeros((3, 3)))])
    with pytest.raises(ValueError, match="patch_px"):
        characterize(TRUTH, {}, patch_px=4)
    with pytest.raises(ValueError, match="triples"):
        characterize(TRUTH, [1.0, 2.0])
