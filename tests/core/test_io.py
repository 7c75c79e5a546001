"""Tests of metrology.core.io: stack, rig, height and series files, and every bad input."""

from __future__ import annotations

import io
import json
import os
import re
import struct
import zipfile
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.core import io as gio
from metrology.core.geometry.crossed_axes import PAPER_RIG, Rig, RigError
from metrology.core.io import (
    CaptureStack,
    StackError,
    image_header_size,
    read_height_npy,
    read_rig,
    read_series,
    read_stack,
    series_capture_name,
    write_height_npy,
    write_height_tiff,
    write_rig,
    write_series,
    write_stack,
)
from metrology.core.patterns import PATTERN_NAMES

SHAPE = (24, 32)


def make_images(bit_depth: int = 8, shape: tuple[int, int] = SHAPE, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    high = 256 if bit_depth == 8 else 65536
    return rng.integers(0, high, size=(len(PATTERN_NAMES), *shape), dtype=dtype)


def encoded(image: np.ndarray, ext: str = ".png") -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def zip_bytes(members: dict[str, bytes], compression: int = zipfile.ZIP_STORED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=compression) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def stack_members(images: np.ndarray | None = None, ext: str = ".png", prefix: str = "") -> dict[str, bytes]:
    images = make_images() if images is None else images
    return {f"{prefix}{name}{ext}": encoded(image, ext) for name, image in zip(PATTERN_NAMES, images, strict=True)}


def write_folder(folder: Path, members: dict[str, bytes]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in members.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    return folder


# ------------------------------------------------------------------------ round trips


ROUND_TRIPS = [
    (container, bit_depth, ext)
    for container in ("folder", "zip")
    for bit_depth in (8, 16)
    for ext in (".png", ".tif", ".tiff", ".bmp")
    if not (ext == ".bmp" and bit_depth == 16)  # BMP is 8-bit only (see test_write_stack_refuses_16_bit_bmp...)
]


@pytest.mark.parametrize(("container", "bit_depth", "ext"), ROUND_TRIPS)
def test_write_read_round_trip(tmp_path: Path, ext: str, bit_depth: int, container: str) -> None:
    images = make_images(bit_depth)
    dest = tmp_path / ("stack.zip" if container == "zip" else "stack")
    assert write_stack(images, dest, ext=ext) == dest
    stack = read_stack(dest)
    assert stack.bit_depth == bit_depth
    assert stack.shape == SHAPE
    assert stack.images.dtype == images.dtype
    np.testing.assert_array_equal(stack.images, images)
    assert not stack.images.flags.writeable
    np.testing.assert_array_equal(stack["PS_2"], images[PATTERN_NAMES.index("PS_2")])
    assert not list(tmp_path.glob(".*")), "temporary files left behind"


def test_read_stack_from_file_object_and_rig_shape(tmp_path: Path) -> None:
    rig = PAPER_RIG.with_parameters(width_px=SHAPE[1], height_px=SHAPE[0])
    images = make_images()
    upload = io.BytesIO(zip_bytes(stack_members(images)))
    stack = read_stack(upload, rig=rig, expected_bit_depth=8)
    np.testing.assert_array_equal(stack.images, images)


def test_zip_with_single_folder_junk_and_upper_case_extension() -> None:
    images = make_images()
    members = stack_members(images, ext=".PNG", prefix="capture/")
    members["__MACOSX/capture/._GC_0.PNG"] = b"apple double"
    members["capture/.DS_Store"] = b"junk"
    members["capture/Thumbs.db"] = b"junk"
    stack = read_stack(io.BytesIO(zip_bytes(members)))
    np.testing.assert_array_equal(stack.images, images)


def test_folder_with_single_subfolder(tmp_path: Path) -> None:
    images = make_images()
    write_folder(tmp_path / "outer" / "inner", stack_members(images, ext=".tif"))
    (tmp_path / "outer" / ".DS_Store").write_bytes(b"junk")
    np.testing.assert_array_equal(read_stack(tmp_path / "outer").images, images)


def test_color_images_become_grey() -> None:
    rng = np.random.default_rng(1)
    colour = rng.integers(0, 256, size=(*SHAPE, 3), dtype=np.uint8)
    rgba = np.dstack([colour, np.full(SHAPE, 7, np.uint8)])
    members = stack_members()
    members["GC_0.png"] = encoded(colour)
    members["GC_1.png"] = encoded(rgba)
    stack = read_stack(io.BytesIO(zip_bytes(members)))
    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    np.testing.assert_array_equal(stack["GC_0"], grey)
    np.testing.assert_array_equal(stack["GC_1"], grey)  # alpha ignored


def test_color_16_bit_becomes_grey() -> None:
    colour = make_images(16)[:3].transpose(1, 2, 0).copy()
    members = stack_members(make_images(16))
    members["PS_3.png"] = encoded(colour)
    stack = read_stack(io.BytesIO(zip_bytes(members)))
    assert stack.bit_depth == 16
    np.testing.assert_array_equal(stack["PS_3"], cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))


def test_image_header_size_of_each_format() -> None:
    image = np.zeros((7, 13), np.uint8)
    assert image_header_size(encoded(image, ".png")) == ("PNG", 13, 7)
    assert image_header_size(encoded(image, ".bmp")) == ("BMP", 13, 7)
    assert image_header_size(encoded(image, ".tif")) == ("TIFF", 13, 7)
    assert image_header_size(encoded(image.astype(np.uint16) * 300, ".tif")) == ("TIFF", 13, 7)
    with pytest.raises(ValueError, match="not a PNG, TIFF or BMP"):
        image_header_size(b"GIF89a....")
    with pytest.raises(ValueError, match="truncated"):
        image_header_size(encoded(image, ".png")[:20])


def test_capture_stack_validates_its_fields() -> None:
    images = make_images()
    with pytest.raises(ValueError, match="bit_depth 16"):
        CaptureStack(images=images, bit_depth=16, shape=SHAPE)
    with pytest.raises(ValueError, match="shape"):
        CaptureStack(images=images, bit_depth=8, shape=(1, 2))
    with pytest.raises(ValueError, match=r"\(11, H, W\)"):
        CaptureStack(images=images[:10], bit_depth=8, shape=SHAPE)
    with pytest.raises(KeyError, match="GC_9"):
        CaptureStack(images=images, bit_depth=8, shape=SHAPE)["GC_9"]


# ------------------------------------------------------------------------ bad stacks


def read_zip_members(members: dict[str, bytes], **kwargs: object) -> CaptureStack:
    return read_stack(io.BytesIO(zip_bytes(members)), **kwargs)  # type: ignore[arg-type]


def test_missing_patterns_are_listed() -> None:
    members = stack_members()
    del members["GC_3.png"], members["PS_1.png"]
    with pytest.raises(StackError, match=r"missing pattern\(s\) GC_3, PS_1") as info:
        read_zip_members(members)
    assert "\n" not in str(info.value)


def test_missing_patterns_in_folder(tmp_path: Path) -> None:
    members = stack_members()
    del members["PS_3.png"]
    with pytest.raises(StackError, match=r"capture stack 'ref' is missing pattern\(s\) PS_3$|PS_3;"):
        read_stack(write_folder(tmp_path / "ref", members))


def test_extra_and_misnamed_files_are_named(tmp_path: Path) -> None:
    members = stack_members()
    members["notes.txt"] = b"hello"
    members["GC_7.png"] = members["GC_0.png"]
    with pytest.raises(StackError, match=r"unexpected file\(s\) GC_7.png, notes.txt"):
        read_zip_members(members)
    # A wrong name is both a missing pattern and an unexpected file, in one line.
    members = stack_members()
    members["gc_0.png"] = members.pop("GC_0.png")
    with pytest.raises(StackError, match=r"missing pattern\(s\) GC_0 and holds unexpected file\(s\) gc_0.png"):
        read_stack(write_folder(tmp_path / "s", members))


def test_extra_folder_is_named(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "s", stack_members())
    (folder / "sub").mkdir()
    with pytest.raises(StackError, match=r"unexpected file\(s\) sub/"):
        read_stack(folder)


def test_duplicate_pattern_is_refused(tmp_path: Path) -> None:
    members = stack_members()
    members["GC_0.tif"] = encoded(make_images()[0], ".tif")
    with pytest.raises(StackError, match=re.escape("holds pattern GC_0 more than once: GC_0.png, GC_0.tif")):
        read_stack(write_folder(tmp_path / "s", members))


def test_duplicate_zip_member_is_refused() -> None:
    buffer = io.BytesIO()
    members = stack_members()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
        with pytest.warns(UserWarning, match="Duplicate name"):
            archive.writestr("GC_0.png", members["GC_0.png"])
    with pytest.raises(StackError, match=re.escape("member GC_0.png more than once")):
        read_stack(io.BytesIO(buffer.getvalue()))


def test_unreadable_image_is_named() -> None:
    members = stack_members()
    members["GC_3.png"] = b"this is not an image at all"
    with pytest.raises(StackError, match=re.escape("GC_3.png is not a readable PNG, TIFF or BMP image")):
        read_zip_members(members)


def test_corrupt_image_is_named(tmp_path: Path) -> None:
    members = stack_members(make_images(8, (64, 64)))
    members["PS_2.png"] = members["PS_2.png"][:60]  # valid header, truncated data
    with pytest.raises(StackError, match=r"'s'/PS_2.png is a corrupt"):
        read_stack(write_folder(tmp_path / "s", members))


def test_mismatched_shapes_name_both_files() -> None:
    images = make_images()
    members = stack_members(images)
    members["PS_1.png"] = encoded(np.zeros((SHAPE[0], SHAPE[1] + 1), np.uint8))
    with pytest.raises(StackError, match=r"PS_1.png has shape \(24, 33\) but GC_0.png has shape \(24, 32\)"):
        read_zip_members(members)


def test_shape_unlike_the_rig_says_both() -> None:
    with pytest.raises(StackError, match=r"GC_0.png does not match the rig: expected 640x480 from the rig, got 32x24"):
        read_zip_members(stack_members(), rig=PAPER_RIG)


def test_stack_larger_than_the_rig_is_a_mismatch_not_a_size_limit() -> None:
    """With a rig, the rig's shape is the limit: a bigger image does not match it (issue 9 item 2)."""
    small_rig = Rig.from_dict({**PAPER_RIG.to_dict(), "width_px": 16, "height_px": 12})
    with pytest.raises(StackError, match=r"does not match the rig: expected 16x12 from the rig, got 32x24") as info:
        read_zip_members(stack_members(), rig=small_rig, max_pixels=16 * 12)
    assert "limit" not in str(info.value)


def test_sixteen_bit_where_eight_declared() -> None:
    with pytest.raises(StackError, match=re.escape("GC_0.png is 16-bit but the stack was declared 8-bit")):
        read_zip_members(stack_members(make_images(16)), expected_bit_depth=8)
    with pytest.raises(StackError, match="is 8-bit but the stack was declared 16-bit"):
        read_zip_members(stack_members(make_images(8)), expected_bit_depth=16)
    with pytest.raises(ValueError, match="expected_bit_depth must be None, 8 or 16"):
        read_zip_members(stack_members(), expected_bit_depth=12)


def test_mixed_bit_depths_are_refused() -> None:
    members = stack_members(make_images(8))
    members["PS_0.png"] = encoded(make_images(16)[0])
    with pytest.raises(StackError, match=re.escape("PS_0.png is 16-bit but GC_0.png is 8-bit")):
        read_zip_members(members)


def test_float_tiff_is_refused() -> None:
    members = stack_members()
    del members["GC_5.png"]
    members["GC_5.tif"] = encoded(np.zeros(SHAPE, np.float32), ".tif")
    with pytest.raises(StackError, match=re.escape("GC_5.tif has float32 samples; only 8- or 16-bit")):
        read_zip_members(members)


def test_not_a_zip(tmp_path: Path) -> None:
    fake = tmp_path / "stack.zip"
    fake.write_text("definitely not a zip")
    with pytest.raises(StackError, match=re.escape("capture stack 'stack.zip' is not a zip file")):
        read_stack(fake)
    with pytest.raises(StackError, match="capture stack upload is not a zip file"):
        read_stack(io.BytesIO(b"PK\x03\x04 but truncated"))
    with pytest.raises(StackError, match="'nothing' does not exist"):
        read_stack(tmp_path / "nothing")


@pytest.mark.parametrize("bad_name", ["../GC_0.png", "/GC_0.png", "a/../../GC_0.png", "..\\GC_0.png", "C:/GC_0.png"])
def test_path_traversal_is_refused(bad_name: str) -> None:
    members = stack_members()
    members[bad_name] = members.pop("GC_0.png")
    with pytest.raises(StackError, match="unsafe member name"):
        read_zip_members(members)


def test_zip_bomb_total_size_is_refused_before_decompressing(monkeypatch: pytest.MonkeyPatch) -> None:
    members = stack_members()
    members["GC_0.png"] = b"\0" * (8 * 2**20)  # 8 MiB that deflate packs into ~8 kB
    data = zip_bytes(members, compression=zipfile.ZIP_DEFLATED)
    assert len(data) < 100_000

    def no_decompression(*args: object, **kwargs: object) -> None:
        raise AssertionError("a member was decompressed")

    monkeypatch.setattr(zipfile.ZipFile, "open", no_decompression)
    with pytest.raises(StackError, match=r"expands to \d+ bytes, more than the limit of 4194304 bytes"):
        read_stack(io.BytesIO(data), max_bytes=4 * 2**20)


def test_zip_bomb_ratio_is_refused() -> None:
    members = stack_members()
    members["GC_0.png"] = b"\0" * (16 * 2**20)
    data = zip_bytes(members, compression=zipfile.ZIP_BZIP2)
    with pytest.raises(StackError, match=r"member GC_0.png claims a compression ratio of \d+:1"):
        read_stack(io.BytesIO(data))


def test_oversized_archive_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "big.zip"
    path.write_bytes(zip_bytes(stack_members()))
    with pytest.raises(StackError, match=r"'big\.zip' is \d+ bytes, more than the limit of 1000 bytes"):
        read_stack(path, max_bytes=1000)


def huge_png() -> bytes:
    data = bytearray(encoded(np.zeros(SHAPE, np.uint8)))
    data[16:24] = struct.pack(">II", 100_000, 100_000)
    crc = zlib.crc32(bytes(data[12:29]))
    data[29:33] = struct.pack(">I", crc)
    return bytes(data)


def huge_bmp() -> bytes:
    data = bytearray(encoded(np.zeros(SHAPE, np.uint8), ".bmp"))
    data[18:26] = struct.pack("<ii", 100_000, -100_000)
    return bytes(data)


def huge_tiff() -> bytes:
    data = bytearray(encoded(np.zeros(SHAPE, np.uint8), ".tif"))
    assert data[:4] == b"II*\x00"
    (ifd,) = struct.unpack_from("<I", data, 4)
    (count,) = struct.unpack_from("<H", data, ifd)
    for i in range(count):
        at = ifd + 2 + 12 * i
        tag, _type = struct.unpack_from("<HH", data, at)
        if tag in (256, 257):
            data[at + 2 : at + 4] = struct.pack("<H", 4)
            data[at + 8 : at + 12] = struct.pack("<I", 100_000)
    return bytes(data)


@pytest.mark.parametrize(("maker", "ext"), [(huge_png, ".png"), (huge_bmp, ".bmp"), (huge_tiff, ".tif")])
def test_enormous_header_dimensions_are_refused_before_decoding(
    maker: object, ext: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert callable(maker)
    data = maker()
    assert image_header_size(data)[1:] == (100_000, 100_000)

    real_imdecode = cv2.imdecode

    def guarded_imdecode(buf: np.ndarray, flags: int) -> np.ndarray | None:
        if buf.tobytes() == data:
            raise AssertionError("the oversized image was decoded")
        return real_imdecode(buf, flags)

    monkeypatch.setattr(gio.cv2, "imdecode", guarded_imdecode)
    with pytest.raises(StackError, match=r"claims 100000x100000 pixels, more than the limit of \d+ pixels"):
        gio.decode_grey_image(data, "GC_0" + ext)
    # In a stack the first image sets the shape, so a huge first image is refused on max_pixels...
    members = stack_members()
    del members["GC_0.png"]
    members["GC_0" + ext] = data
    with pytest.raises(StackError, match="claims 100000x100000 pixels"):
        read_zip_members(members)
    # ... and so is a huge later one: every header is checked before any image is decoded.
    members = stack_members()
    del members["PS_3.png"]
    members["PS_3" + ext] = data
    with pytest.raises(StackError, match=r"PS_3\.\w+ claims 100000x100000 pixels"):
        read_zip_members(members)


# ------------------------------------------------------------------------ writing stacks


def test_write_stack_refuses_16_bit_bmp_and_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="BMP holds 8-bit images only"):
        write_stack(make_images(16), tmp_path / "s", ext=".bmp")
    with pytest.raises(ValueError, match=r"\(11, H, W\)"):
        write_stack(make_images()[:3], tmp_path / "s")
    with pytest.raises(ValueError, match="uint8 or uint16"):
        write_stack(make_images().astype(np.float32), tmp_path / "s")
    with pytest.raises(ValueError, match="ext must be one of"):
        write_stack(make_images(), tmp_path / "s", ext=".jpg")
    assert not list(tmp_path.iterdir())


def test_write_stack_into_existing_folder(tmp_path: Path) -> None:
    write_stack(make_images(seed=1), tmp_path / "s")
    write_stack(make_images(seed=2), tmp_path / "s")  # overwrite, same format
    np.testing.assert_array_equal(read_stack(tmp_path / "s").images, make_images(seed=2))
    with pytest.raises(ValueError, match=r"already holds GC_0\.png, .*would duplicate patterns"):
        write_stack(make_images(), tmp_path / "s", ext=".tif")


def test_write_stack_zip_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dest = tmp_path / "stack.zip"
    write_stack(make_images(seed=1), dest)
    before = dest.read_bytes()

    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(gio.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_stack(make_images(seed=2), dest)
    assert dest.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["stack.zip"]


# ------------------------------------------------------------------------ rigs


def test_rig_round_trip(tmp_path: Path) -> None:
    rig = Rig.from_dict({**PAPER_RIG.to_dict(), "name": "bench A"})
    write_rig(rig, tmp_path / "rig.json")
    again = read_rig(tmp_path / "rig.json")
    assert again == rig
    assert again.extra["name"] == "bench A"


def test_read_rig_names_the_file(tmp_path: Path) -> None:
    data = PAPER_RIG.to_dict()
    del data["alpha_rad"]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(RigError, match=r"rig file 'bad.json': rig is missing required key\(s\): alpha_rad"):
        read_rig(tmp_path / "bad.json")
    (tmp_path / "range.json").write_text(json.dumps({**PAPER_RIG.to_dict(), "L_mm": -1}))
    with pytest.raises(RigError, match=re.escape("rig file 'range.json': rig L_mm must be a positive")):
        read_rig(tmp_path / "range.json")
    (tmp_path / "garbled.json").write_text("{not json")
    with pytest.raises(RigError, match=re.escape("rig file 'garbled.json': rig file is not valid JSON")):
        read_rig(tmp_path / "garbled.json")
    with pytest.raises(RigError, match=re.escape("rig file 'missing.json' does not exist")):
        read_rig(tmp_path / "missing.json")


# ------------------------------------------------------------------------ heights


def height_map() -> np.ndarray:
    z = np.linspace(-3.0, 80.0, 12 * 9, dtype=np.float32).reshape(12, 9)
    z[2, 3] = np.nan
    z[5:7, 0] = np.nan
    return z


def test_height_npy_round_trip(tmp_path: Path) -> None:
    z = height_map()
    write_height_npy(z.astype(np.float64), tmp_path / "z.npy")
    again = read_height_npy(tmp_path / "z.npy")
    assert again.dtype == np.float32
    np.testing.assert_array_equal(again, z)  # NaNs in the same places


def test_height_tiff_keeps_float32_and_nan(tmp_path: Path) -> None:
    z = height_map()
    write_height_tiff(z, tmp_path / "z.tiff")
    again = cv2.imread(str(tmp_path / "z.tiff"), cv2.IMREAD_UNCHANGED)
    assert again.dtype == np.float32
    np.testing.assert_array_equal(again, z)


def test_height_writers_are_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(gio.os, "replace", failing_replace)
    for writer, name in [(write_height_npy, "z.npy"), (write_height_tiff, "z.tiff")]:
        with pytest.raises(OSError, match="disk full"):
            writer(height_map(), tmp_path / name)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        write_height_npy(np.zeros(5), tmp_path / "z.npy")


# ------------------------------------------------------------------------ series


def test_series_round_trip(tmp_path: Path) -> None:
    images = make_images()
    layout = {
        0.0: [series_capture_name(0.0, r) for r in range(2)],
        4.0: [series_capture_name(4.0, r) for r in range(2)],
    }
    for refs in layout.values():
        for ref in refs:
            write_stack(images, tmp_path / ref)
    # One capture stored as a zip but referenced without the extension.
    os.replace(tmp_path / "z004" / "r01", tmp_path / "z004" / "tmp")
    write_stack(images, tmp_path / "z004" / "r01.zip")
    for child in (tmp_path / "z004" / "tmp").iterdir():
        child.unlink()
    (tmp_path / "z004" / "tmp").rmdir()

    write_series(layout, tmp_path / "SERIES.json")
    assert json.loads((tmp_path / "SERIES.json").read_text())["positions"][1] == {
        "z_in_mm": 4.0,
        "captures": ["z004/r00", "z004/r01"],
    }
    series = read_series(tmp_path / "SERIES.json")
    np.testing.assert_array_equal(series.z_in_mm, [0.0, 4.0])
    assert series.positions[1].captures == (tmp_path / "z004" / "r00", tmp_path / "z004" / "r01.zip")
    for position in series.positions:
        for capture in position.captures:
            np.testing.assert_array_equal(read_stack(capture).images, images)
    # Absolute paths inside the folder are written relative; outside ones are refused.
    write_series({8.0: [tmp_path / "z004" / "r00"]}, tmp_path / "other.json")
    assert json.loads((tmp_path / "other.json").read_text())["positions"][0]["captures"] == ["z004/r00"]
    with pytest.raises(ValueError, match="outside the series folder"):
        write_series({8.0: [tmp_path.parent / "elsewhere"]}, tmp_path / "other.json")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{oops", "'SERIES.json' is not valid JSON"),
        ('{"pos": []}', "must be a JSON object with a list 'positions'"),
        ('{"positions": []}', "has no positions"),
        ('{"positions": [5]}', "position 0 must be an object"),
        ('{"positions": [{"z_in_mm": "4", "captures": ["a"]}]}', "'z_in_mm' must be a finite number, got '4'"),
        ('{"positions": [{"z_in_mm": NaN, "captures": ["a"]}]}', "'z_in_mm' must be a finite number, got nan"),
        ('{"positions": [{"z_in_mm": 4, "captures": []}]}', r"position 0 \(z_in_mm=4\): 'captures' must be"),
        ('{"positions": [{"z_in_mm": 4, "captures": [""]}]}', "must be a non-empty path string"),
        ('{"positions": [{"z_in_mm": 4, "captures": ["/abs/r00"]}]}', "must be a relative path inside"),
        ('{"positions": [{"z_in_mm": 4, "captures": ["../r00"]}]}', "must be a relative path inside"),
        ('{"positions": [{"z_in_mm": 4, "captures": ["z004/r00"]}]}', "capture 'z004/r00' not found"),
        (
            '{"positions": [{"z_in_mm": 4, "captures": ["a"]}, {"z_in_mm": 4.0, "captures": ["b"]}]}',
            "position 1: z_in_mm 4.0 appears more than once",
        ),
    ],
)
def test_bad_series_files(tmp_path: Path, content: str, message: str) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "SERIES.json").write_text(content)
    with pytest.raises(StackError, match=message) as info:
        read_series(tmp_path / "SERIES.json")
    assert "\n" not in str(info.value)


