"""Every decoding option (the code-space filters' thresholds and the gcps-v1 decoder's settings) is
validated where it enters, the error naming the option and the value."""

import numpy as np
import pytest

from metrology.core.decode import GcpsV1Options
from metrology.core.filters import FilterOptions
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.measure import MeasureOptions, decode_block, measure, prepare_reference, split_decode_block
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity
from metrology.core.synthetic import exact_codes, reference_codes

RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=64, height_px=48)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("min_modulation", -1.0),
        ("min_modulation", float("nan")),
        ("consistency_codes", -1),
        ("consistency_codes", float("inf")),
        ("smoothing_px", -2),
        ("smoothing_px", "1"),
        ("discontinuity_codes", -0.5),
        ("edge_band_px", -1),
        ("edge_band_px", 1.5),
        ("edge_band_px", True),
        ("field_margin_codes", 500),
        ("field_margin_codes", -0.1),
        ("min_visibility_ratio", 1.0),
        ("min_visibility_ratio", -0.2),
        ("blur_variance_px2", 100.0),
        ("blur_variance_px2", -1.0),
        ("max_blur_bias_codes", -0.01),
        ("max_blur_bias_codes", 1.0),
        ("max_blur_bias_codes", float("nan")),
    ],
)
def test_bad_option_raises_naming_it(name, value):
    gcps_v1_keys = GcpsV1Options.keys()  # the rest are the code-space filters'
    kind = GcpsV1Options if name in gcps_v1_keys else FilterOptions
    with pytest.raises(ValueError, match=rf"{name} .*got {value!r}".replace("(", r"\(").replace(")", r"\)")):
        kind(**{name: value})
    with pytest.raises(ValueError, match=rf"{name} .*got {value!r}".replace("(", r"\(").replace(")", r"\)")):
        split_decode_block({name: value})  # the JSON form's flat decode block names it too


def test_defaults_and_round_trip():
    filters, gcps_v1 = FilterOptions(edge_band_px=0), GcpsV1Options(smoothing_px=1.0)
    assert split_decode_block(decode_block(filters, gcps_v1)) == (filters, gcps_v1)
    options = MeasureOptions(filters=filters, gcps_v1=gcps_v1)
    assert MeasureOptions.from_dict(options.to_dict()) == options
    with pytest.raises(ValueError, match=r"unknown decode option.*smooth"):
        split_decode_block({"smooth": 1.0})


def _stack(codes: np.ndarray) -> np.ndarray:
    codes = np.where(np.isfinite(codes), codes, 0.0)  # out of the field: dark there anyway for the decoder
    return np.stack(
        [np.nan_to_num(np.round(20 + 200 * pattern_intensity(codes, n))).astype(np.uint8) for n in PATTERN_NAMES]
    )


def test_margin_that_leaves_no_field_is_refused_with_a_kept_reference():
    small = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=32, width_px=64, height_px=48)
    ref = _stack(reference_codes(small))
    obj = _stack(exact_codes(small, 20.0))
    kept = prepare_reference(small, ref)

    def margin(codes: float) -> MeasureOptions:
        return MeasureOptions(filters=FilterOptions(field_margin_codes=codes))

    with pytest.raises(ValueError, match=r"field_margin_codes .*got 20"):
        measure(small, obj, reference=kept, options=margin(20))
    with pytest.raises(ValueError, match=r"field_margin_codes .*got 20"):
        prepare_reference(small, ref, options=margin(20))
    z = measure(small, obj, reference=kept, options=margin(1)).z_mm
    assert np.nanmedian(z) == pytest.approx(20.0, abs=0.05)
