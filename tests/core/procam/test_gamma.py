"""Projector gamma: the response measured, pre-compensation, and the phase correction of captures
already taken; on the virtual rig with gamma 2.2 the periodic error on a plane drops >= 10x."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.decode import decode_codec
from metrology.core.procam.gamma import (
    correct_coordinate,
    gamma_from_ramp,
    phase_error_table,
    precompensate,
    response_table,
)
from metrology.core.procam.observe import gamma_from_mean_ratio
from metrology.core.procam.virtual import BoardPose, render_board
from metrology.core.simulate import noise_free_16bit

from .virtual_rig import BOARD, RIG, plane_flatness_mm


def gamma_codec():  # type: ignore[no-untyped-def]
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 22,
            "projector": {"width": 1024, "height": 768},
            "white": [20],
            "black": [21],
            "axes": {
                "u": {
                    "phase": [{"frames": [0, 1, 2, 3], "period": 32.0}],
                    "gray": {"frames": [4, 5, 6, 7, 8], "word": 32.0, "origin": -0.5},
                },
                "v": {
                    "phase": [{"frames": [10, 11, 12, 13], "period": 32.0}],
                    "gray": {"frames": [14, 15, 16, 17, 18], "word": 32.0, "origin": -0.5},
                },
            },
        }
    )


def test_gamma_from_a_grey_ramp() -> None:
    levels = np.arange(0, 256, 15)
    rng = np.random.default_rng(1)
    grey = 12 + 200 * (levels / 255) ** 2.2 + 0.3 * rng.standard_normal(levels.size)
    assert gamma_from_ramp(levels, grey) == pytest.approx(2.2, abs=0.02)
    table = response_table(2.2)
    assert len(table) == 256 and table[0] == 0 and table[255] == 1 and table[128] == pytest.approx((128 / 255) ** 2.2)
    with pytest.raises(ValueError, match="gamma"):
        response_table(0.0)


def test_precompensated_patterns_emit_the_sine() -> None:
    s = np.linspace(0, 1, 101)
    assert np.allclose(precompensate(s, 2.2) ** 2.2, s)


def test_phase_error_vanishes_for_gamma_one_and_matches_harmonics() -> None:
    phi, theta = phase_error_table(1.0, 4)
    assert np.abs(theta - phi).max() < 1e-9
    phi, theta = phase_error_table(2.2, 4)
    err = theta - phi
    assert 0.01 < np.abs(err).max() < 0.5
    # the 4-step error has period P / 4: err(phi + pi/2) = err(phi)
    assert np.allclose(err, np.roll(err, len(phi) // 4), atol=1e-9)
    assert gamma_from_mean_ratio(float(np.mean(((1 + np.cos(phi)) / 2) ** 2.2))) == pytest.approx(2.2, abs=1e-3)


@pytest.mark.slow
def test_gamma_22_plane_error_drops_tenfold() -> None:
    codec = gamma_codec()
    blur = 1.2
    options = noise_free_16bit(supersample=2, projector_gamma=2.2, projector_defocus_codes=blur / 8)
    tilted = BoardPose.from_angles(12, -8, 0, (0, 0, 500))
    plane = BoardPose(R=tilted.R, t=tilted.t - tilted.R @ np.array([5000.0, 5000.0, 0.0]))
    images = render_board(RIG, BOARD, plane, codec, options, seed=3)
    decoded = decode_codec(images, codec)
    u, v = decoded.axes["u"].coordinate, decoded.axes["v"].coordinate
    # the response measured from the fringes' mean against white and black
    white, black = images[20].astype(float), images[21].astype(float)
    ok = np.isfinite(u) & (white - black > 1000)
    ratio = float(np.median((decoded.axes["u"].mean[ok] - black[ok]) / (white - black)[ok]))
    gamma = gamma_from_mean_ratio(ratio)
    assert gamma == pytest.approx(2.2, abs=0.05)
    before = plane_flatness_mm(RIG, u, v)
    uc = correct_coordinate(u, 32.0, 0.0, 4, gamma, blur_px=blur)
    vc = correct_coordinate(v, 32.0, 0.0, 4, gamma, blur_px=blur)
    after = plane_flatness_mm(RIG, uc.astype(np.float32), vc.astype(np.float32))
    linear = render_board(RIG, BOARD, plane, codec, options.with_changes(projector_gamma=1.0), seed=3)
    dl = decode_codec(linear, codec)
    floor = plane_flatness_mm(RIG, dl.axes["u"].coordinate, dl.axes["v"].coordinate)
    print(
        f"plane flatness RMS: gamma 2.2 {before * 1000:.1f} um, corrected {after * 1000:.1f} um, "
        f"linear {floor * 1000:.1f} um"
    )
    assert before > 10 * after, (before, after, floor)


@pytest.mark.slow
def test_gamma_correct_command(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """gcps gamma-correct on a capture folder: the corrected coordinates give a flat plane, and
    the summary reports the depth change in micrometres."""
    import json

    import cv2

    from metrology.cli import main

    codec = gamma_codec()
    options = noise_free_16bit(supersample=2, projector_gamma=2.2, projector_defocus_codes=0.15)
    tilted = BoardPose.from_angles(12, -8, 0, (0, 0, 500))
    plane = BoardPose(R=tilted.R, t=tilted.t - tilted.R @ np.array([5000.0, 5000.0, 0.0]))
    images = render_board(RIG, BOARD, plane, codec, options, seed=4)
    stack = tmp_path / "plane"
    stack.mkdir()
    for k, image in enumerate(images):
        cv2.imwrite(str(stack / f"f{k:02d}.png"), image)
    (stack / "codec.json").write_text(json.dumps(codec.to_dict()))
    (tmp_path / "rig.json").write_text(RIG.to_json())
    out = tmp_path / "uv.npy"
    args = ["gamma-correct", "--stack", str(stack), "--gamma", "2.2", "--blur-px", "1.2", "--out", str(out)]
    assert main([*args, "--rig", str(tmp_path / "rig.json")]) == 0
    uv = np.load(out)
    after = plane_flatness_mm(RIG, uv[..., 0], uv[..., 1])
    decoded = decode_codec(images, codec)
    before = plane_flatness_mm(RIG, decoded.axes["u"].coordinate, decoded.axes["v"].coordinate)
    assert before > 10 * after
    assert main(["gamma-correct", "--stack", str(stack), "--gamma", "9", "--out", str(out)]) == 2
