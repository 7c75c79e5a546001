"""The pipeline layer: free of Django, typed options validated with their names, results that carry
their options, the software version and timings."""

import ast
from pathlib import Path

import numpy as np
import pytest

from metrology.core.filters import FilterOptions
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity
from metrology.core.synthetic import exact_codes
from metrology.pipeline import (
    AcceptanceOptions,
    CalibrateOptions,
    CharacterizeOptions,
    MeasureOptions,
)
from metrology.pipeline.measure import measure
from metrology.version import software_version

PIPELINE = Path(__file__).resolve().parents[2] / "metrology" / "pipeline"
FORBIDDEN = {"django", "celery", "rest_framework", "redis", "workers", "plotly"}
RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=320, height_px=48)


@pytest.mark.parametrize("path", sorted(PIPELINE.glob("*.py")), ids=lambda p: p.name)
def test_pipeline_imports_no_application_layer(path):
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        for name in names:
            parts = name.split(".")
            assert parts[0] not in FORBIDDEN, f"{path.name} imports {name}"
            if parts[0] == "metrology" and len(parts) > 1:
                assert parts[1] in {"core", "pipeline", "version"}, f"{path.name} imports {name}"


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: MeasureOptions(gray_only=1), "gray_only must be true or false, got 1"),
        (lambda: MeasureOptions.from_dict({"decode": {"smoothing_px": -2}}), "smoothing_px"),
        (lambda: MeasureOptions.from_dict({"grey_only": True}), "unknown measure option(s): grey_only"),
        (lambda: CalibrateOptions(master_height_mm=0), "master_height_mm must be a positive number, got 0"),
        (lambda: CalibrateOptions(master_height_mm=40, method="newton"), "method must be one of lsq, paper"),
        (lambda: CalibrateOptions(master_height_mm=40, max_iterations=0), "max_iterations must be an integer"),
        (lambda: CalibrateOptions(master_height_mm=40, roi=((5, 2), (0, 9))), "roi must be"),
        (lambda: CharacterizeOptions(patch_px=4), "patch_px must be odd, got 4"),
        (lambda: CharacterizeOptions(margin_frac=0.5), "margin_frac must be a number in [0, 0.5), got 0.5"),
        (lambda: CharacterizeOptions(rows=()), "rows must list at least one row"),
        (lambda: AcceptanceOptions(test="probing"), "diameter_mm must be a positive number, got None"),
        (lambda: AcceptanceOptions(test="roundness"), "test must be one of flatness, probing, spacing"),
    ],
)
def test_bad_options_are_named(make, words):
    with pytest.raises(ValueError) as info:
        make()
    assert words in str(info.value)


def test_options_round_trip():
    for options in (
        MeasureOptions(filters=FilterOptions(edge_band_px=0), gray_only=False),
        CalibrateOptions(master_height_mm=40.0, method="paper", roi=((1, 9), (2, 8)), max_iterations=12),
        CharacterizeOptions(n_points=7, rows=(3, 9)),
        AcceptanceOptions(test="spacing", spacing_mm=100.0),
    ):
        assert type(options).from_dict(options.to_dict()) == options


def _stack(z_mm: float) -> np.ndarray:
    codes = np.nan_to_num(exact_codes(RIG, np.full(RIG.shape, z_mm)))
    return np.stack([np.round(20 + 200 * pattern_intensity(codes, n)).astype(np.uint8) for n in PATTERN_NAMES])


def test_measure_result_carries_options_version_and_timings():
    options = MeasureOptions(filters=FilterOptions(edge_band_px=1))
    result = measure(RIG, _stack(0.0), _stack(12.0), options)
    assert np.nanmedian(result.z_mm) == pytest.approx(12.0, abs=0.01)
    data = result.to_dict()
    assert data["options"] == options.to_dict() and data["options"]["decode"]["edge_band_px"] == 1
    assert data["software_version"] == software_version()
    assert data["timings_s"]["measure"] >= data["timings_s"]["measure.object_decode_triangulate_s"] > 0
    assert data["statistics"]["gray_only"]["valid_pixels"] > 0
