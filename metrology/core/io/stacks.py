"""Capture stacks: the eleven images of gcps-v1 (:class:`CaptureStack`), read and validated from a folder,
a zip or an upload (:func:`read_stack`), and written (:func:`write_stack`, :func:`encode_stack`)."""

from __future__ import annotations

import hashlib
import io
import os
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.io.archives import (
    DEFAULT_MAX_BYTES,
    DEFAULT_MAX_RATIO,
    IMAGE_EXTENSIONS,
    _match_patterns,
    _open_zip,
    _read_folder,
    _read_zip,
    is_junk,
    strip_single_folder,
)
from metrology.core.io.atomic import _write_bytes_atomic, write_files_new_folder_atomic, write_files_zip_atomic
from metrology.core.io.errors import StackError
from metrology.core.io.images import DEFAULT_MAX_PIXELS, checked_header, decode_grey_image, encode_params
from metrology.core.io.png import sample_dtype
from metrology.core.patterns import PATTERN_NAMES

if TYPE_CHECKING:  # the geometry package (every model) is not imported to read a stack
    from metrology.core.geometry.base import GeometryModel


@dataclass(frozen=True, eq=False)
class CaptureStack:
    """The eleven images of a capture stack (docs/file-formats.md).

    Parameters
    ----------
    images : (11, H, W) uint8 or uint16 array
        Grey images in :data:`~metrology.core.patterns.PATTERN_NAMES` order (GC_0..GC_6,
        PS_0..PS_3), grey levels. Made read-only.
    bit_depth : int
        8 (uint8) or 16 (uint16).
    shape : tuple of int
        ``(H, W)`` = ``(height_px, width_px)``.

    Raises
    ------
    ValueError
        If the three fields are inconsistent.
    """

    images: np.ndarray
    bit_depth: int
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        images = self.images
        if not isinstance(images, np.ndarray) or images.ndim != 3 or images.shape[0] != len(PATTERN_NAMES):
            got = getattr(images, "shape", type(images).__name__)
            raise ValueError(f"images must be an ({len(PATTERN_NAMES)}, H, W) array, got {got}")
        expected_dtype = {8: np.uint8, 16: np.uint16}.get(self.bit_depth)
        if expected_dtype is None or images.dtype != expected_dtype:
            raise ValueError(f"bit_depth {self.bit_depth!r} does not match images of dtype {images.dtype}")
        if tuple(self.shape) != images.shape[1:]:
            raise ValueError(f"shape {self.shape!r} does not match images of shape {images.shape}")
        object.__setattr__(self, "shape", (int(images.shape[1]), int(images.shape[2])))
        images.flags.writeable = False

    def __getitem__(self, name: str) -> np.ndarray:
        """The image of pattern ``name`` (e.g. ``"PS_0"``): ``(H, W)`` array."""
        try:
            return self.images[PATTERN_NAMES.index(name)]
        except ValueError:
            raise KeyError(f"unknown pattern name {name!r}; expected one of {', '.join(PATTERN_NAMES)}") from None


