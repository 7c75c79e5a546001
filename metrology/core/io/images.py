"""Image headers (PNG IHDR, BMP info header, TIFF first IFD) read before decoding, and decoding to
grey: sizes are checked against ``max_pixels`` before any pixel is decompressed."""

from __future__ import annotations

import struct

import cv2
import numpy as np

from metrology.core.io.errors import StackError
from metrology.core.io.png import decode_grey_png

DEFAULT_MAX_PIXELS = 2**26
"""Largest accepted image, pixels (64 Mpx, e.g. 8192 x 8192)."""


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

PNG_WRITE_PARAMS: tuple[int, ...] = (
    (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FAST_FILTERS) if hasattr(cv2, "IMWRITE_PNG_FILTER") else ()
)
"""OpenCV's PNG encoder parameters for the frames GCPS Lab writes (capture stacks, codec stacks, the
capture agent's uploads): each row filtered with none, sub or up, as libpng's heuristic picks per
row (the smallest sum of absolute filtered values), never paeth or average. Measured on the 11
frames of a realistic 1280x1024 8-bit capture (OpenCV 5.1): 8.08 -> 5.92 MB and 103 -> 71 ms of CPU
to decode them (OpenCV's default chose the sub filter), 10 -> 12 ms to encode one; a 16-bit frame
2.30 -> 2.08 MB, 15.8 -> 14.4 ms to decode. The same pixels (PNG is lossless). Empty where this
OpenCV has no filter choice (``IMWRITE_PNG_FILTER``)."""


def encode_params(ext: str) -> list[int]:
    """``cv2.imencode``'s parameters for a frame written as ``ext`` (``.png``: :data:`PNG_WRITE_PARAMS`)."""
    return list(PNG_WRITE_PARAMS) if ext.lower() == ".png" else []


