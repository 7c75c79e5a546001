"""Multi-exposure captures on disk (issue 26, docs/exposures.md): ``exposures.json`` and one stack
per exposure in its sub-folder, read from folders and zips, with errors naming the exposure and
the file."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.stack import (
    ExposureStack,
    is_exposure_capture,
    read_codec_stack,
    read_exposure_stack,
    write_exposure_stack,
)
from metrology.core.io import StackError
from metrology.core.io.exposures import Exposure, exposures_json, parse_exposures
from metrology.core.patterns import PATTERN_NAMES

CODEC = codec_from_dict(
    {
        "codec": "gcps-codec/1",
        "frames": 6,
        "projector": {"width": 64, "height": 48},
        "axes": {"u": {"phase": [{"frames": [0, 1, 2, 3], "period": 64.0}]}},
        "white": [4],
        "black": [5],
    }
)


def _stacks(n: int, frames: int, dtype: type = np.uint8, shape: tuple[int, int] = (12, 16)) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    top = np.iinfo(dtype).max
    return [rng.integers(0, top, (frames, *shape), dtype=dtype) for _ in range(n)]


def _manifest(*entries: dict) -> str:
    return json.dumps({"format": "gcps-exposures/1", "exposures": list(entries)})


def test_manifest_is_ordered_by_exposure_whatever_its_order() -> None:
    text = _manifest(
        {"name": "long", "exposure_us": 8000},
        {"name": "short", "exposure_us": 2000, "gain": 2.0},
        {"name": "dim", "exposure_us": 2000, "projector_brightness": 0.5},
    )
    exposures = parse_exposures(text)
    assert [e.name for e in exposures] == ["dim", "short", "long"]
    assert exposures[1] == Exposure("short", 2000.0, gain=2.0)
    assert parse_exposures(exposures_json(exposures)) == exposures


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"format": "gcps-exposures/1", "exposures": [{"name": "a", "exposure_us": 1}], "x": 1}, "unknown key(s) x"),
        ({"format": "gcps-exposures/2", "exposures": [{"name": "a", "exposure_us": 1}]}, "format must be"),
        ({"format": "gcps-exposures/1", "exposures": []}, "non-empty list"),
        ({"format": "gcps-exposures/1", "exposures": [{"exposure_us": 1}]}, "exposures[0]: name is required"),
        (
            {"format": "gcps-exposures/1", "exposures": [{"name": "a", "exposure_us": 1, "iso": 100}]},
            "exposure 'a' has unknown key(s) iso",
        ),
        ({"format": "gcps-exposures/1", "exposures": [{"name": "a"}]}, "exposure 'a': exposure_us is required"),
        ({"format": "gcps-exposures/1", "exposures": [{"name": "a", "exposure_us": 0}]}, "finite number > 0"),
        (
            {"format": "gcps-exposures/1", "exposures": [{"name": "a", "exposure_us": 1, "gain": True}]},
            "exposure 'a': gain must be",
        ),
        ({"format": "gcps-exposures/1", "exposures": [{"name": "../a", "exposure_us": 1}]}, "one folder name"),
        (
            {
                "format": "gcps-exposures/1",
                "exposures": [{"name": "a", "exposure_us": 1}, {"name": "a", "exposure_us": 2}],
            },
            "lists exposure 'a' twice",
        ),
    ],
)
def test_manifest_refusals_name_the_file_and_the_entry(doc: dict, message: str) -> None:
    with pytest.raises(StackError) as err:
        parse_exposures(json.dumps(doc), "'cap'")
    assert "capture 'cap' exposures.json" in str(err.value)
    assert message in str(err.value)


@pytest.mark.parametrize("as_zip", [False, True])
def test_codec_capture_round_trip(tmp_path: Path, as_zip: bool) -> None:
    images = _stacks(3, 6, np.uint16)
    exposures = (Exposure("e2", 300.0), Exposure("e0", 100.0), Exposure("e1", 200.0))
    ordered = tuple(sorted(exposures, key=lambda e: e.exposure_us))
    dest = tmp_path / ("cap.zip" if as_zip else "cap")
    write_exposure_stack(ExposureStack(tuple(images), ordered), dest, CODEC)
    assert is_exposure_capture(dest)
    read = read_exposure_stack(dest)
    assert read.codec == CODEC and read.codec_source == "codec.json" and read.bit_depth == 16
    assert [e.name for e in read.stack.exposures] == ["e0", "e1", "e2"]
    for got, want in zip(read.stack.images, images, strict=True):
        np.testing.assert_array_equal(got, want)
    with pytest.raises(StackError, match="multi-exposure capture"):
        read_codec_stack(dest)


def test_gcps_v1_capture_by_names_and_in_a_wrapping_zip_folder(tmp_path: Path) -> None:
    images = _stacks(2, len(PATTERN_NAMES))
    stack = ExposureStack(tuple(images), (Exposure("a", 1.0), Exposure("b", 4.0)))
    folder = write_exposure_stack(stack, tmp_path / "cap")
    assert not (folder / "codec.json").exists()
    read = read_exposure_stack(folder)
    assert read.codec.name == "gcps-v1" and read.codec_source == "gcps-v1 names"
    np.testing.assert_array_equal(read.stack.images[1], images[1])
    # a zip holding the capture inside one folder
    with zipfile.ZipFile(tmp_path / "wrapped.zip", "w") as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                archive.write(path, "capture/" + path.relative_to(folder).as_posix())
    read = read_exposure_stack(tmp_path / "wrapped.zip")
    np.testing.assert_array_equal(read.stack.images[0], images[0])


def _folder_capture(tmp_path: Path) -> Path:
    stack = ExposureStack(tuple(_stacks(2, 6)), (Exposure("exp0", 100.0), Exposure("exp1", 400.0)))
    return write_exposure_stack(stack, tmp_path / "cap", CODEC)


def test_missing_exposure_folder_is_named(tmp_path: Path) -> None:
    folder = _folder_capture(tmp_path)
    for child in (folder / "exp1").iterdir():
        child.unlink()
    (folder / "exp1").rmdir()
    with pytest.raises(StackError, match=r"no folder exp1/ for exposure 'exp1'"):
        read_exposure_stack(folder)


def test_bad_frame_names_the_exposure_and_the_file(tmp_path: Path) -> None:
    folder = _folder_capture(tmp_path)
    (folder / "exp1" / "03.png").write_bytes(b"not a png")
    with pytest.raises(StackError, match=r"'cap'/exp1/03.png"):
        read_exposure_stack(folder)
    (folder / "exp1" / "03.png").unlink()
    with pytest.raises(StackError, match=r"capture 'cap'/exp1 holds 5 image files but the codec describes 6"):
        read_exposure_stack(folder)


def test_codec_json_inside_an_exposure_is_refused(tmp_path: Path) -> None:
    folder = _folder_capture(tmp_path)
    (folder / "exp0" / "codec.json").write_text(CODEC.to_json())
    with pytest.raises(StackError, match=r"exp0/codec.json"):
        read_exposure_stack(folder)


def test_exposures_of_different_shapes_are_refused(tmp_path: Path) -> None:
    folder = _folder_capture(tmp_path)
    small = np.zeros((10, 16), np.uint8)
    for i in range(6):
        assert cv2.imwrite(str(folder / "exp1" / f"{i:02d}.png"), small)
    with pytest.raises(StackError, match=r"exposure 'exp1' has frames of shape \(10, 16\)"):
        read_exposure_stack(folder)


def test_no_manifest_is_not_a_multi_exposure_capture(tmp_path: Path) -> None:
    folder = _folder_capture(tmp_path)
    (folder / "exposures.json").unlink()
    assert not is_exposure_capture(folder)
    with pytest.raises(StackError, match=r"has no exposures\.json"):
        read_exposure_stack(folder)


def test_example_manifest_parses() -> None:
    example = Path(__file__).resolve().parents[2] / "examples" / "exposures.json"
    exposures = parse_exposures(example.read_bytes(), "'examples'")
    assert [e.name for e in exposures] == ["exp0", "exp1", "exp2"]
