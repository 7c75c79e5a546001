"""``gcps decode`` and ``gcps patterns --codec``: the contract of issue 11 (docs/codecs.md)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import codec_from_dict, codec_patterns, render_codec
from metrology.core.codecs.stack import read_codec_stack

CODEC: dict[str, Any] = {
    "codec": "gcps-codec/1",
    "frames": 18,
    "files": "pat*.png",
    "projector": {"width": 128, "height": 96},
    "white": [16],
    "black": [17],
    "axes": {
        "u": {
            "phase": [{"frames": [0, 1, 2, 3], "period": 16.0, "origin": -0.5}],
            "gray": {"frames": [4, 5, 6], "inverse_frames": [7, 8, 9], "word": 16.0, "origin": -0.5},
        },
        "v": {
            "phase": [{"frames": [10, 11, 12], "period": 12.0, "shift": -1}],
            "gray": {"frames": [13, 14, 15], "word": 12.0, "order": "lsb_first"},
        },
    },
}


def run(*args: str) -> int:
    return main(["--quiet", *args])


def truth(height: int = 40, width: int = 60) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    u = 1.013 + 2.0 * xx + 0.05 * yy  # no pixel exactly on a gray edge
    v = 2.0 + 2.1 * yy + 0.03 * xx
    u[:3, :3] = np.nan
    v[:3, :3] = np.nan
    return u, v


def write_capture(folder: Path, images: np.ndarray, codec: dict[str, Any] | None = CODEC, prefix: str = "pat") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, image in enumerate(images):
        assert cv2.imwrite(str(folder / f"{prefix}{i}.png"), image)
    if codec is not None:
        (folder / "codec.json").write_text(json.dumps(codec))
    (folder / "notes.txt").write_text("not a frame")
    return folder


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    u, v = truth()
    images = render_codec(codec_from_dict(CODEC), u, v)
    root = tmp_path_factory.mktemp("codec_capture")
    return write_capture(root / "cap", images), u, v


def test_decode_writes_uv_and_quality(capture: tuple[Path, np.ndarray, np.ndarray], tmp_path: Path) -> None:
    folder, u, v = capture
    out, quality = tmp_path / "uv.npy", tmp_path / "q.npz"
    assert run("decode", "--stack", str(folder), "--out", str(out), "--quality", str(quality)) == 0
    uv = np.load(out)
    assert uv.shape == (40, 60, 2) and uv.dtype == np.float32
    for index, t in enumerate((u, v)):
        lit = np.isfinite(t)
        assert np.isnan(uv[..., index][~lit]).all()
        assert np.abs(uv[..., index][lit] - t[lit]).max() < 0.01
    q = np.load(quality)
    assert sorted(q.files) == sorted(f"{k}_{a}" for k in ("modulation", "noise", "reason") for a in "uv")
    for a in "uv":
        assert q[f"modulation_{a}"].dtype == np.float32 and q[f"noise_{a}"].dtype == np.float32
        assert q[f"reason_{a}"].dtype == np.uint8 and q[f"reason_{a}"].shape == (40, 60)
    assert (q["reason_u"][:3, :3] == 1).all() and (q["reason_u"][3:] == 0).all()
    # noise-free 16-bit: the 4-step fit residual is the rounding of the grey levels only
    assert np.nanmax(q["noise_u"][3:]) < 1.0
    assert np.isnan(q["noise_v"]).all()  # 3-step: no residual


def test_decode_zip_with_codec_option_and_gray_only_axis(tmp_path: Path) -> None:
    codec = {
        "codec": "gcps-codec/1",
        "frames": 8,
        "projector": {"width": 16, "height": 4},
        "axes": {"u": {"gray": {"frames": [0, 2, 4, 6], "inverse_frames": [1, 3, 5, 7], "word": 1, "origin": -0.5}}},
    }
    u, _ = truth(8, 12)
    u = u / 2.0
    images = render_codec(codec_from_dict(codec), u, None)
    folder = write_capture(tmp_path / "cap", images, codec=None)
    archive = tmp_path / "cap.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for child in folder.iterdir():
            zf.write(child, f"inner/{child.name}")
    (tmp_path / "c.json").write_text(json.dumps(codec))
    out = tmp_path / "uv.npy"
    assert run("decode", "--stack", str(archive), "--codec", str(tmp_path / "c.json"), "--out", str(out)) == 0
    uv = np.load(out)
    lit = np.isfinite(u)
    np.testing.assert_array_equal(uv[..., 0][lit], np.floor(u[lit] + 0.5))
    assert np.isnan(uv[..., 1]).all()


def test_decode_gcps_v1_named_stack_without_codec(tmp_path: Path) -> None:
    rig = tmp_path / "rig.json"
    rig.write_text(
        json.dumps(
            {
                "L_mm": 1022.0,
                "d_mm": 352.0,
                "alpha_rad": 0.332,
                "fw_mm": 500.0,
                "nlp": 128,
                "width_px": 160,
                "height_px": 120,
            }
        )
    )
    stack = tmp_path / "s"
    assert (
        run("simulate", "--rig", str(rig), "--scene", "reference", "--preset", "noise-free", "--out", str(stack)) == 0
    )
    out = tmp_path / "uv.npy"
    assert run("decode", "--stack", str(stack), "--out", str(out)) == 0
    uv = np.load(out)
    assert np.isfinite(uv[..., 0]).mean() > 0.95 and np.isnan(uv[..., 1]).all()
    # u increases along the rows: the light code grows across the field
    assert (np.diff(uv[60, 5:-5, 0]) > 0).all()


def test_patterns_for_a_codec_decode_to_the_projector_pixels(tmp_path: Path) -> None:
    (tmp_path / "c.json").write_text(json.dumps(CODEC))
    out = tmp_path / "patterns"
    assert run("patterns", "--codec", str(tmp_path / "c.json"), "--out", str(out)) == 0
    stack = read_codec_stack(out)
    assert stack.names[:2] == ("pat00.png", "pat01.png") and stack.codec_source == "codec.json"
    np.testing.assert_array_equal(stack.images, codec_patterns(codec_from_dict(CODEC)))
    # the projector images seen by an identity camera decode to the pixel centres (8-bit patterns)
    # the patterns reach full scale: saturation is off here (256 > 255)
    assert run("decode", "--stack", str(out), "--out", str(tmp_path / "uv.npy"), "--saturation", "256") == 0
    uv = np.load(tmp_path / "uv.npy")
    columns = np.broadcast_to(np.arange(128, dtype=np.float32), (96, 128))
    rows = np.broadcast_to(np.arange(96, dtype=np.float32)[:, None], (96, 128))
    assert np.nanmax(np.abs(uv[..., 0] - columns)) < 0.05 and np.nanmax(np.abs(uv[..., 1] - rows)) < 0.05
    assert np.isfinite(uv).mean() > 0.99
    assert run("patterns", "--codec", "gcps-v1:64x32", "--out", str(tmp_path / "v1.zip")) == 0
    assert read_codec_stack(tmp_path / "v1.zip").images.shape == (11, 32, 64)


def bad(capsys: pytest.CaptureFixture[str], tmp_path: Path, *args: str) -> str:
    out = tmp_path / "bad_uv.npy"
    quality = tmp_path / "bad_q.npz"
    code = run("decode", *args, "--out", str(out), "--quality", str(quality))
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert not out.exists() and not quality.exists()
    return err


def test_every_bad_codec_field_exits_2(
    capture: tuple[Path, np.ndarray, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, _, _ = capture
    cases = [
        (lambda c: c["axes"]["u"]["phase"][0].update(period=-1), "axes.u.phase[0].period must be > 0"),
        (lambda c: c["axes"]["u"]["phase"][0].update(frames=[0, 1]), "N >= 3"),
        (lambda c: c["axes"]["u"]["gray"].update(inverse_frames=[7, 8]), "inverse_frames must hold one frame per bit"),
        (lambda c: c["axes"]["v"]["gray"]["frames"].__setitem__(0, 0), "already used by axes.u.phase[0].frames[0]"),
        (lambda c: c["axes"]["v"]["gray"]["frames"].__setitem__(0, 18), "out of range"),
        (lambda c: c.update(extra=1), "unknown key 'extra'"),
        (lambda c: c["axes"]["u"]["phase"][0].update(period=1e308), "axes.u.phase[0].period must be at most 64 times"),
        (lambda c: c["axes"]["v"]["gray"].update(word=64 * 96 + 1), "(64 x 96 = 6144 px), got 6145"),
        (lambda c: c["projector"].update(width=10**9), "projector.width must be at most 16384 pixels"),
        (lambda c: c["axes"]["u"]["phase"][0].update(origin=float("inf")), "origin must be a finite number"),
    ]
    for mutate, message in cases:
        codec = json.loads(json.dumps(CODEC))
        mutate(codec)
        (tmp_path / "bad.json").write_text(json.dumps(codec))
        assert message in bad(capsys, tmp_path, "--stack", str(folder), "--codec", str(tmp_path / "bad.json"))


def test_stacks_that_do_not_match_their_codec_exit_2(
    capture: tuple[Path, np.ndarray, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, _, _ = capture
    codec = json.loads(json.dumps(CODEC))
    codec["frames"] = 19
    codec["white"] = [16, 18]
    (tmp_path / "c19.json").write_text(json.dumps(codec))
    assert "holds 18 image files matching 'pat*.png' but the codec describes 19 frames" in bad(
        capsys, tmp_path, "--stack", str(folder), "--codec", str(tmp_path / "c19.json")
    )
    nocodec = write_capture(tmp_path / "nocodec", np.zeros((3, 4, 4), np.uint8), codec=None)
    assert "has no codec.json" in bad(capsys, tmp_path, "--stack", str(nocodec))
    mixed = write_capture(tmp_path / "mixed", np.zeros((18, 4, 4), np.uint8))
    cv2.imwrite(str(mixed / "pat5.png"), np.zeros((5, 4), np.uint8))
    assert "has shape (5, 4) but pat0.png has shape (4, 4)" in bad(capsys, tmp_path, "--stack", str(mixed))
    assert "does not exist" in bad(capsys, tmp_path, "--stack", str(tmp_path / "nowhere"))
    assert "no such file" in bad(capsys, tmp_path, "--stack", str(folder), "--codec", str(tmp_path / "none.json"))
    (tmp_path / "broken.json").write_text("{")
    assert "not valid JSON" in bad(capsys, tmp_path, "--stack", str(folder), "--codec", str(tmp_path / "broken.json"))
    code = run("decode", "--stack", str(folder), "--out", str(tmp_path / "uv.txt"))
    assert code == 2 and "extension must be .npy" in capsys.readouterr().err


def test_patterns_codec_refuses_gcps_v1_size_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run("patterns", "--codec", "gcps-v1", "--width", "64", "--out", str(tmp_path / "p"))
    assert code == 2 and "drop --width" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
    assert run("patterns", "--out", str(tmp_path / "p")) == 2
    assert "give --width and --height (gcps-v1) or --codec" in capsys.readouterr().err


def test_capture_zip_as_an_upload_file_object(capture: tuple[Path, np.ndarray, np.ndarray], tmp_path: Path) -> None:
    folder = capture[0]
    archive = tmp_path / "upload.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for child in folder.iterdir():
            zf.write(child, child.name)
    with archive.open("rb") as fh:
        stack = read_codec_stack(fh)
    assert stack.codec_source == "codec.json" and stack.images.shape == (18, 40, 60)
    assert stack.images.dtype == np.uint16


def test_a_nested_or_deeply_nested_codec_json_exits_2_with_one_line(
    capture: tuple[Path, np.ndarray, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 23 item 6: a codec.json in a sub-folder, or nested 100,000 levels deep, is refused (no traceback)."""
    folder = capture[0]
    frames = {child.name: child.read_bytes() for child in folder.iterdir() if child.name != "codec.json"}
    deep = b'{"codec": "gcps-codec/1", "axes": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    cases = {
        "sub.zip": ({**frames, "stack/codec.json": json.dumps(CODEC).encode()}, "in a sub-folder (stack/codec.json)"),
        "deep.zip": ({**frames, "a/b/c/d/e/codec.json": json.dumps(CODEC).encode()}, "(a/b/c/d/e/codec.json)"),
        "deepjson.zip": ({**frames, "codec.json": deep}, "codec.json is nested deeper than 16 levels"),
    }
    for name, (members, message) in cases.items():
        with zipfile.ZipFile(tmp_path / name, "w") as zf:
            for member, data in members.items():
                zf.writestr(member, data)
        assert message in bad(capsys, tmp_path, "--stack", str(tmp_path / name)), name
    nested_folder = write_capture(tmp_path / "nested", np.zeros((18, 4, 4), np.uint8), codec=None)
    (nested_folder / "more").mkdir()
    (nested_folder / "more" / "codec.json").write_text(json.dumps(CODEC))
    assert "in a sub-folder (more/codec.json)" in bad(capsys, tmp_path, "--stack", str(nested_folder))
