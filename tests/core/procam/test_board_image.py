"""The board image: white frames and sine phase sequences of 4 or more steps averaged (an N-step
sine sequence averages to an even half-white light), which lowers the camera corners' noise."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict
from metrology.core.procam.board import detect_board
from metrology.core.procam.observe import board_frames, board_image
from metrology.core.procam.virtual import BoardPose, render_board, true_corners

from .virtual_rig import BOARD, CODEC, OPTIONS, RIG


def codec(steps: int, waveform: str = "sine", white: bool = True) -> object:
    axis = {
        "phase": [{"frames": list(range(steps)), "period": 32.0, "waveform": waveform}],
        "gray": {"frames": list(range(steps, steps + 5)), "word": 32.0, "origin": -0.5},
    }
    data: dict[str, object] = {
        "codec": "gcps-codec/1",
        "frames": steps + 6,
        "projector": {"width": 1024, "height": 768},
        "axes": {"u": axis},
    }
    if white:
        data["white"] = [steps + 5]
    return codec_from_dict(data)


def test_frames_averaged() -> None:
    assert board_frames(CODEC) == [*range(8), *range(13, 21), 26]  # both 8-step sequences and white
    assert board_frames(codec(4)) == [0, 1, 2, 3, 9]
    assert board_frames(codec(3)) == [8]  # 3 steps: a gamma 2.2 leaves a 3 % ripple
    assert board_frames(codec(4, "square")) == [9]  # square waves do not average to an even light
    assert board_frames(codec(3, white=False)) == []
    stack = np.arange(9 * 2 * 3, dtype=np.uint8).reshape(9, 2, 3)
    assert np.array_equal(board_image(stack, codec(3, white=False)), stack.mean(axis=0))  # all frames


@pytest.mark.slow
def test_phase_frames_lower_the_corner_noise() -> None:
    """A board turned 20 degrees in the middle of the view, realistic 8-bit renders: corners from the
    white frame alone against the board image, RMS against the true corners over 3 noise draws
    (0.0079 px against 0.0043)."""
    pose = BoardPose.from_angles(15, -10, 20, (0, 0, 480)).centred(BOARD)
    truth, _ = true_corners(RIG, BOARD, pose)
    white, averaged = [], []
    for seed in range(3):
        images = render_board(RIG, BOARD, pose, CODEC, OPTIONS, seed=seed)
        for found, target in (
            (detect_board(images[26].astype(np.float64), BOARD), white),
            (detect_board(board_image(images, CODEC), BOARD), averaged),
        ):
            assert found is not None
            if np.abs(found - truth).max() > np.abs(found[::-1] - truth).max():
                found = found[::-1]
            target.append(found - truth)
    rms_white = float(np.sqrt(np.mean(np.square(white))))
    rms_averaged = float(np.sqrt(np.mean(np.square(averaged))))
    assert rms_averaged < 0.7 * rms_white and rms_averaged < 0.006, (rms_averaged, rms_white)