def read_stack(
    source: str | os.PathLike[str] | IO[bytes],
    *,
    rig: GeometryModel | None = None,
    expected_bit_depth: int | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> CaptureStack:
    """Read and validate a capture stack (docs/file-formats.md).

    Parameters
    ----------
    source : path or binary file object
        A folder, a ``.zip`` file, or a readable binary file object holding a zip
        (an upload). A file object's ``name`` attribute, if any, labels messages.
    rig : GeometryModel, optional
        When given, every image must have the rig's shape ``(height_px, width_px)``.
    expected_bit_depth : {None, 8, 16}
        When given, the stack's bit depth must equal it.
    max_pixels : int
        Largest accepted width * height of one image, pixels; checked on the image
        header before decoding.
    max_bytes : int
        Largest accepted archive size and total (uncompressed) size of the eleven
        image files, bytes; for zips checked on the declared sizes before decompressing.
    max_ratio : float
        Largest accepted compression ratio of a zip member over 1 MiB
        (see :data:`DEFAULT_MAX_RATIO`).

    Returns
    -------
    CaptureStack
        ``images`` is ``(11, H, W)`` uint8 or uint16 in PATTERN_NAMES order.

    Raises
    ------
    StackError
        With a one-line message naming the problem: missing, unexpected or duplicate
        files, not a zip, unsafe member names, zip bomb, unreadable or corrupt image,
        oversized image header, unsupported sample type, mixed bit depths or shapes,
        a shape unlike the rig's, or a bit depth unlike the expected one.
    ValueError
        If ``expected_bit_depth`` is not None, 8 or 16.
    """
    if expected_bit_depth not in (None, 8, 16):
        raise ValueError(f"expected_bit_depth must be None, 8 or 16, got {expected_bit_depth!r}")
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label = repr(path.name or str(path))
        if path.is_dir():
            files = _read_folder(label, path, max_bytes=max_bytes)
        elif path.is_file():
            import zipfile  # here: reading a folder (gcps measure's start-up) does without it

            size = path.stat().st_size
            if size > max_bytes:
                raise StackError(f"capture stack {label} is {size} bytes, more than the limit of {max_bytes} bytes")
            if not zipfile.is_zipfile(path):
                raise StackError(f"capture stack {label} is not a zip file (nor a folder)")
            with _open_zip(label, path) as archive:
                files = _read_zip(label, archive, max_bytes=max_bytes, max_ratio=max_ratio)
        else:
            raise StackError(f"capture stack {label} does not exist")
    else:
        name = getattr(source, "name", None)
        label = repr(Path(name).name) if isinstance(name, str) and name else "upload"
        fileobj: IO[bytes] = source
        if not (hasattr(fileobj, "seekable") and fileobj.seekable()):
            data = fileobj.read(max_bytes + 1)
            if len(data) > max_bytes:
                raise StackError(f"capture stack {label} is larger than the limit of {max_bytes} bytes")
            fileobj = io.BytesIO(data)
        else:
            size = fileobj.seek(0, os.SEEK_END)
            fileobj.seek(0)
            if size > max_bytes:
                raise StackError(f"capture stack {label} is {size} bytes, more than the limit of {max_bytes} bytes")
        with _open_zip(label, fileobj) as archive:
            files = _read_zip(label, archive, max_bytes=max_bytes, max_ratio=max_ratio)
    return _decode_stack(label, files, rig=rig, expected_bit_depth=expected_bit_depth, max_pixels=max_pixels)


def _decode_stack(
    label: str,
    files: Mapping[str, tuple[str, bytes]],
    *,
    rig: GeometryModel | None,
    expected_bit_depth: int | None,
    max_pixels: int,
) -> CaptureStack:
    expected_shape = rig.shape if rig is not None else None
    names: list[str] = []
    first_shape: tuple[str, tuple[int, int]] | None = None
    # 1. every header, in pattern order, before decoding anything
    for pattern in PATTERN_NAMES:
        entry, data = files[pattern]
        name = f"{label}/{entry}" if label != "upload" else entry
        names.append(name)
        _, width, height = checked_header(data, name, max_pixels=max_pixels, expected_shape=expected_shape)
        shape = (height, width)
        if first_shape is not None and shape != first_shape[1]:
            raise StackError(
                f"{name} has shape {shape} but {first_shape[0]} has shape {first_shape[1]} (height, width)"
            )
        if first_shape is None:
            first_shape = (name, shape)

    # 2. decode in parallel (the decoders release the GIL), each frame straight into its slot of
    # the stack when the first file's header tells the stack's dtype (a PNG); the first error in
    # pattern order wins
    assert first_shape is not None
    dtype = sample_dtype(files[PATTERN_NAMES[0]][1])
    slots = None if dtype is None else np.empty((len(PATTERN_NAMES), *first_shape[1]), dtype)

    def decode(index: int) -> np.ndarray | StackError:
        slot = None if slots is None else slots[index]
        try:
            return decode_grey_image(files[PATTERN_NAMES[index]][1], names[index], max_pixels=max_pixels, out=slot)
        except StackError as exc:
            return exc

    with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        decoded = list(pool.map(decode, range(len(PATTERN_NAMES))))

    # 3. bit depths, in pattern order
    images: np.ndarray | None = None
    first_depth: tuple[str, int] | None = None
    for index, image in enumerate(decoded):
        if isinstance(image, StackError):
            raise image
        name = names[index]
        depth = 8 if image.dtype == np.uint8 else 16
        if expected_bit_depth is not None and depth != expected_bit_depth:
            raise StackError(f"{name} is {depth}-bit but the stack was declared {expected_bit_depth}-bit")
        if first_depth is None:
            first_depth = (name, depth)
            images = slots if slots is not None and slots.dtype == image.dtype else None
            if images is None:
                images = np.empty((len(PATTERN_NAMES), *image.shape), dtype=image.dtype)
        elif depth != first_depth[1]:
            raise StackError(
                f"{name} is {depth}-bit but {first_depth[0]} is {first_depth[1]}-bit; a stack has one bit depth"
            )
        assert images is not None
        if image.base is not images:  # not decoded into its slot
            images[index] = image
    assert images is not None and first_depth is not None
    return CaptureStack(images=images, bit_depth=first_depth[1], shape=first_shape[1])


def _as_stack_images(images: CaptureStack | npt.ArrayLike) -> np.ndarray:
    array = images.images if isinstance(images, CaptureStack) else np.asarray(images)
    if array.ndim != 3 or array.shape[0] != len(PATTERN_NAMES) or 0 in array.shape:
        raise ValueError(f"images must be an ({len(PATTERN_NAMES)}, H, W) array, got shape {array.shape}")
    if array.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"images must be uint8 or uint16, got {array.dtype}")
    return array


