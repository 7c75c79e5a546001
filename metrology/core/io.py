"""File formats of gcps-v1 (DESIGN.md 1.2, 1.3, 1.5, 1.6): capture stacks, rigs, heights, series.

Capture stacks
--------------
A capture stack is a folder or a .zip holding exactly one image per pattern of
:data:`~metrology.core.patterns.PATTERN_NAMES`, named ``GC_0.png`` .. ``PS_3.png``
with extension ``.png``, ``.tif``, ``.tiff`` or ``.bmp`` (extension case-insensitive,
pattern name case-sensitive). :func:`read_stack` refuses anything else with a
:class:`StackError` whose one-line message names the problem.

- A zip may hold the eleven files at its top level or inside one single folder; a folder
  may likewise hold them directly or inside one single sub-folder.
- Junk that operating systems add is ignored, and nothing else: the ``__MACOSX/`` tree,
  AppleDouble files ``._*``, ``.DS_Store``, ``Thumbs.db`` and ``desktop.ini``
  (see :data:`JUNK_NAMES`). Directory entries of a zip are ignored.
- Zips are read into memory (``cv2.imdecode``), never extracted. Before anything is
  decompressed, member names with ``..`` components or absolute paths are refused, and so
  are archives whose declared uncompressed sizes add up beyond ``max_bytes`` or whose
  members claim a compression ratio beyond ``max_ratio`` (zip bombs).
- Each image's width and height are parsed from its header (PNG IHDR, BMP info header,
  TIFF first IFD) and checked against ``max_pixels`` and the expected shape *before* it
  is decoded, so a small file claiming enormous dimensions is refused cheaply.
- Colour images are converted to grey (alpha ignored); samples must be 8- or 16-bit
  unsigned integers, and all eleven images must share one bit depth and one shape.

Other files
-----------
Rig files are JSON (:func:`read_rig`, :func:`write_rig`); height maps are float32
``.npy`` or float32 TIFF (:func:`write_height_npy`, :func:`write_height_tiff`); stage
series are ``SERIES.json`` files (:func:`read_series`, :func:`write_series`). Every
writer is atomic: it writes a temporary file in the destination folder and renames it
into place (``os.replace``), so no partial output is ever visible under the final name.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import secrets
import shutil
import struct
import zipfile
import zlib
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO, Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.patterns import PATTERN_NAMES
from metrology.core.rig import Rig, RigError

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".tif", ".tiff", ".bmp")
"""Accepted image file extensions (compared case-insensitively)."""

JUNK_NAMES: frozenset[str] = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})
"""File names ignored in stacks, besides ``__MACOSX/`` and AppleDouble ``._*`` files."""

DEFAULT_MAX_PIXELS = 2**26
"""Largest accepted image, pixels (64 Mpx, e.g. 8192 x 8192)."""

DEFAULT_MAX_BYTES = 2**29
"""Largest accepted archive, and largest total uncompressed size of a stack's files (512 MiB)."""

DEFAULT_MAX_RATIO = 1100.0
"""Largest accepted compression ratio of a zip member.

Deflate cannot exceed about 1032:1, and noise-free simulated captures stored as BMP
legitimately come close to that, so this limit only refuses members compressed by
other methods (bzip2, LZMA) beyond what deflate could reach. The real protection
against zip bombs is ``max_bytes``, checked on the declared sizes before decompression
(and enforced while reading, since :mod:`zipfile` never returns more than the
declared size).
"""

MAX_ARCHIVE_MEMBERS = 1000
"""Largest number of entries accepted in a stack zip."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class StackError(ValueError):
    """A capture stack (or stage series) is malformed; the one-line message names the problem."""


@dataclass(frozen=True, eq=False)
class CaptureStack:
    """The eleven images of a capture stack (DESIGN.md 1.3).

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


