"""Grey PNGs decoded without OpenCV: the frames of a capture as cameras and GCPS Lab write them.

A PNG stores its rows deflate-compressed, each row preceded by a filter type byte (PNG
specification, section 9): the stored bytes ``f`` of a row are the image bytes ``x`` minus a
prediction from bytes already decoded,

- type 0, none: ``x[i] = f[i]``;
- type 1, sub: ``x[i] = f[i] + x[i - bpp]`` (the byte one pixel to the left, 0 before the row);
- type 2, up: ``x[i] = f[i] + x_above[i]`` (the byte above, 0 above the first row);

all modulo 256, where ``bpp`` is the bytes per pixel (1 for 8-bit grey, 2 for 16-bit). A sub row
is a running sum along the row (``numpy.cumsum`` in uint8), an up row one vector addition.

:func:`decode_grey_png` decodes the PNGs whose pixels these rules give exactly: grey (colour type
0), 8 or 16 bits per sample, not interlaced, no transparency chunk, every row of type 0, 1 or 2 --
the files OpenCV writes by default (sub rows) and with GCPS Lab's fast filters
(:data:`~metrology.core.io.images.PNG_WRITE_PARAMS`: none, sub or up per row). Inflating is
most of the cost of decoding such a file, and ISA-L's inflate (:mod:`metrology.core.deflate`)
does it 2.7x faster than zlib's, which OpenCV's decoder uses: on the 11 frames of a realistic
1280x1024 capture, 26 ms of CPU against 72 ms with zlib and 85 ms for OpenCV's whole decode.
Anything else -- colour, palette, alpha, transparency, interlacing, 1/2/4-bit samples, average or
Paeth rows, a chunk that could change the pixels, a checksum that does not match, a truncated or
over-long stream -- returns None, and the caller decodes the file with OpenCV, which gives the
same pixels or says why it cannot (:func:`~metrology.core.io.images.decode_grey_image`). So the
pixels never depend on which decoder ran.
"""

from __future__ import annotations

import itertools
import struct
import zlib

import numpy as np

from metrology.core.deflate import ZLIB, ZLIB_ERRORS

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