def encode_stack(images: CaptureStack | npt.ArrayLike, ext: str = ".png") -> dict[str, bytes]:
    """Encode the eleven images of a stack: file name -> bytes.

    Parameters
    ----------
    images : CaptureStack or (11, H, W) uint8/uint16 array
        In PATTERN_NAMES order.
    ext : {".png", ".tif", ".tiff", ".bmp"}
        Image format. BMP holds 8-bit images only.

    Returns
    -------
    dict
        ``{"GC_0.png": b"...", ...}`` in PATTERN_NAMES order.
    """
    array = _as_stack_images(images)
    ext = ext.lower()
    if ext not in IMAGE_EXTENSIONS:
        raise ValueError(f"ext must be one of {', '.join(IMAGE_EXTENSIONS)}, got {ext!r}")
    if ext == ".bmp" and array.dtype != np.uint8:
        raise ValueError("BMP holds 8-bit images only; write 16-bit stacks as .png or .tif")
    encoded = {}
    for pattern, image in zip(PATTERN_NAMES, array, strict=True):
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image), encode_params(ext))
        if not ok:
            raise OSError(f"OpenCV could not encode {pattern}{ext}")
        encoded[pattern + ext] = buf.tobytes()
    return encoded


def write_stack(images: CaptureStack | npt.ArrayLike, dest: str | os.PathLike[str], *, ext: str = ".png") -> Path:
    """Write a capture stack as a folder or a .zip (docs/file-formats.md).

    Parameters
    ----------
    images : CaptureStack or (11, H, W) uint8/uint16 array
        Grey images in PATTERN_NAMES order.
    dest : path
        A path ending in ``.zip`` (case-insensitive) writes a zip with the eleven files at
        its top level; any other path is a folder, created if needed.
    ext : {".png", ".tif", ".tiff", ".bmp"}
        Image format (8- or 16-bit PNG/TIFF; 8-bit BMP).

    Returns
    -------
    Path
        ``dest``.

    Raises
    ------
    ValueError
        On a bad array or format, or when an existing folder already holds a pattern
        file with another extension (the folder would then hold a duplicate pattern).

    Notes
    -----
    A zip is written to a temporary file and renamed into place. A new folder is
    written as a temporary sibling folder and renamed into place; in an existing folder
    each file is replaced atomically.
    """
    encoded = encode_stack(images, ext)
    target = Path(dest)
    if target.suffix.lower() == ".zip":
        return write_files_zip_atomic(encoded, target, compress=ext.lower() != ".png")
    if target.is_dir():
        clashes = [
            child.name
            for child in target.iterdir()
            if child.stem in PATTERN_NAMES and child.suffix.lower() in IMAGE_EXTENSIONS and child.name not in encoded
        ]
        if clashes:
            raise ValueError(
                f"folder {str(target)!r} already holds {', '.join(sorted(clashes))}; writing {ext} images there "
                "would duplicate patterns"
            )
        for name, data in encoded.items():
            _write_bytes_atomic(target / name, data)
        return target
    return write_files_new_folder_atomic(encoded, target)


def read_verified_stack(data: bytes, sha256: str, *, shape: tuple[int, int] | None = None) -> CaptureStack:
    """Read a stack zip that :func:`read_stack` validated before (an upload), once its hash still matches.

    The zip's structure, names, sizes and image headers were checked when ``sha256`` was recorded;
    they are not checked again. Only the hash is (about 2 ms per MB): a file that changed since is
    refused. The eleven members are inflated and decoded in parallel (zlib and OpenCV release the GIL).

    Parameters
    ----------
    data : bytes
        The stored zip.
    sha256 : str
        Its hex SHA-256 recorded when it was validated.
    shape : (H, W), optional
        The expected image shape (the rig's).

    Returns
    -------
    CaptureStack

    Raises
    ------
    StackError
        If the hash differs, or the images are not one shape and bit depth (or not ``shape``).
    """
    import zipfile

    digest = hashlib.sha256(data).hexdigest()
    if digest != sha256.lower():
        raise StackError(
            f"capture stack no longer matches the sha256 recorded when it was validated ({digest} != {sha256}); refused"
        )
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        names = [info.filename for info in archive.infolist() if not info.is_dir() and not is_junk(info.filename)]
    prefix, entries = strip_single_folder(names)
    members = _match_patterns("verified stack", entries)

    def load(pattern: str) -> np.ndarray:
        member = prefix + members[pattern]
        with zipfile.ZipFile(io.BytesIO(data)) as archive:  # one reader per thread
            raw = archive.read(member)
        return decode_grey_image(raw, member, max_pixels=2**62)

    with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        decoded = list(pool.map(load, PATTERN_NAMES))
    first = decoded[0]
    for pattern, image in zip(PATTERN_NAMES, decoded, strict=True):
        if image.shape != first.shape or image.dtype != first.dtype:
            raise StackError(
                f"{pattern} has shape {image.shape} {image.dtype}, unlike GC_0 {first.shape} {first.dtype}"
            )
    if shape is not None and first.shape != tuple(shape):
        raise StackError(f"images have shape {first.shape} (height, width) but {tuple(shape)} was expected")
    images = np.stack(decoded)
    return CaptureStack(images=images, bit_depth=8 if images.dtype == np.uint8 else 16, shape=first.shape)