# ---------------------------------------------------------------------------- atomic writes


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The temporary file is hidden (leading dot), lives in the destination folder (so the
    final ``os.replace`` is atomic) and keeps ``path``'s extension (so writers that pick a
    format by extension, like ``cv2.imwrite`` or open3d, work). If the body raises, the
    temporary file is removed and ``path`` is left untouched. The parent folder must exist.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> out.read_text()
    'done'
    """
    final = Path(path)
    if not final.parent.is_dir():
        raise FileNotFoundError(f"output folder {str(final.parent)!r} does not exist")
    tmp = final.with_name(f".{final.stem}.{secrets.token_hex(6)}.tmp{final.suffix}")
    try:
        yield tmp
        if not tmp.exists():
            raise OSError(f"writing {final.name} produced no file")
        os.replace(tmp, final)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    with atomic_path(path) as tmp:
        # os.open honours the umask, unlike mkstemp's 0600.
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)


def write_text_atomic(text: str, path: str | os.PathLike[str]) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (a reader sees the old file or the whole new one)."""
    _write_bytes_atomic(path, text.encode("utf-8"))


# ---------------------------------------------------------------------------- image headers


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


def decode_grey_image(data: bytes, name: str, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """Decode one PNG/TIFF/BMP image to grey, checking its header first.

    Parameters
    ----------
    data : bytes
        The encoded image.
    name : str
        File name used in error messages.
    max_pixels : int
        Largest accepted width * height, pixels, checked on the header before decoding.

    Returns
    -------
    image : (H, W) uint8 or uint16 array
        Grey levels; colour is converted with ``cv2.cvtColor`` (BGR or BGRA to grey,
        alpha ignored).

    Raises
    ------
    StackError
        If the data is not a readable image, is too large, or has a sample type other
        than 8- or 16-bit unsigned integers.
    """
    fmt, width, height = checked_header(data, name, max_pixels=max_pixels)
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
    return image


# ---------------------------------------------------------------------------- reading stacks


def _is_junk(relpath: str) -> bool:
    parts = relpath.split("/")
    base = parts[-1]
    return parts[0] == "__MACOSX" or base in JUNK_NAMES or base.startswith("._")


def _list_names(names: Sequence[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _match_patterns(label: str, entries: Sequence[str]) -> dict[str, str]:
    """Map pattern names to entry paths; refuse missing, extra and duplicate entries.

    ``entries`` are '/'-separated relative paths of the non-junk files (and folders,
    ending in '/') of the stack, already reduced to the stack's root.
    """
    found: dict[str, list[str]] = {}
    unexpected: list[str] = []
    for entry in entries:
        path = PurePosixPath(entry)
        if entry.endswith("/") or len(path.parts) != 1 or path.suffix.lower() not in IMAGE_EXTENSIONS:
            unexpected.append(entry)
        elif path.stem in PATTERN_NAMES:
            found.setdefault(path.stem, []).append(entry)
        else:
            unexpected.append(entry)
    duplicates = {name: files for name, files in found.items() if len(files) > 1}
    if duplicates:
        name, files = next(iter(duplicates.items()))
        raise StackError(f"capture stack {label} holds pattern {name} more than once: {', '.join(sorted(files))}")
    missing = [name for name in PATTERN_NAMES if name not in found]
    problems = []
    if missing:
        problems.append(f"is missing pattern(s) {', '.join(missing)}")
    if unexpected:
        problems.append(f"holds unexpected file(s) {_list_names(sorted(unexpected))}")
    if problems:
        raise StackError(
            f"capture stack {label} {' and '.join(problems)}; a stack holds exactly GC_0..GC_6 and PS_0..PS_3 "
            f"as {'/'.join(IMAGE_EXTENSIONS)}"
        )
    return {name: files[0] for name, files in found.items()}


def _strip_single_folder(entries: list[str]) -> tuple[str, list[str]]:
    """If every entry lies in one top-level folder (and none at top level), drop that folder."""
    tops = {entry.split("/", 1)[0] for entry in entries}
    if len(tops) == 1 and all("/" in entry for entry in entries):
        top = tops.pop()
        inner = [entry.split("/", 1)[1] for entry in entries]
        inner = [entry for entry in inner if entry]
        if inner:
            return top + "/", inner
    return "", entries


def _check_member_name(label: str, name: str) -> None:
    normal = name.replace("\\", "/")
    parts = normal.split("/")
    if normal.startswith("/") or (len(normal) > 1 and normal[1] == ":") or ".." in parts:
        raise StackError(f"capture stack {label} holds an unsafe member name {name!r} (absolute path or '..')")


def _read_zip(
    label: str,
    archive: zipfile.ZipFile,
    *,
    max_bytes: int,
    max_ratio: float,
) -> dict[str, tuple[str, bytes]]:
    """Pattern name -> (member name, bytes) of a stack zip, checked before decompression."""
    infos = archive.infolist()
    if len(infos) > MAX_ARCHIVE_MEMBERS:
        raise StackError(f"capture stack {label} holds {len(infos)} entries, more than {MAX_ARCHIVE_MEMBERS}")
    for info in infos:
        _check_member_name(label, info.filename)
    files = [info for info in infos if not info.is_dir() and not _is_junk(info.filename)]
    total = sum(info.file_size for info in files)
    if total > max_bytes:
        raise StackError(
            f"capture stack {label} expands to {total} bytes, more than the limit of {max_bytes} bytes; "
            "refused before decompressing"
        )
    for info in files:
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > 2**20 and ratio > max_ratio:
            raise StackError(
                f"capture stack {label} member {info.filename} claims a compression ratio of {ratio:.0f}:1, "
                f"more than the limit of {max_ratio:.0f}:1; refused before decompressing"
            )
    names = [info.filename for info in files]
    if len(set(names)) != len(names):
        dup = next(name for name in names if names.count(name) > 1)
        raise StackError(f"capture stack {label} holds member {dup} more than once")
    prefix, entries = _strip_single_folder(names)
    matched = _match_patterns(label, entries)
    result: dict[str, tuple[str, bytes]] = {}
    for pattern, entry in matched.items():
        member = prefix + entry
        info = archive.getinfo(member)
        try:
            with archive.open(info) as fh:
                data = fh.read(info.file_size + 1)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
            raise StackError(f"capture stack {label} member {member} is corrupt ({exc})") from None
        except (RuntimeError, NotImplementedError) as exc:  # encrypted, unsupported method
            raise StackError(f"capture stack {label} member {member} cannot be read ({exc})") from None
        if len(data) > info.file_size:
            raise StackError(f"capture stack {label} member {member} is larger than its declared size")
        result[pattern] = (member, data)
    return result


def _read_folder(label: str, folder: Path, *, max_bytes: int) -> dict[str, tuple[str, bytes]]:
    def listing(where: Path, prefix: str) -> list[str]:
        entries = []
        for child in sorted(where.iterdir()):
            rel = prefix + child.name
            if _is_junk(rel):
                continue
            entries.append(rel + "/" if child.is_dir() else rel)
        return entries

    entries = listing(folder, "")
    root = folder
    if len(entries) == 1 and entries[0].endswith("/"):
        root = folder / entries[0].rstrip("/")
        entries = listing(root, "")
    matched = _match_patterns(label, entries)
    sizes = {pattern: (root / entry).stat().st_size for pattern, entry in matched.items()}
    total = sum(sizes.values())
    if total > max_bytes:
        raise StackError(f"capture stack {label} holds {total} bytes of images, more than the limit of {max_bytes}")
    result: dict[str, tuple[str, bytes]] = {}
    for pattern, entry in matched.items():
        path = root / entry
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise StackError(f"capture stack {label}: cannot read {entry} ({exc.strerror or exc})") from None
        result[pattern] = (str(path.relative_to(folder)), data)
    return result


def read_stack(
    source: str | os.PathLike[str] | IO[bytes],
    *,
    rig: Rig | None = None,
    expected_bit_depth: int | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> CaptureStack:
    """Read and validate a capture stack (DESIGN.md 1.3).

    Parameters
    ----------
    source : path or binary file object
        A folder, a ``.zip`` file, or a readable binary file object holding a zip
        (an upload). A file object's ``name`` attribute, if any, labels messages.
    rig : Rig, optional
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


@contextlib.contextmanager
def _open_zip(label: str, source: Path | IO[bytes]) -> Iterator[zipfile.ZipFile]:
    try:
        archive = zipfile.ZipFile(source)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise StackError(f"capture stack {label} is not a zip file ({exc})") from None
    with archive:
        yield archive


def _decode_stack(
    label: str,
    files: Mapping[str, tuple[str, bytes]],
    *,
    rig: Rig | None,
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

    # 2. decode in parallel (cv2.imdecode releases the GIL); the first error in pattern order wins
    def decode(index: int) -> np.ndarray | StackError:
        try:
            return decode_grey_image(files[PATTERN_NAMES[index]][1], names[index], max_pixels=max_pixels)
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
            images = np.empty((len(PATTERN_NAMES), *image.shape), dtype=image.dtype)
        elif depth != first_depth[1]:
            raise StackError(
                f"{name} is {depth}-bit but {first_depth[0]} is {first_depth[1]}-bit; a stack has one bit depth"
            )
        assert images is not None
        images[index] = image
    assert images is not None and first_depth is not None and first_shape is not None
    return CaptureStack(images=images, bit_depth=first_depth[1], shape=first_shape[1])


# ---------------------------------------------------------------------------- writing stacks


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
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image))
        if not ok:
            raise OSError(f"OpenCV could not encode {pattern}{ext}")
        encoded[pattern + ext] = buf.tobytes()
    return encoded


def write_stack(images: CaptureStack | npt.ArrayLike, dest: str | os.PathLike[str], *, ext: str = ".png") -> Path:
    """Write a capture stack as a folder or a .zip (DESIGN.md 1.3).

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
        target.parent.mkdir(parents=True, exist_ok=True)
        method = zipfile.ZIP_STORED if ext.lower() == ".png" else zipfile.ZIP_DEFLATED
        with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", compression=method) as archive:
            for name, data in encoded.items():
                archive.writestr(name, data)
        return target
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
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
    tmp_dir.mkdir()
    try:
        for name, data in encoded.items():
            (tmp_dir / name).write_bytes(data)
        os.rename(tmp_dir, target)
    finally:
        if tmp_dir.exists():
            shutil.rmtree(tmp_dir)
    return target


# ---------------------------------------------------------------------------- rigs and heights


def read_rig(path: str | os.PathLike[str]) -> Rig:
    """Read a rig file (DESIGN.md 1.2).

    Raises
    ------
    RigError
        With the file name, if the file is missing, unreadable, not JSON, lacks a
        required key or holds a value out of range.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(f"rig file {path.name!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RigError(f"rig file {path.name!r} cannot be read ({exc})") from None
    try:
        return Rig.from_json(text)
    except RigError as exc:
        raise RigError(f"rig file {path.name!r}: {exc}") from None


def write_rig(rig: Rig, path: str | os.PathLike[str]) -> None:
    """Write ``rig`` as a rig file (JSON, the seven keys then the extra ones), atomically."""
    text = json.dumps(rig.to_dict(), indent=2, allow_nan=False) + "\n"
    _write_bytes_atomic(path, text.encode("utf-8"))


def _as_height_map(z_mm: npt.ArrayLike) -> np.ndarray:
    z = np.asarray(z_mm)
    if z.ndim != 2 or 0 in z.shape:
        raise ValueError(f"z_mm must be a non-empty (H, W) array, got shape {z.shape}")
    if z.dtype.kind not in "fiu":
        raise ValueError(f"z_mm must be numeric, got dtype {z.dtype}")
    return np.ascontiguousarray(z, dtype=np.float32)


def write_height_npy(z_mm: npt.ArrayLike, path: str | os.PathLike[str]) -> None:
    """Write a height map as a float32 ``.npy`` file, atomically (DESIGN.md 1.5).

    Parameters
    ----------
    z_mm : (H, W) array_like of float
        Heights above R, mm, NaN where not measured; stored as float32.
    path : path
        Destination file (conventionally ending in ``.npy``; used verbatim).
    """
    z = _as_height_map(z_mm)
    buffer = io.BytesIO()
    np.save(buffer, z, allow_pickle=False)
    _write_bytes_atomic(path, buffer.getvalue())


def read_height_npy(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a height map written by :func:`write_height_npy`: ``(H, W)`` float32, mm, NaN where invalid."""
    z = np.load(Path(path), allow_pickle=False)
    if not isinstance(z, np.ndarray) or z.ndim != 2 or z.dtype.kind != "f":
        raise ValueError(f"{Path(path).name} is not a (H, W) float height map")
    return z.astype(np.float32, copy=False)


def write_height_tiff(z_mm: npt.ArrayLike, path: str | os.PathLike[str]) -> None:
    """Write a height map as a single-channel float32 TIFF (NaN kept), atomically.

    Parameters
    ----------
    z_mm : (H, W) array_like of float
        Heights above R, mm, NaN where not measured; stored as float32.
    path : path
        Destination file; the format is TIFF whatever the extension.
    """
    z = _as_height_map(z_mm)
    ok, buf = cv2.imencode(".tiff", z)
    if not ok:
        raise OSError("OpenCV could not encode the height map as TIFF")
    _write_bytes_atomic(path, buf.tobytes())


# ---------------------------------------------------------------------------- stage series


@dataclass(frozen=True)
class StagePosition:
    """One stage position of a characterization series.

    Parameters
    ----------
    z_in_mm : float
        Stage height of the plane above R, mm.
    captures : tuple of Path
        The capture stacks (folders or zips) taken at this position, one per repeat.
    """

    z_in_mm: float
    captures: tuple[Path, ...]


@dataclass(frozen=True)
class StageSeries:
    """A characterization series (SERIES.json, DESIGN.md 1.6), positions in file order."""

    positions: tuple[StagePosition, ...]

    @property
    def z_in_mm(self) -> np.ndarray:
        """Stage heights: ``(n_positions,)`` float64, mm."""
        return np.array([position.z_in_mm for position in self.positions], dtype=np.float64)


def series_capture_name(z_in_mm: float, repeat: int) -> str:
    """Conventional relative path of a stage capture: ``z004/r00`` for 4 mm, repeat 0.

    Integral heights give ``zNNN``; others ``zNNNpFFF`` (4.5 mm -> ``z004p500``); negative
    heights start with ``zm``.

    Examples
    --------
    >>> series_capture_name(4.0, 0), series_capture_name(80, 29), series_capture_name(-2.25, 1)
    ('z004/r00', 'z080/r29', 'zm002p250/r01')
    """
    if not math.isfinite(z_in_mm) or repeat < 0:
        raise ValueError(f"z_in_mm must be finite and repeat >= 0, got {z_in_mm!r}, {repeat!r}")
    sign = "m" if z_in_mm < 0 else ""
    magnitude = abs(float(z_in_mm))
    z_part = f"{int(magnitude):03d}" if magnitude.is_integer() else f"{magnitude:07.3f}".replace(".", "p")
    return f"z{sign}{z_part}/r{repeat:02d}"


def _resolve_capture(base: Path, label: str, where: str, ref: str, check_exists: bool) -> Path:
    pure = PurePosixPath(ref.replace("\\", "/"))
    if pure.is_absolute() or (len(ref) > 1 and ref[1] == ":") or ".." in pure.parts:
        raise StackError(f"series {label} {where}: capture {ref!r} must be a relative path inside the series folder")
    path = base.joinpath(*pure.parts)
    if not check_exists:
        return path
    if path.exists():
        return path
    zipped = path.with_name(path.name + ".zip")
    if zipped.is_file():
        return zipped
    raise StackError(f"series {label} {where}: capture {ref!r} not found (neither a folder nor a .zip)")


def read_series(path: str | os.PathLike[str], *, check_exists: bool = True) -> StageSeries:
    """Read a stage series file (SERIES.json, DESIGN.md 1.6).

    The file is ``{"positions": [{"z_in_mm": 4.0, "captures": ["z004/r00", ...]}, ...]}``
    with capture paths relative to the file's folder, each a folder or a zip (given with or
    without ``.zip``). Other keys are allowed and ignored.

    Parameters
    ----------
    path : path
        The series file.
    check_exists : bool
        Require every capture to exist (and resolve ``name`` to ``name.zip`` when only
        the zip exists).

    Returns
    -------
    StageSeries
        Capture paths resolved against the file's folder.

    Raises
    ------
    StackError
        On a missing or unreadable file, invalid JSON, a wrong structure, a non-finite or
        repeated ``z_in_mm``, an empty or repeated capture list entry, an absolute or
        ``..`` capture path, or a capture that does not exist.
    """
    path = Path(path)
    label = repr(path.name)
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StackError(f"series file {label} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StackError(f"series file {label} cannot be read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise StackError(f"series file {label} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(data, dict) or not isinstance(data.get("positions"), list):
        raise StackError(f"series {label} must be a JSON object with a list 'positions'")
    if not data["positions"]:
        raise StackError(f"series {label} has no positions")
    base = path.parent
    positions: list[StagePosition] = []
    seen_z: set[float] = set()
    seen_captures: set[Path] = set()
    for number, item in enumerate(data["positions"]):
        where = f"position {number}"
        if not isinstance(item, dict):
            raise StackError(f"series {label} {where} must be an object with 'z_in_mm' and 'captures'")
        z = item.get("z_in_mm")
        if isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z):
            raise StackError(f"series {label} {where}: 'z_in_mm' must be a finite number, got {z!r}")
        z = float(z)
        if z in seen_z:
            raise StackError(f"series {label} {where}: z_in_mm {z} appears more than once")
        seen_z.add(z)
        where = f"position {number} (z_in_mm={z:g})"
        captures = item.get("captures")
        if not isinstance(captures, list) or not captures:
            raise StackError(f"series {label} {where}: 'captures' must be a non-empty list of paths")
        resolved = []
        for ref in captures:
            if not isinstance(ref, str) or not ref.strip():
                raise StackError(f"series {label} {where}: capture {ref!r} must be a non-empty path string")
            capture = _resolve_capture(base, label, where, ref, check_exists)
            if capture in seen_captures:
                raise StackError(f"series {label} {where}: capture {ref!r} is listed more than once")
            seen_captures.add(capture)
            resolved.append(capture)
        positions.append(StagePosition(z_in_mm=z, captures=tuple(resolved)))
    return StageSeries(positions=tuple(positions))


def write_series(
    series: StageSeries | Mapping[float, Sequence[str | os.PathLike[str]]],
    path: str | os.PathLike[str],
) -> None:
    """Write a stage series file (SERIES.json, DESIGN.md 1.6), atomically.

    Parameters
    ----------
    series : StageSeries or mapping
        Positions, or ``{z_in_mm: [capture, ...]}``. Captures are paths relative to the
        file's folder, or absolute paths inside it (written relative, '/'-separated).
    path : path
        Destination file.

    Raises
    ------
    ValueError
        If a capture lies outside the file's folder or a height is not finite.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "SERIES.json"
    >>> write_series({4.0: ["z004/r00", "z004/r01"]}, out)
    >>> read_series(out, check_exists=False).positions[0].z_in_mm
    4.0
    """
    path = Path(path)
    base = path.parent.resolve()
    items: list[tuple[float, Sequence[str | os.PathLike[str]]]]
    if isinstance(series, StageSeries):
        items = [(position.z_in_mm, position.captures) for position in series.positions]
    else:
        items = list(series.items())
    positions = []
    for z, captures in items:
        z = float(z)
        if not math.isfinite(z):
            raise ValueError(f"z_in_mm must be finite, got {z!r}")
        refs = []
        for capture in captures:
            capture_path = Path(capture)
            if capture_path.is_absolute():
                try:
                    capture_path = capture_path.resolve().relative_to(base)
                except ValueError:
                    raise ValueError(f"capture {str(capture)!r} lies outside the series folder {str(base)!r}") from None
            refs.append(capture_path.as_posix())
        positions.append({"z_in_mm": z, "captures": refs})
    text = json.dumps({"positions": positions}, indent=2) + "\n"
    _write_bytes_atomic(path, text.encode("utf-8"))


__all__ = [
    "DEFAULT_MAX_BYTES",
    "DEFAULT_MAX_PIXELS",
    "DEFAULT_MAX_RATIO",
    "IMAGE_EXTENSIONS",
    "JUNK_NAMES",
    "CaptureStack",
    "StackError",
    "StagePosition",
    "StageSeries",
    "atomic_path",
    "decode_grey_image",
    "encode_stack",
    "image_header_size",
    "read_height_npy",
    "read_rig",
    "read_series",
    "read_stack",
    "series_capture_name",
    "write_height_npy",
    "write_height_tiff",
    "write_rig",
    "write_series",
    "write_stack",
]
