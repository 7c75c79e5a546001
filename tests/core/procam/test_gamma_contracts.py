"""Gamma in the two contracts: ``projector.gamma`` / ``projector.response`` in the pinhole rig file,
``precompensated_gamma`` in the codec (pre-compensated patterns), and calibrate-procam writing the
measured gamma into the rig."""

from __future__ import annotations

import copy
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict, codec_from_json, codec_patterns, render_codec
from metrology.core.codecs.decode import decode_codec
from metrology.core.codecs.model import CodecError
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.geometry.rig_file import RigFileError
from metrology.core.procam.board import parse_board
from metrology.core.procam.calibrate import calibrate_procam
from metrology.core.procam.correspondences import read_correspondences
from metrology.core.procam.gamma import phase_error_table
from metrology.core.simulate import noise_free_16bit

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "procam-correspondences.json"
RIG_DICT: dict[str, Any] = {
    "model": "pinhole",
    "camera": {"width_px": 640, "height_px": 480, "K": [[800.0, 0, 320.0], [0, 800.0, 240.0], [0, 0, 1]]},
    "projector": {"width": 1024, "height": 768, "K": [[1500.0, 0, 512.0], [0, 1500.0, 700.0], [0, 0, 1]]},
    "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    "T": [-150.0, 0.0, 20.0],
}
CODEC_DICT: dict[str, Any] = {
    "codec": "gcps-codec/1",
    "frames": 14,
    "projector": {"width": 256, "height": 64},
    "white": [12],
    "black": [13],
    "axes": {
        "u": {
            "phase": [{"frames": [0, 1, 2, 3], "period": 32.0}],
            "gray": {"frames": [4, 5, 6], "word": 32.0, "origin": -0.5, "inverse_frames": [7, 8, 9]},
        }
    },
}


def _rig(**projector: Any) -> dict[str, Any]:
    data = copy.deepcopy(RIG_DICT)
    data["projector"].update(projector)
    return data


def test_rig_gamma_and_response_round_trip() -> None:
    table = [(i / 255) ** 2.2 for i in range(256)]
    rig = PinholeRig.from_dict(_rig(gamma=2.2, response=table))
    assert rig.projector.gamma == 2.2 and rig.projector.response == tuple(table)
    again = PinholeRig.from_json(rig.to_json())
    assert again == rig and again.to_dict()["projector"]["gamma"] == 2.2
    assert again.to_dict()["projector"]["response"] == table
    plain = PinholeRig.from_dict(RIG_DICT)
    assert plain.projector.gamma is None and "gamma" not in plain.to_dict()["projector"]
    assert "response" not in plain.to_dict()["projector"]


@pytest.mark.parametrize(
    ("projector", "message"),
    [
        ({"gamma": 0.1}, r"projector gamma must be in 0\.2\.\.5, got 0\.1"),
        ({"gamma": 7}, r"projector gamma must be in 0\.2\.\.5"),
        ({"gamma": "2.2"}, r"projector gamma must be a number"),
        ({"response": [0.5] * 255}, r"projector response must be a list of 256 numbers in 0\.\.1, got 255 entries"),
        ({"response": 2.2}, r"projector response must be a list of 256 numbers"),
        ({"response": [0.0] * 255 + [1.2]}, r"projector response\[255\] must be in 0\.\.1, got 1\.2"),
        ({"response": [i / 255 for i in range(255)] + [0.5]}, r"projector response must be non-decreasing"),
    ],
)
def test_rig_bad_gamma_keys_are_named(projector: dict[str, Any], message: str) -> None:
    with pytest.raises(RigFileError, match=message):
        PinholeRig.from_dict(_rig(**projector))


def test_codec_precompensated_gamma_round_trip_and_bad_values() -> None:
    codec = codec_from_dict({**CODEC_DICT, "precompensated_gamma": 2.2})
    assert codec.precompensated_gamma == 2.2
    again = codec_from_json(codec.to_json())
    assert again == codec and json.loads(codec.to_json())["precompensated_gamma"] == 2.2
    assert "precompensated_gamma" not in codec_from_dict(CODEC_DICT).to_dict()
    for bad in (0.1, 6, "2.2", True):
        with pytest.raises(CodecError, match="precompensated_gamma"):
            codec_from_dict({**CODEC_DICT, "precompensated_gamma": bad})


