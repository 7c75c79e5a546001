"""``gcps decode`` prints the codec self-check (``codec_check``, docs/codecs.md) and exits 0 with
its outputs written whatever the status; a gray word wider than the period it unwraps exits 2."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import codec_from_dict, render_codec

CODEC: dict[str, Any] = {
    "codec": "gcps-codec/1",
    "frames": 10,
    "projector": {"width": 256, "height": 192},
    "white": [8],
    "black": [9],
    "axes": {
        "u": {
            "phase": [{"frames": [0, 1, 2, 3], "period": 32.0, "origin": -0.5}],
            "gray": {"frames": [4, 5, 6, 7], "word": 16.0, "origin": -0.5},
        }
    },
}


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Path:
    yy, xx = np.mgrid[0:60, 0:90].astype(np.float64)
    u = 1.013 + 2.8 * xx + 0.05 * yy
    path = tmp_path_factory.mktemp("check") / "stack.npy"
    np.save(path, render_codec(codec_from_dict(CODEC), u, None))
    return path


def decode(stack: Path, codec: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, Any]:
    folder = tmp_path / "cap"
    folder.mkdir(exist_ok=True)
    for i, image in enumerate(np.load(stack)):
        assert cv2.imwrite(str(folder / f"{i:02d}.png"), image)
    codec_file = tmp_path / "codec.json"
    codec_file.write_text(json.dumps(codec))
    out = tmp_path / "uv.npy"
    status = main(["decode", "--stack", str(folder), "--codec", str(codec_file), "--out", str(out)])
    printed = capsys.readouterr().out
    return status, json.loads(printed) if status == 0 else printed


def test_right_codec_is_consistent(stack: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status, summary = decode(stack, CODEC, tmp_path, capsys)
    assert status == 0
    check = summary["codec_check"]["u"]
    assert check["status"] == "consistent" and check["message"] == ""
    assert abs(check["offset_px"]) <= 2.0 and check["outside_share"] <= 0.05


def test_wrong_origin_is_inconsistent_and_still_exits_0(
    stack: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wrong = copy.deepcopy(CODEC)
    wrong["axes"]["u"]["phase"][0]["origin"] = 15.5  # half a period off
    status, summary = decode(stack, wrong, tmp_path, capsys)
    assert status == 0 and (tmp_path / "uv.npy").exists()
    check = summary["codec_check"]["u"]
    assert check["status"] == "inconsistent"
    assert "origin should be -0.5, not 15.5" in check["message"].lower()


def test_a_word_wider_than_the_period_exits_2(stack: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    wrong = copy.deepcopy(CODEC)
    wrong["axes"]["u"]["gray"]["word"] = 64.0
    folder = tmp_path / "cap"
    folder.mkdir()
    codec_file = tmp_path / "codec.json"
    codec_file.write_text(json.dumps(wrong))
    status = main(["decode", "--stack", str(folder), "--codec", str(codec_file), "--out", str(tmp_path / "uv.npy")])
    assert status == 2
    assert "gray word (64) is wider than the period 32 of phase:0" in capsys.readouterr().err
    assert not (tmp_path / "uv.npy").exists()