def test_series_repeated_capture_and_missing_file(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "SERIES.json").write_text('{"positions": [{"z_in_mm": 0, "captures": ["a", "a/"]}]}')
    with pytest.raises(StackError, match="capture 'a/' is listed more than once"):
        read_series(tmp_path / "SERIES.json")
    with pytest.raises(StackError, match=re.escape("series file 'nope.json' does not exist")):
        read_series(tmp_path / "nope.json")


def test_png_frames_are_written_smaller_than_opencvs_default_and_decode_to_the_same_pixels() -> None:
    """Frames are PNG-encoded with a row filter of none, sub or up (``PNG_WRITE_PARAMS``): on fringe
    frames with noise (a cosine of period 24 px, 2 grey levels of noise) the file is 0.62x the size
    of OpenCV's default encoding (which filtered every row with sub here), the pixels the same."""
    rng = np.random.default_rng(0)
    x = np.arange(320)[None, :]
    frame = np.clip(np.round(128 + 90 * np.cos(2 * np.pi * x / 24) + rng.normal(0, 2, (256, 320))), 0, 255)
    stack = np.repeat(frame.astype(np.uint8)[None], len(PATTERN_NAMES), axis=0)
    files = gio.encode_stack(stack, ".png")
    ours = files[f"{PATTERN_NAMES[0]}.png"]
    default = cv2.imencode(".png", stack[0])[1].tobytes()
    assert len(ours) < 0.7 * len(default), (len(ours), len(default))
    assert np.array_equal(cv2.imdecode(np.frombuffer(ours, np.uint8), cv2.IMREAD_UNCHANGED), stack[0])