def test_precompensated_patterns_through_a_gamma_projector_are_linear() -> None:
    """``round(255 s**(1/g))`` emitted as ``(value/255)**g`` is ``s`` within the 8-bit steps:
    ``g * 0.5 / 255`` from its rounding (the derivative of ``x**g`` is at most ``g`` on 0..1) plus
    ``0.5 / 255`` from the rounding of the linear pattern it is compared with."""
    g = 2.2
    linear = codec_from_dict(CODEC_DICT)
    compensated = codec_from_dict({**CODEC_DICT, "precompensated_gamma": g})
    s = codec_patterns(linear).astype(np.float64) / 255
    emitted = (codec_patterns(compensated).astype(np.float64) / 255) ** g
    assert np.abs(emitted - s).max() <= (g + 1) * 0.5 / 255
    assert np.abs(s**g - s).max() > 0.2  # without pre-compensation the sine is far from linear
    # gray and white frames are 0/1 and unchanged
    assert np.array_equal(codec_patterns(compensated)[4:], codec_patterns(linear)[4:])


def test_precompensated_codec_decodes_linearly_on_a_gamma_virtual_projector() -> None:
    """A gamma-2.2 virtual projector (no blur, noise-free): the uncompensated codec's coordinate
    error is the 4-step estimator's error under ``s**2.2`` (``phase_error_table``, RMS times
    ``P / 2 pi``, within 10 %); the pre-compensated codec's is that of a linear projector."""
    g = 2.2
    u_true = np.tile(np.linspace(0.0, 255.0, 512), (8, 1))
    options = noise_free_16bit(projector_gamma=g, projector_defocus_codes=0.0)

    def rms_error(codec_dict: dict[str, Any], gamma: float) -> float:
        codec = codec_from_dict(codec_dict)
        images = render_codec(codec, u_true, None, options.with_changes(projector_gamma=gamma), projector_blur_px=0.0)
        u = decode_codec(images, codec).axes["u"].coordinate
        ok = np.isfinite(u)
        assert ok.mean() > 0.95
        return float(np.sqrt(np.mean((u[ok] - u_true[ok]) ** 2)))

    plain = rms_error(CODEC_DICT, g)
    compensated = rms_error({**CODEC_DICT, "precompensated_gamma": g}, g)
    linear = rms_error(CODEC_DICT, 1.0)
    phi, theta = phase_error_table(g, 4)
    expected = float(np.sqrt(np.mean((theta - phi) ** 2))) * 32.0 / (2 * np.pi)
    assert plain == pytest.approx(expected, rel=0.1), (plain, expected)  # projector units
    assert compensated < 0.1 * plain and compensated == pytest.approx(linear, abs=1e-6)


def test_calibration_writes_the_measured_gamma_unless_precompensated() -> None:
    board = parse_board("chessboard:9x6:20")
    poses, camera_size, projector_size = read_correspondences(EXAMPLE, board)
    poses = [replace(pose, gamma=2.1) for pose in poses]
    result = calibrate_procam(poses, board, camera_size, projector_size, fix_k3=True)
    assert result.rig.projector.gamma == pytest.approx(2.1)
    assert PinholeRig.from_json(result.rig.to_json()).to_dict()["projector"]["gamma"] == pytest.approx(2.1)
    poses, camera_size, projector_size = read_correspondences(EXAMPLE, board)
    poses = [replace(pose, gamma=2.1) for pose in poses]
    kept = calibrate_procam(poses, board, camera_size, projector_size, fix_k3=True, codec_gamma_precompensated=True)
    assert kept.rig.projector.gamma is None and "gamma" not in kept.rig.to_dict()["projector"]


def test_patterns_command_writes_precompensated_patterns(tmp_path: Path) -> None:
    """``gcps patterns --codec`` with ``precompensated_gamma``: the PNGs hold ``round(255 s**(1/g))``
    and the written codec.json keeps the key, so the capture documents its pre-compensation."""
    import cv2

    from metrology.cli import main

    spec = tmp_path / "codec.json"
    spec.write_text(json.dumps({**CODEC_DICT, "precompensated_gamma": 2.0}))
    assert main(["--quiet", "patterns", "--codec", str(spec), "--out", str(tmp_path / "out")]) == 0
    written = codec_from_json((tmp_path / "out" / "codec.json").read_text())
    assert written.precompensated_gamma == 2.0
    first = sorted(p for p in (tmp_path / "out").iterdir() if p.suffix == ".png")[0]
    image = cv2.imread(str(first), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    s = codec_patterns(codec_from_dict(CODEC_DICT))[0].astype(np.float64) / 255
    assert np.abs((image / 255) ** 2.0 - s).max() <= 3 * 0.5 / 255
    assert np.abs(image / 255 - s).max() > 0.2
