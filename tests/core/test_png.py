"""metrology.core.io.png: the grey PNGs it decodes give OpenCV's samples bit for bit, and every
other PNG is left to OpenCV (None), so that decode_grey_image's pixels never depend on the
decoder that ran."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from metrology.core.io import decode_grey_image
from metrology.core.io.images import PNG_WRITE_PARAMS
from metrology.core.io.png import PNG_SIGNATURE, decode_grey_png, unfilter_rows
from tests.datasets import dataset_path, require_dataset

FILTERS = {
    "none": [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE],
    "sub": [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB],
    "up": [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP],
    "fast (GCPS Lab's)": list(PNG_WRITE_PARAMS),
    "OpenCV's default": [],
}
"""Writer settings whose rows are all none, sub or up: decoded here."""


def opencv(data: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None
    return image


def encode(image: np.ndarray, params: list[int]) -> bytes:
    ok, buf = cv2.imencode(".png", image, params)
    assert ok
    return buf.tobytes()


def chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """A PNG's chunks as (type, body)."""
    out, position = [], len(PNG_SIGNATURE)
    while position < len(data):
        (length,) = struct.unpack_from(">I", data, position)
        out.append((data[position + 4 : position + 8], data[position + 8 : position + 8 + length]))
        position += 12 + length
    return out


def png(parts: list[tuple[bytes, bytes]]) -> bytes:
    """A PNG from chunks, each with its CRC."""
    body = b"".join(
        struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data)) for kind, data in parts
    )
    return PNG_SIGNATURE + body


def images(bit_depth: int) -> list[np.ndarray]:
    """Noise, a ramp that wraps around the byte, a constant, and degenerate sizes."""
    rng = np.random.default_rng(bit_depth)
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    top = 2**bit_depth
    ramp = (np.arange(37 * 53).reshape(37, 53) * 97 % top).astype(dtype)
    return [
        rng.integers(0, top, (37, 53), dtype=dtype),
        ramp,
        np.full((4, 6), top - 1, dtype),
        rng.integers(0, top, (1, 9), dtype=dtype),
        rng.integers(0, top, (9, 1), dtype=dtype),
        rng.integers(0, top, (1, 1), dtype=dtype),
    ]


@pytest.mark.parametrize("bit_depth", [8, 16])
@pytest.mark.parametrize("writer", list(FILTERS))
def test_rows_of_none_sub_and_up_decode_to_opencvs_samples(bit_depth, writer):
    # OpenCV's default writer (sub rows) only without a compression level: with one, libpng's adaptive filters
    levels = [[]] if writer == "OpenCV's default" else [[cv2.IMWRITE_PNG_COMPRESSION, level] for level in (0, 1, 9)]
    for image in images(bit_depth):
        for level in levels:
            data = encode(image, [*FILTERS[writer], *level])
            decoded = decode_grey_png(data)
            assert decoded is not None, f"{writer}, {image.shape}, level {level}: left to OpenCV"
            assert decoded.dtype == image.dtype and decoded.flags.c_contiguous
            np.testing.assert_array_equal(decoded, image)
            np.testing.assert_array_equal(decoded, opencv(data))


def test_sixteen_bit_samples_are_read_big_endian():
    image = np.array([[0x0102, 0xFF00, 0x00FF]], np.uint16)
    decoded = decode_grey_png(encode(image, []))
    assert decoded is not None and decoded.tolist() == [[258, 65280, 255]]


def test_mixed_rows_of_each_type_follow_the_png_specification():
    """The three rules on hand-made rows (bpp 1 and 2), against a direct per-byte loop."""
    rng = np.random.default_rng(3)
    for bpp in (1, 2):
        filtered = rng.integers(0, 256, (12, 5 * bpp), dtype=np.uint8)
        filters = np.array([2, 1, 1, 0, 2, 2, 1, 0, 0, 2, 1, 2], np.uint8)
        expected = np.zeros_like(filtered, dtype=np.int64)
        for y in range(12):
            for i in range(5 * bpp):
                left = expected[y, i - bpp] if i >= bpp else 0
                above = expected[y - 1, i] if y else 0
                predictor = {0: 0, 1: left, 2: above}[int(filters[y])]
                expected[y, i] = (int(filtered[y, i]) + predictor) % 256
        np.testing.assert_array_equal(unfilter_rows(filtered, filters, bpp), expected)


@pytest.mark.parametrize("filter_flag", ["IMWRITE_PNG_FILTER_AVG", "IMWRITE_PNG_FILTER_PAETH"])
def test_average_and_paeth_rows_are_left_to_opencv_and_decode_alike(filter_flag):
    image = images(8)[0]
    data = encode(image, [cv2.IMWRITE_PNG_FILTER, getattr(cv2, filter_flag)])
    assert decode_grey_png(data) is None
    np.testing.assert_array_equal(decode_grey_image(data, "f.png"), image)


