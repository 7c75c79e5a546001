"""The inspection pipeline's options (frozen, validated, JSON round trip) and its result: every
input point keeps its place, points without a usable sigma are undecided, timings recorded."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.inspection import alignment
from metrology.core.inspection.distance import SurfaceDistance
from metrology.core.inspection.scan import Scan
from metrology.pipeline.inspect import InspectOptions, inspect
from tests.core.inspection.parts import asymmetric_part, random_pose


def test_options_round_trip_and_validation() -> None:
    options = InspectOptions(
        init="pairs", pairs=(((0, 0, 0), (1, 1, 1)),) * 3, tolerance_mm=0.05, k=3.0, systematic_mm=0.001, seed=7
    )
    assert InspectOptions.from_dict(options.to_dict()) == options
    assert InspectOptions.from_dict({}) == InspectOptions()
    for bad, words in [
        ({"init": "guess"}, "init must be one of"),
        ({"init": "pairs"}, "at least 3 point pairs"),
        ({"tolerance_mm": 0}, "tolerance_mm must be a positive"),
        ({"k": -1}, "k must be"),
        ({"systematic_mm": float("nan")}, "systematic_mm must be"),
        ({"seed": -1}, "seed must be"),
        ({"colour": "red"}, "unknown inspect option"),
        ({"init": "pairs", "pairs": [{"scan": [0, 0], "nominal": [0, 0, 0]}] * 3}, "three finite numbers"),
    ]:
        with pytest.raises(ValueError, match=words):
            InspectOptions.from_dict(bad)


def test_every_point_keeps_its_place_and_unusable_sigma_is_undecided() -> None:
    nominal = asymmetric_part()
    surface = SurfaceDistance(nominal)
    rng = np.random.default_rng(12)
    points, _ = alignment.sample_surface(surface, 4000, rng)
    truth = random_pose(rng, angle_rad=0.01, shift_mm=0.3)
    scan_points = alignment.apply(np.linalg.inv(truth), points)
    scan_points[::10] = np.nan  # no point there
    sigma = np.full(4000, 0.001)
    sigma[5::10] = np.nan  # a point without a usable sigma
    result = inspect(nominal, Scan(scan_points, (4000,), sigma), InspectOptions(init="identity", tolerance_mm=0.01))
    assert np.isnan(result.deviation_mm[::10]).all() and np.isfinite(result.deviation_mm[1::10]).all()
    assert np.isfinite(result.deviation_mm[5::10]).all() and np.isnan(result.uncertainty_mm[5::10]).all()
    np.testing.assert_allclose(result.aligned_mm[1::10], points[1::10], atol=1e-9)
    report = result.report({})
    assert report["conformance"] == {"conforming": 3200, "nonconforming": 0, "undecided": 400}
    assert report["deviation"]["points"] == 3600 and abs(report["deviation"]["max_mm"]) < 1e-9
    assert report["alignment"]["points_used"] == 3200 and report["provenance"]["seed"] is None
    assert set(result.timings_s) >= {"inspect", "start", "best_fit", "deviations", "uncertainty"}


def test_a_scan_without_points_is_refused() -> None:
    with pytest.raises(ValueError, match="no points"):
        inspect(asymmetric_part(), Scan(np.full((3, 3), np.nan), (3,)))
