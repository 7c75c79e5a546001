"""The codec self-check on the families added beside it: multi-level gray codes and beats of beats.

- right multi-level descriptions (L = 3, 4, 8) are ``consistent``;
- a wrong level count is never ``consistent``: refused by the level thresholding (every pixel
  reason 7, so the check has nothing to judge and says so) or ``inconsistent``;
- the issue's own case, a 4-level code described as the nearest binary code, is not ``consistent``;
- an axis without a gray code (three-frequency heterodyne) has nothing to check.

Noise-free 16-bit renders of a smooth view of the projector (tests/core/codecs/roundtrips.py).
"""

from __future__ import annotations

import pytest

from metrology.core.codecs import CodecError, codec_from_dict, render_codec
from metrology.core.codecs.check import CONSISTENT
from metrology.core.codecs.decode import decode_codec
from tests.core.codecs.roundtrips import PROJ_W, multilevel_codec, truth_maps

U, V = truth_maps()


@pytest.mark.parametrize(("levels", "digits"), [(3, 4), (4, 3), (8, 2)])
def test_right_multilevel_descriptions_are_consistent(levels: int, digits: int) -> None:
    codec = multilevel_codec(levels, digits, 8.0)
    check = decode_codec(render_codec(codec, U, None), codec).summary()["codec_check"]
    assert check["u"]["status"] == CONSISTENT, check["u"]


@pytest.mark.parametrize(("true_levels", "described"), [(4, 3), (3, 4), (4, 8), (4, 2), (3, 2)])
def test_a_wrong_level_count_is_never_consistent(true_levels: int, described: int) -> None:
    """The same frames described with another level count: words of the same width (the level
    thresholding then refuses the axis) or, for the binary description, as wide as the described
    digits need to span the same projector (validation refuses a word wider than the phase period)."""
    digits = {2: 5, 3: 4, 4: 3}[true_levels]
    truth = multilevel_codec(true_levels, digits, 8.0)
    images = render_codec(truth, U, None)
    for word in (8.0, 8.0 * true_levels**digits / described**digits):
        try:
            wrong = multilevel_codec(described, digits, word)
        except CodecError as exc:
            assert "word" in str(exc)
            continue
        summary = decode_codec(images, wrong).summary()
        refused = summary.get("gray_levels", {}).get("u", {}).get("status") == "refused"
        check = summary["codec_check"]["u"]
        assert refused or check["status"] != CONSISTENT, (word, summary.get("gray_levels"), check)


def test_an_axis_without_a_gray_code_has_nothing_to_check() -> None:
    codec = codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 24,
            "projector": {"width": PROJ_W, "height": 192},
            "axes": {
                "u": {
                    "phase": [
                        {"frames": list(range(8 * i, 8 * i + 8)), "period": PROJ_W / n, "origin": -0.5}
                        for i, n in enumerate((64, 58, 53))
                    ],
                    "unwrap": ["beat:(0,1),(1,2)", "beat:0,1", "phase:0"],
                }
            },
        }
    )
    summary = decode_codec(render_codec(codec, U, None), codec).summary()
    assert "u" not in summary["codec_check"]
