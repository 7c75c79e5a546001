"""Each reason code of the quality maps, provoked on purpose (docs/codecs.md, reason codes)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict, render_codec
from metrology.core.codecs.decode import (
    REASON_INCONSISTENT,
    REASON_LOW_INVERSE_CONTRAST,
    REASON_OUTSIDE,
    REASON_SATURATED,
    REASON_SLIP_REPAIRED,
    REASON_TOO_DARK,
    REASON_VALID,
    CodecDecodeOptions,
    decode_codec,
)
from metrology.core.simulate import SimulationOptions

H, W = 20, 64


def codec(word: float = 16.0, inverse: bool = False, width: int = 256) -> Any:
    bits = int(np.ceil(np.log2((width + 1) / word)))
    gray: dict[str, Any] = {"frames": list(range(4, 4 + bits)), "word": word, "origin": -0.5}
    frames = 4 + bits
    if inverse:
        gray["inverse_frames"] = list(range(frames, frames + bits))
        frames += bits
    axis = {"phase": [{"frames": [0, 1, 2, 3], "period": 16.0, "origin": -0.5}], "gray": gray}
    return codec_from_dict(
        {"codec": "gcps-codec/1", "frames": frames, "projector": {"width": width, "height": 8}, "axes": {"u": axis}}
    )


def truth() -> np.ndarray:
    return np.broadcast_to(0.37 + 3.9 * np.arange(W, dtype=np.float64), (H, W)).copy()


def test_dark_saturated_and_flagged_gray_saturation() -> None:
    c = codec()
    u = truth()
    albedo = np.ones((H, W))
    albedo[2, 2] = 0.0
    images = render_codec(c, u, None, SimulationOptions(bit_depth=8), albedo=albedo)
    images[1, 5, 5] = 255  # a phase frame
    images[4, 6, 6] = 255  # a gray frame: flagged, not refused
    decoded = decode_codec(images, c)
    reason = decoded.axes["u"].reason
    assert reason[2, 2] == REASON_TOO_DARK
    assert reason[5, 5] == REASON_SATURATED and np.isnan(decoded.axes["u"].coordinate[5, 5])
    assert reason[6, 6] != REASON_SATURATED
    assert decoded.saturated_pixels == 2
    others = np.ones((H, W), bool)
    others[2, 2] = others[5, 5] = others[6, 6] = False
    assert (reason[others] == REASON_VALID).all()


def test_low_inverse_contrast() -> None:
    c = codec(inverse=True)
    images = render_codec(c, truth(), None, SimulationOptions(bit_depth=8))
    g = c.axes["u"].gray
    images[g.inverse_frames[2], 3, 3] = images[g.frames[2], 3, 3] + 1  # contrast 1 < 4 grey levels
    reason = decode_codec(images, c).axes["u"].reason
    assert reason[3, 3] == REASON_LOW_INVERSE_CONTRAST
    assert (np.delete(reason.ravel(), 3 * W + 3) == REASON_VALID).all()


def test_gray_phase_inconsistent_and_outside() -> None:
    c = codec(word=4.0)
    u = np.full((H, W), 108.3)
    images = render_codec(c, u, None)
    images[4:, 0, 0] = 0  # gray word 0 (centre 1.5) where the phase says 108.3 mod 16
    # x = -3.7: 5.2 from the word's centre, more than 2 + 0.05 * 16 (and outside the projector)
    options = CodecDecodeOptions(consistency_periods=0.05)
    reason = decode_codec(images, c, options).axes["u"].reason
    assert reason[0, 0] == REASON_INCONSISTENT
    # with the default tolerance (2 + 4 px) it is consistent but outside the projector
    assert decode_codec(images, c).axes["u"].reason[0, 0] == REASON_OUTSIDE
    wide = codec()
    spec = wide.to_dict()
    spec["projector"]["width"] = 128  # the same frames, read as a narrower projector
    narrow = codec_from_dict(spec)
    reason = decode_codec(render_codec(wide, truth(), None), narrow).axes["u"].reason
    outside = truth() > 127.5
    assert outside.any() and (reason[outside] == REASON_OUTSIDE).all() and (reason[~outside] == REASON_VALID).all()


def test_slip_repaired_and_kept() -> None:
    c = codec(word=16.0)
    u = truth()
    images = render_codec(c, u, None)
    # a pixel just right of a gray edge (u = 47.5) given the gray bits of its left neighbour
    col = int(np.argmax((u[0] > 47.5) & (u[0] < 51.5)))
    assert u[0, col - 1] < 47.5
    images[4:, 7, col] = images[4:, 7, col - 1]
    decoded = decode_codec(images, c)
    axis = decoded.axes["u"]
    assert axis.reason[7, col] == REASON_SLIP_REPAIRED and axis.slips_repaired == 1
    assert abs(axis.coordinate[7, col] - u[7, col]) < 0.01
    unrepaired = decode_codec(images, c, CodecDecodeOptions(repair_slips=False)).axes["u"]
    assert abs(unrepaired.coordinate[7, col] - (u[7, col] - 16.0)) < 0.01


def test_depth_edge_is_not_taken_for_a_slip() -> None:
    """A pixel on the near side of a step whose 5x5 neighbourhood lies mostly on the far side (the
    median on the other surface, 30 px away) is correct as decoded: the repair would move it by two
    words, far outside the cell of the gray word it read, so it is left alone (found in a pinhole
    render of a sphere, pixel (97, 88), moved by 32 px)."""
    c = codec(word=16.0)
    u = truth()
    row, col = 10, 20
    far = np.zeros((H, W), bool)  # the far surface: rows above the step and the rest of its row
    far[:row, :48] = True
    far[row, :48] = np.arange(48) != col
    u[far] += 30.0
    images = render_codec(c, u, None)
    axis = decode_codec(images, c).axes["u"]
    valid = axis.valid
    assert valid[row - 2 : row + 3, col - 2 : col + 3].all()
    assert axis.slips_repaired == 0 and axis.reason[row, col] == REASON_VALID
    assert np.abs(axis.coordinate[valid] - u[valid]).max() < 0.01


def _two_period_codec() -> Any:
    """u: phase 0 (period 16, frames 0-3), phase 1 (period 64, frames 4-7), gray words of 16 px
    (frames 8-12), chain gray -> phase 1 -> phase 0."""
    axis = {
        "phase": [
            {"frames": [0, 1, 2, 3], "period": 16.0, "origin": -0.5},
            {"frames": [4, 5, 6, 7], "period": 64.0, "origin": -0.5},
        ],
        "gray": {"frames": list(range(8, 13)), "word": 16.0, "origin": -0.5},
        "unwrap": ["gray", "phase:1", "phase:0"],
    }
    return codec_from_dict(
        {"codec": "gcps-codec/1", "frames": 13, "projector": {"width": 256, "height": 8}, "axes": {"u": axis}}
    )


def test_every_stage_is_checked_against_the_gray_word_and_its_coarser_stage() -> None:
    """The 64-px stage shown shifted: by 16 px (a whole fine period) it passes the gray check of
    the first stage (8 + 16 px) but moves the 16-px stage by a period, outside the word's cell
    (8 + 4 px): refused; by 0.4 fine periods it strays from the fine stage by more than a third of
    a period: refused; by 0.25 fine periods it is kept, and decoded right."""
    c = _two_period_codec()
    u = truth()
    images = render_codec(c, u, None)
    for shift, refused in ((16.0, True), (6.4, True), (4.0, False)):
        shifted = images.copy()
        shifted[4:8, 5:] = render_codec(c, u + shift, None)[4:8, 5:]
        axis = decode_codec(shifted, c).axes["u"]
        inside = (u > 12.0) & (u < 240.0)  # away from the projector's edges
        rows = slice(5, None)
        if refused:
            # shifted by a word, a pixel in the first quarter of its word still lies within the
            # tolerance (a quarter period) of the cell: only the others are refused
            check = inside & (((u + 0.5) % 16.0 > 4.5) if shift == 16.0 else True)
            assert (axis.reason[rows][check[rows]] == REASON_INCONSISTENT).all(), shift
        else:
            kept = axis.valid[rows] & inside[rows]
            assert (
                axis.valid[rows][inside[rows]].all()
                and np.abs(axis.coordinate[rows][kept] - u[rows][kept]).max() < 0.01
            )
        assert (axis.reason[:5][inside[:5]] == REASON_VALID).all()
    assert (
        decode_codec(images, c, CodecDecodeOptions(unwrap_consistency_periods=0.5)).options.to_dict()[
            "unwrap_consistency_periods"
        ]
        == 0.5
    )
    with pytest.raises(ValueError, match="unwrap_consistency_periods"):
        CodecDecodeOptions(unwrap_consistency_periods=-1)
