"""Rig validation and the derived constants of Eqs. 7, 12, 13, 15."""

import json
import math

import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG, REQUIRED_KEYS, Rig, RigError

RIG_JSON = {
    "L_mm": 1022.0,
    "d_mm": 352.0,
    "alpha_rad": 0.332,
    "fw_mm": 500.0,
    "nlp": 128,
    "width_px": 640,
    "height_px": 480,
}


def test_round_trip_keeps_extra_keys():
    rig = Rig.from_dict({**RIG_JSON, "name": "bench A", "calibration": {"method": "lsq"}})
    assert rig == PAPER_RIG
    data = rig.to_dict()
    assert data["name"] == "bench A" and data["calibration"] == {"method": "lsq"}
    assert Rig.from_json(json.dumps(data)).to_dict() == data


def test_gamma_matches_eq7():
    assert PAPER_RIG.gamma_rad == pytest.approx(math.atan((352 - 250) / 1022), abs=1e-15)


def test_gamma_may_be_negative_when_q_inside_field():
    rig = Rig.from_dict({**RIG_JSON, "d_mm": 200.0})
    assert rig.gamma_rad < 0


def test_pixel_coordinates_follow_design_1_1():
    x = PAPER_RIG.column_x_mm()
    y = PAPER_RIG.row_y_mm()
    assert x[0] == pytest.approx(352 - 250 + 0.5 * 500 / 640)
    assert x[-1] == pytest.approx(352 + 250 - 0.5 * 500 / 640)
    assert y[0] == pytest.approx(-240 * 500 / 640 + 0.5 * 500 / 640)
    assert y.mean() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_missing_key_is_named(key):
    data = {k: v for k, v in RIG_JSON.items() if k != key}
    with pytest.raises(RigError, match=key):
        Rig.from_dict(data)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("L_mm", 0),
        ("L_mm", -5.0),
        ("d_mm", float("nan")),
        ("fw_mm", "500"),
        ("alpha_rad", 0.0),
        ("alpha_rad", math.pi / 2),
        ("nlp", 0),
        ("nlp", 2.5),
        ("nlp", 129),
        ("width_px", -1),
        ("height_px", True),
    ],
)
def test_out_of_range_value_is_named(key, value):
    with pytest.raises(RigError, match=key):
        Rig.from_dict({**RIG_JSON, key: value})


def test_not_json():
    with pytest.raises(RigError, match="not valid JSON"):
        Rig.from_json("{L_mm: 3")