def image_header_size(data: bytes) -> tuple[str, int, int]:
    """Format, width and height of a PNG, BMP or TIFF image, read from its header only.

    Parameters
    ----------
    data : bytes
        The file's bytes (only the header part is read).

    Returns
    -------
    fmt : str
        ``"PNG"``, ``"BMP"`` or ``"TIFF"``.
    width_px, height_px : int
        Image size, pixels, as the header claims it.

    Raises
    ------
    ValueError
        If the data is none of the three formats or its header is truncated or invalid.

    Examples
    --------
    >>> import cv2, numpy as np
    >>> ok, buf = cv2.imencode(".png", np.zeros((3, 5), np.uint8))
    >>> image_header_size(buf.tobytes())
    ('PNG', 5, 3)
    """
    try:
        if data.startswith(_PNG_SIGNATURE):
            length, tag, width, height = struct.unpack_from(">I4sII", data, 8)
            if tag != b"IHDR" or length != 13:
                raise ValueError("PNG does not start with an IHDR chunk")
            fmt = "PNG"
        elif data.startswith(b"BM"):
            (header_size,) = struct.unpack_from("<I", data, 14)
            if header_size == 12:
                width, height = struct.unpack_from("<HH", data, 18)
            elif header_size >= 40:
                width, height = struct.unpack_from("<ii", data, 18)
                height = abs(height)
            else:
                raise ValueError(f"BMP info header of unknown size {header_size}")
            fmt = "BMP"
        elif data[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
            width, height = _tiff_size(data)
            fmt = "TIFF"
        else:
            raise ValueError("not a PNG, TIFF or BMP image")
    except struct.error:
        raise ValueError("image header is truncated") from None
    if width <= 0 or height <= 0:
        raise ValueError(f"image header claims a size of {width}x{height}")
    return fmt, int(width), int(height)


def _tiff_size(data: bytes) -> tuple[int, int]:
    """Width and height from the first IFD of a classic or Big TIFF."""
    end = "<" if data[:2] == b"II" else ">"
    big = data[2:4] in (b"+\x00", b"\x00+")
    if big:
        offset_size, _, ifd = struct.unpack_from(end + "HHQ", data, 4)
        if offset_size != 8:
            raise ValueError("BigTIFF with an offset size other than 8")
        (count,) = struct.unpack_from(end + "Q", data, ifd)
        first, entry_size = ifd + 8, 20
    else:
        (ifd,) = struct.unpack_from(end + "I", data, 4)
        (count,) = struct.unpack_from(end + "H", data, ifd)
        first, entry_size = ifd + 2, 12
    if count > 4096:
        raise ValueError(f"TIFF directory claims {count} entries")
    found: dict[int, int] = {}
    for i in range(count):
        at = first + i * entry_size
        tag, typ = struct.unpack_from(end + "HH", data, at)
        if tag not in (256, 257):
            continue
        value_at = at + (12 if big else 8)
        if typ == 3:  # SHORT
            (found[tag],) = struct.unpack_from(end + "H", data, value_at)
        elif typ == 4:  # LONG
            (found[tag],) = struct.unpack_from(end + "I", data, value_at)
        elif typ == 16 and big:  # LONG8
            (found[tag],) = struct.unpack_from(end + "Q", data, value_at)
        else:
            raise ValueError(f"TIFF tag {tag} has unexpected type {typ}")
    if 256 not in found or 257 not in found:
        raise ValueError("TIFF directory lacks ImageWidth or ImageLength")
    return found[256], found[257]


def checked_header(
    data: bytes,
    name: str,
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    expected_shape: tuple[int, int] | None = None,
) -> tuple[str, int, int]:
    """Format, width and height from an image's header, refusing sizes above ``max_pixels``.

    ``expected_shape`` (height_px, width_px), e.g. a rig's, is checked first: an image of another
    size does not match it, whatever the pixel limit.

    Raises
    ------
    StackError
        If the header is unreadable, differs from ``expected_shape`` or claims more than
        ``max_pixels`` pixels.
    """
    try:
        fmt, width, height = image_header_size(data)
    except ValueError as exc:
        raise StackError(f"{name} is not a readable PNG, TIFF or BMP image ({exc})") from None
    if expected_shape is not None and (height, width) != tuple(expected_shape):
        raise StackError(
            f"{name} does not match the rig: expected {expected_shape[1]}x{expected_shape[0]} from the rig, "
            f"got {width}x{height} (image shape as width x height, pixels)"
        )
    if width * height > max_pixels:
        raise StackError(
            f"{name} claims {width}x{height} pixels, more than the limit of {max_pixels} pixels; "
            "refused before decoding"
        )
    return fmt, width, height


def decode_grey_image(
    data: bytes, name: str, *, max_pixels: int = DEFAULT_MAX_PIXELS, out: np.ndarray | None = None
) -> np.ndarray:
    """Decode one PNG/TIFF/BMP image to grey, checking its header first.

    Parameters
    ----------
    data : bytes
        The encoded image.
    name : str
        File name used in error messages.
    max_pixels : int
        Largest accepted width * height, pixels, checked on the header before decoding.
    out : (H, W) C-contiguous array, optional
        Where to write the grey levels when it has the image's shape and dtype (a slot of a
        stack); an image of another shape or dtype is returned as a new array instead.

    Returns
    -------
    image : (H, W) uint8 or uint16 array
        Grey levels (``out`` where they were written there); colour is converted with
        ``cv2.cvtColor`` (BGR or BGRA to grey, alpha ignored). A grey PNG of none, sub and up
        rows is decoded by :func:`~metrology.core.io.png.decode_grey_png` (the same samples,
        faster), any other image by OpenCV.

    Raises
    ------
    StackError
        If the data is not a readable image, is too large, or has a sample type other
        than 8- or 16-bit unsigned integers.
    """
    fmt, width, height = checked_header(data, name, max_pixels=max_pixels)
    image = decode_grey_png(data, out) if fmt == "PNG" else None
    if image is not None and image.shape == (height, width):
        return image  # grey, none/sub/up rows: the same samples as OpenCV's, decoded faster
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        message = str(exc).strip().splitlines()[-1] if str(exc).strip() else "decoder error"
        raise StackError(f"{name} is a corrupt {fmt} image ({message})") from None
    if image is None:
        raise StackError(f"{name} is a corrupt or unsupported {fmt} image (OpenCV could not decode it)")
    if image.dtype not in (np.uint8, np.uint16):
        raise StackError(f"{name} has {image.dtype} samples; only 8- or 16-bit unsigned integer images are accepted")
    if image.ndim == 3:
        channels = image.shape[2]
        if channels == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        elif channels == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        elif channels in (1, 2):  # grey (+ alpha)
            image = np.ascontiguousarray(image[:, :, 0])
        else:
            raise StackError(f"{name} has {channels} channels; expected grey, RGB or RGBA")
    if image.ndim != 2 or image.shape != (height, width):
        raise StackError(f"{name} decoded to shape {image.shape}, unlike its header's {(height, width)}")
    if out is not None and out.shape == image.shape and out.dtype == image.dtype:
        out[...] = image
        return out
    return image