def test_chunks_that_leave_the_samples_unchanged_are_skipped():
    image = images(8)[1]
    parts = chunks(encode(image, []))
    extra = [
        (b"tEXt", b"Software\0GCPS Lab"),
        (b"pHYs", struct.pack(">IIB", 3780, 3780, 1)),
        (b"gAMA", struct.pack(">I", 45455)),
        (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)),
        (b"sRGB", b"\x00"),
        (b"sBIT", b"\x05"),
    ]
    data = png([parts[0], *extra, *parts[1:]])
    decoded = decode_grey_png(data)
    assert decoded is not None
    np.testing.assert_array_equal(decoded, image)
    np.testing.assert_array_equal(opencv(data), image)  # OpenCV applies none of them either


def test_several_idat_chunks_are_joined():
    image = images(8)[0]
    parts = chunks(encode(image, []))
    (idat,) = [body for kind, body in parts if kind == b"IDAT"]
    split = [(b"IDAT", idat[i : i + 100]) for i in range(0, len(idat), 100)]
    data = png([parts[0], *split, (b"IEND", b"")])
    decoded = decode_grey_png(data)
    assert decoded is not None
    np.testing.assert_array_equal(decoded, image)


def test_other_pngs_are_left_to_opencv():
    image = images(8)[0]
    good = encode(image, [])
    parts = chunks(good)
    ihdr = parts[0][1]
    cases = {
        "colour": encode(np.dstack([image, image, image]), []),
        "colour and alpha": encode(np.dstack([image, image, image, image]), []),
        "transparency chunk": png([parts[0], (b"tRNS", b"\x00\x07"), *parts[1:]]),
        "unknown ancillary chunk": png([parts[0], (b"prVt", b"x"), *parts[1:]]),
        "interlaced header": png([(b"IHDR", ihdr[:12] + b"\x01"), *parts[1:]]),
        "4-bit header": png([(b"IHDR", ihdr[:8] + b"\x04" + ihdr[9:]), *parts[1:]]),
        "bad CRC": good[:-5] + bytes([good[-5] ^ 1]) + good[-4:],
        "truncated": good[: len(good) // 2],
        "no IEND": png(parts[:-1]),
        "not a PNG": b"BM" + good[2:],
        "stream too short for the header": png([(b"IHDR", struct.pack(">II", 37, 54) + ihdr[8:]), *parts[1:]]),
        "corrupt stream": png([parts[0], (b"IDAT", b"\x78\x9c" + b"\xff" * 40), (b"IEND", b"")]),
    }
    for name, data in cases.items():
        assert decode_grey_png(data) is None, name


def test_decode_grey_image_takes_this_decoder_where_it_can():
    """The fast path runs (decode_grey_image's result is this decoder's array) and OpenCV's path
    still decodes colour to grey."""
    image = images(8)[0]
    np.testing.assert_array_equal(decode_grey_image(encode(image, list(PNG_WRITE_PARAMS)), "f.png"), image)
    colour = np.dstack([image, image // 2, image // 3])
    expected = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    np.testing.assert_array_equal(decode_grey_image(encode(colour, []), "c.png"), expected)


def test_the_real_captures_decode_to_opencvs_samples():
    """kamino410 object1: 32 8-bit grey frames of 1936x1216 written by OpenCV (sub rows)."""
    folder = dataset_path("kamino410-phase-shifting", "object1")
    require_dataset(folder, "kamino410 phase-shifting object1")
    frames = sorted(folder.glob("pat*.png"))
    assert len(frames) == 32
    for path in frames:
        data = path.read_bytes()
        decoded = decode_grey_png(data)
        assert decoded is not None, path.name
        np.testing.assert_array_equal(decoded, opencv(data))


@pytest.mark.parametrize("bit_depth", [8, 16])
def test_samples_are_written_into_a_slot_of_their_shape_and_dtype(bit_depth):
    image = images(bit_depth)[0]
    stack = np.zeros((2, *image.shape), image.dtype)
    for params in (list(PNG_WRITE_PARAMS), [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]):  # both decoders
        stack[:] = 0
        decoded = decode_grey_image(encode(image, params), "f.png", out=stack[1])
        assert decoded.base is stack
        np.testing.assert_array_equal(stack[1], image)
        assert not stack[0].any()
    other = np.zeros(image.shape, np.uint16 if bit_depth == 8 else np.uint8)  # another dtype: a new array
    decoded = decode_grey_image(encode(image, []), "f.png", out=other)
    assert decoded.base is not other and not other.any()
    np.testing.assert_array_equal(decoded, image)