IGNORED_CHUNKS = frozenset({b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs", b"gAMA", b"cHRM", b"sRGB", b"sBIT"})
"""Ancillary chunks that leave the decoded samples unchanged: text, time, pixel size, and the gamma,
chromaticities, sRGB intent and significant bits, which OpenCV's decoder does not apply either.
Any other chunk but IHDR, IDAT and IEND sends the file to OpenCV."""

_FILTER_NONE, _FILTER_SUB, _FILTER_UP = 0, 1, 2


def decode_grey_png(data: bytes, out: np.ndarray | None = None) -> np.ndarray | None:
    """The samples of a grey PNG, or None where this decoder does not take the file (see the module
    docstring; the caller then decodes it with OpenCV).

    Parameters
    ----------
    data : bytes
        The whole file.
    out : (H, W) array, optional
        Where to write the samples, when it has the image's shape and dtype (:func:`sample_dtype`)
        and is C-contiguous (a slot of a stack of frames, say); else a new array is returned.

    Returns
    -------
    image : (H, W) uint8 or uint16 array, or None
        The samples as stored (16-bit ones converted from the file's big-endian order): ``out``
        where it was written, else a new C-contiguous array.
    """
    parsed = _parse(data)
    if parsed is None:
        return None
    width, height, bit_depth, compressed = parsed
    bpp = bit_depth // 8
    stride = 1 + width * bpp
    try:
        raw = ZLIB.decompress(compressed, bufsize=height * stride)
    except ZLIB_ERRORS:
        return None
    if len(raw) != height * stride:
        return None
    filtered = np.frombuffer(raw, np.uint8).reshape(height, stride)
    filters = filtered[:, 0]
    if int(filters.max()) > _FILTER_UP:
        return None  # average, Paeth (or invalid) rows: OpenCV
    dtype = np.uint8 if bpp == 1 else np.uint16
    fits = out is not None and out.shape == (height, width) and out.dtype == dtype and out.flags.c_contiguous
    if bpp == 1:
        return unfilter_rows(filtered[:, 1:], filters, bpp, out=out if fits else None)
    image_bytes = unfilter_rows(filtered[:, 1:], filters, bpp).view(">u2")
    if fits:
        assert out is not None
        np.copyto(out, image_bytes)
        return out
    return image_bytes.astype(np.uint16)


def sample_dtype(data: bytes) -> type[np.uint8] | type[np.uint16] | None:
    """The dtype of the grey samples that decoding a PNG gives (here or with OpenCV): uint16 for a
    16-bit PNG, uint8 for any other (1- to 8-bit grey, palette, 8-bit colour converted to grey);
    None where ``data`` does not start like a PNG (signature and IHDR)."""
    if len(data) < 33 or not data.startswith(PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return None
    return np.uint16 if data[24] == 16 else np.uint8


def unfilter_rows(filtered: np.ndarray, filters: np.ndarray, bpp: int, out: np.ndarray | None = None) -> np.ndarray:
    """The image bytes from the filtered bytes of rows of types none, sub and up (module docstring).

    Parameters
    ----------
    filtered : (H, W * bpp) uint8 array
        Each row's stored bytes, without its filter type byte.
    filters : (H,) uint8 array
        Each row's filter type, 0, 1 or 2.
    bpp : int
        Bytes per pixel (1 or 2).
    out : (H, W * bpp) uint8 C-contiguous array, optional
        Where to write the image bytes (a new array when None).

    Returns
    -------
    (H, W * bpp) uint8 array
        The image bytes (``out`` when given): runs of rows of one type at a time, a run of sub
        rows as one running sum along its rows, an up row as the sum with the row above.
    """
    height, row_bytes = filtered.shape
    if out is None:
        out = np.empty((height, row_bytes), np.uint8)
    starts = np.flatnonzero(np.diff(filters)) + 1
    bounds = [0, *starts.tolist(), height]
    for start, end in itertools.pairwise(bounds):
        kind = int(filters[start])
        if kind == _FILTER_NONE:
            out[start:end] = filtered[start:end]
        elif kind == _FILTER_SUB:
            lanes = (end - start, row_bytes // bpp, bpp)  # each byte of a pixel sums with its own lane
            np.cumsum(filtered[start:end].reshape(lanes), axis=1, dtype=np.uint8, out=out[start:end].reshape(lanes))
        else:
            first = start
            if start == 0:
                out[0] = filtered[0]  # the row above the first is zero
                first = 1
            for row in range(first, end):
                np.add(out[row - 1], filtered[row], out=out[row])
    return out


CRC_PIECE_BYTES = 4096
"""The CRC of a chunk is computed over pieces of at most this many bytes: CPython's ``zlib.crc32``
keeps the GIL for less than 5 KiB and releases it above, and each release is followed by taking it
back, which waits for the switch interval (5 ms) where another thread holds it -- ``gcps measure``'s
main thread importing while the frames decode. A frame's 60-odd IDAT chunks of 8 KiB (libpng's)
then cost tens of milliseconds of waiting; in pieces, 0.2 ms of CPU holding the GIL."""


def _crc32(data: memoryview) -> int:
    """CRC-32 of ``data`` (zlib's), computed piecewise without releasing the GIL (:data:`CRC_PIECE_BYTES`)."""
    crc = 0
    for start in range(0, len(data), CRC_PIECE_BYTES):
        crc = zlib.crc32(data[start : start + CRC_PIECE_BYTES], crc)
    return crc


def _parse(data: bytes) -> tuple[int, int, int, bytes] | None:
    """Width, height, bit depth and the concatenated IDAT data of a PNG this decoder takes; None
    for any other (module docstring), a malformed one or a chunk whose CRC does not match."""
    if not data.startswith(PNG_SIGNATURE):
        return None
    view = memoryview(data)
    position = len(PNG_SIGNATURE)
    header: tuple[int, int, int] | None = None
    idat: list[memoryview] = []
    while position + 12 <= len(data):
        (length,) = struct.unpack_from(">I", data, position)
        kind = bytes(view[position + 4 : position + 8])
        end = position + 12 + length
        if end > len(data):
            return None
        body = view[position + 8 : end - 4]
        (crc,) = struct.unpack_from(">I", data, end - 4)
        if _crc32(view[position + 4 : end - 4]) != crc:
            return None
        if header is None:
            if kind != b"IHDR" or length != 13:
                return None
            width, height, bit_depth, colour, compression, filtering, interlace = struct.unpack(">IIBBBBB", body)
            if (
                not (width and height)
                or bit_depth not in (8, 16)
                or (colour, compression, filtering, interlace) != (0, 0, 0, 0)
            ):
                return None
            header = (width, height, bit_depth)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            if header is None or not idat:
                return None
            return (*header, b"".join(idat))
        elif kind not in IGNORED_CHUNKS:
            return None
        position = end
    return None  # no IEND: truncated


__all__ = ["IGNORED_CHUNKS", "PNG_SIGNATURE", "decode_grey_png", "sample_dtype", "unfilter_rows"]
