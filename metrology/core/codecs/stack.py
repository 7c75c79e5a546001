"""Reading the frames of a capture folder or zip in a codec's frame order.

A capture of any codec is a folder or a ``.zip`` of image files (``.png .bmp .tif .tiff``,
8- or 16-bit, grey or colour converted to grey), possibly inside one single sub-folder,
possibly with its ``codec.json`` at its root (a ``codec.json`` in a sub-folder is refused, naming
it, when the capture's own codec is looked up). Which files are the frames, and in what order, the codec says:

* ``"frames": [names]``: exactly these files (a name without an image extension matches the
  file of that stem with any accepted extension); other files are ignored;
* ``"frames": N``: the image files matching the glob ``"files"`` (default: every image
  file), in natural order (:func:`~metrology.core.codecs.model.natural_key`); their count
  must be N.

Operating-system junk (``__MACOSX/``, ``._*``, ``.DS_Store``, ``Thumbs.db``, ``desktop.ini``)
is ignored. Zips are read in memory with the safety limits of :mod:`metrology.core.io`
(member names, total size, compression ratio), and every image header is checked for size
and shape before anything is decoded.
"""

from __future__ import annotations

import fnmatch
import io
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec, CodecError, builtin_codec, codec_from_json, natural_key
from metrology.core.io import (
    DEFAULT_MAX_BYTES,
    DEFAULT_MAX_PIXELS,
    DEFAULT_MAX_RATIO,
    IMAGE_EXTENSIONS,
    StackError,
    checked_header,
    decode_grey_image,
)
from metrology.core.io.archives import checked_zip_members, is_junk, read_zip_member, strip_single_folder
from metrology.core.io.atomic import write_files_new_folder_atomic, write_files_zip_atomic
from metrology.core.patterns import PATTERN_NAMES

CODEC_FILE_NAME = "codec.json"
"""Name of the codec file inside a capture folder or zip."""


@dataclass(frozen=True, eq=False)
class CodecStack:
    """The frames of a capture, in codec order.

    Attributes
    ----------
    images : (frames, H, W) uint8 or uint16 array
    codec : Codec
        The codec used (given, the capture's ``codec.json``, or gcps-v1 for a stack of the
        eleven named patterns).
    names : tuple of str
        The file of each frame (relative to the capture's root).
    codec_source : str
        ``"given"``, ``"codec.json"`` or ``"gcps-v1 names"``.
    """

    images: np.ndarray
    codec: Codec
    names: tuple[str, ...]
    codec_source: str

    @property
    def bit_depth(self) -> int:
        return 8 if self.images.dtype == np.uint8 else 16


class _Source:
    """Files of a folder or zip: top-level names, a reader of their bytes, and the paths of the
    ``codec.json`` files lying in sub-folders (refused: a capture's codec lies at its root)."""

    def __init__(
        self,
        label: str,
        names: list[str],
        read: Callable[[str], bytes],
        size: Callable[[str], int],
        nested_codecs: list[str] | None = None,
    ):
        self.label = label
        self.names = names
        self.read = read
        self.size = size
        self.nested_codecs = nested_codecs or []


def _nested_codec_files(entries: list[str]) -> list[str]:
    """The entries (relative paths) named ``codec.json`` that lie in a sub-folder."""
    return sorted(e for e in entries if "/" in e and PurePosixPath(e).name == CODEC_FILE_NAME)


def _check_no_nested_codec(src: _Source) -> None:
    """Refuse a capture holding a ``codec.json`` in a sub-folder: it would be silently ignored (or
    taken for the capture's codec when it is not), so the capture is refused, naming the file."""
    if src.nested_codecs:
        shown = ", ".join(src.nested_codecs[:3]) + (" ..." if len(src.nested_codecs) > 3 else "")
        raise StackError(
            f"capture {src.label} holds {CODEC_FILE_NAME} in a sub-folder ({shown}); a capture's "
            f"{CODEC_FILE_NAME} lies at its root, beside the frames"
        )


def _folder_source(label: str, folder: Path) -> _Source:
    entries = sorted(
        child.name + ("/" if child.is_dir() else "") for child in folder.iterdir() if not is_junk(child.name)
    )
    root = folder
    if len(entries) == 1 and entries[0].endswith("/"):
        root = folder / entries[0].rstrip("/")
        entries = sorted(
            child.name + ("/" if child.is_dir() else "") for child in root.iterdir() if not is_junk(child.name)
        )
    files = [e for e in entries if not e.endswith("/")]
    nested = _nested_codec_files(
        [path.relative_to(root).as_posix() for path in root.rglob(CODEC_FILE_NAME) if path.parent != root]
    )

    def read(name: str) -> bytes:
        try:
            return (root / name).read_bytes()
        except OSError as exc:
            raise StackError(f"capture {label}: cannot read {name} ({exc.strerror or exc})") from None

    return _Source(label, files, read, lambda name: (root / name).stat().st_size, nested)


def _zip_source(label: str, archive: zipfile.ZipFile, max_bytes: int, max_ratio: float) -> _Source:
    files = checked_zip_members(archive, label, max_bytes=max_bytes, max_ratio=max_ratio)
    prefix, entries = strip_single_folder([info.filename for info in files])
    top = [e for e in entries if "/" not in e]

    def read(name: str) -> bytes:
        return read_zip_member(archive, prefix + name, label)

    def size(name: str) -> int:
        return archive.getinfo(prefix + name).file_size

    return _Source(label, sorted(top), read, size, _nested_codec_files(entries))


def select_frames(codec: Codec, names: list[str], label: str = "capture") -> list[str]:
    """The file of each frame of ``codec`` among the capture's top-level file ``names``.

    Raises
    ------
    StackError
        If a named frame is missing (or ambiguous), or the number of matching image files
        differs from the codec's frame count (both named).
    """
    images = [n for n in names if PurePosixPath(n).suffix.lower() in IMAGE_EXTENSIONS]
    if isinstance(codec.frames, int):
        pattern = codec.files
        chosen = [n for n in images if pattern is None or fnmatch.fnmatchcase(n, pattern)]
        chosen.sort(key=natural_key)
        if len(chosen) != codec.frames:
            what = f"image files matching {pattern!r}" if pattern else "image files"
            shown = ", ".join(chosen[:6]) + (" ..." if len(chosen) > 6 else "")
            raise StackError(
                f"capture {label} holds {len(chosen)} {what} but the codec describes {codec.frames} frames"
                + (f" ({shown})" if chosen else "")
            )
        return chosen
    selected: list[str] = []
    missing: list[str] = []
    for name in codec.frames:
        if name in names:
            selected.append(name)
            continue
        if PurePosixPath(name).suffix.lower() not in IMAGE_EXTENSIONS:
            matches = [n for n in images if PurePosixPath(n).stem == name]
            if len(matches) == 1:
                selected.append(matches[0])
                continue
            if len(matches) > 1:
                raise StackError(f"capture {label} holds frame {name} more than once: {', '.join(matches)}")
        missing.append(name)
    if missing:
        shown = ", ".join(missing[:8]) + (f" and {len(missing) - 8} more" if len(missing) > 8 else "")
        raise StackError(f"capture {label} is missing frame file(s) {shown} of its codec")
    return selected


def read_codec_stack(
    source: str | os.PathLike[str] | IO[bytes],
    codec: Codec | None = None,
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> CodecStack:
    """Read the frames of a capture folder or zip (or a zip file object) in codec order.

    Parameters
    ----------
    source : path or binary file object
        A folder, a ``.zip``, or a readable binary file object holding a zip.
    codec : Codec, optional
        The codec; default the capture's ``codec.json``, else gcps-v1 when the capture holds
        the eleven named patterns GC_0..PS_3.

    Returns
    -------
    CodecStack

    Raises
    ------
    StackError
        Naming the problem: no codec, frames missing or miscounted, unreadable or oversized
        images, mixed shapes or bit depths, unsafe or oversized zips.
    CodecError
        If the capture's ``codec.json`` is invalid.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label = repr(path.name or str(path))
        if path.is_dir():
            return _read(_folder_source(label, path), codec, max_pixels)
        if not path.is_file():
            raise StackError(f"capture {label} does not exist")
        if path.stat().st_size > max_bytes:
            raise StackError(f"capture {label} is larger than the limit of {max_bytes} bytes")
        if not zipfile.is_zipfile(path):
            raise StackError(f"capture {label} is not a zip file (nor a folder)")
        with zipfile.ZipFile(path) as archive:
            return _read(_zip_source(label, archive, max_bytes, max_ratio), codec, max_pixels)
    name = getattr(source, "name", None)
    label = repr(Path(name).name) if isinstance(name, str) and name else "upload"
    data = source.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise StackError(f"capture {label} is larger than the limit of {max_bytes} bytes")
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise StackError(f"capture {label} is not a zip file ({exc})") from None
    with archive:
        return _read(_zip_source(label, archive, max_bytes, max_ratio), codec, max_pixels)


def read_capture_codec(
    source: str | os.PathLike[str] | IO[bytes],
    *,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> Codec | None:
    """The codec of a capture folder or zip's own ``codec.json`` (None when it has none), without
    decoding its images. A binary file object holding a zip is read and rewound to its start.

    Raises
    ------
    StackError
        If the capture does not exist, is not a folder nor a zip, or is unsafe.
    CodecError
        If its ``codec.json`` is invalid.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label = repr(path.name or str(path))
        if path.is_dir():
            return _own_codec(_folder_source(label, path))
        if not path.is_file():
            raise StackError(f"capture {label} does not exist")
        if not zipfile.is_zipfile(path):
            raise StackError(f"capture {label} is not a zip file (nor a folder)")
        with zipfile.ZipFile(path) as archive:
            return _own_codec(_zip_source(label, archive, max_bytes, max_ratio))
    name = getattr(source, "name", None)
    label = repr(Path(name).name) if isinstance(name, str) and name else "upload"
    start = source.tell()
    data = source.read(max_bytes + 1)
    source.seek(start)
    if len(data) > max_bytes:
        raise StackError(f"capture {label} is larger than the limit of {max_bytes} bytes")
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise StackError(f"capture {label} is not a zip file ({exc})") from None
    with archive:
        return _own_codec(_zip_source(label, archive, max_bytes, max_ratio))


def _own_codec(src: _Source) -> Codec | None:
    _check_no_nested_codec(src)
    if CODEC_FILE_NAME not in src.names:
        return None
    return codec_from_json(src.read(CODEC_FILE_NAME), label=f"capture {src.label} {CODEC_FILE_NAME}")


def _read(src: _Source, codec: Codec | None, max_pixels: int) -> CodecStack:
    label = src.label
    origin = "given"
    if codec is None:
        _check_no_nested_codec(src)
        if CODEC_FILE_NAME in src.names:
            codec = codec_from_json(src.read(CODEC_FILE_NAME), label=f"capture {label} {CODEC_FILE_NAME}")
            origin = CODEC_FILE_NAME
        else:
            stems = {PurePosixPath(n).stem for n in src.names if PurePosixPath(n).suffix.lower() in IMAGE_EXTENSIONS}
            if set(PATTERN_NAMES) <= stems:
                codec = builtin_codec("gcps-v1")
                origin = "gcps-v1 names"
            else:
                raise StackError(
                    f"capture {label} has no {CODEC_FILE_NAME} and is not a gcps-v1 stack (GC_0..PS_3): "
                    "give its codec (--codec FILE)"
                )
    names = select_frames(codec, src.names, label)
    blobs = [src.read(n) for n in names]
    first: tuple[str, tuple[int, int]] | None = None
    for n, data in zip(names, blobs, strict=True):
        _, width, height = checked_header(data, f"{label}/{n}", max_pixels=max_pixels)
        if first is None:
            first = (n, (height, width))
        elif (height, width) != first[1]:
            raise StackError(
                f"{label}/{n} has shape {(height, width)} but {first[0]} has shape {first[1]} (height, width)"
            )
    assert first is not None
    images: np.ndarray | None = None
    for index, (n, data) in enumerate(zip(names, blobs, strict=True)):
        image = decode_grey_image(data, f"{label}/{n}", max_pixels=max_pixels)
        if images is None:
            images = np.empty((len(names), *image.shape), image.dtype)
        elif image.dtype != images.dtype:
            raise StackError(
                f"{label}/{n} is {8 * image.dtype.itemsize}-bit but {names[0]} is {8 * images.dtype.itemsize}-bit; "
                "a capture has one bit depth"
            )
        images[index] = image
    assert images is not None
    return CodecStack(images=images, codec=codec, names=tuple(names), codec_source=origin)


__all__ = ["CODEC_FILE_NAME", "CodecError", "CodecStack", "read_capture_codec", "read_codec_stack", "select_frames"]


def frame_file_names(codec: Codec) -> list[str]:
    """File name of each frame of ``codec``, in frame order: the codec's file names (``.png``
    added where they have no extension), else ``NN.png``; a ``prefix*suffix`` glob of ``files``
    gives ``prefixNNsuffix``."""
    n = codec.n_frames
    if not isinstance(codec.frames, int):
        return [name if PurePosixPath(name).suffix else f"{name}.png" for name in codec.frames]
    digits = max(2, len(str(n - 1)))
    prefix, suffix = "", ".png"
    if codec.files and codec.files.count("*") == 1 and not any(ch in codec.files for ch in "?[]"):
        head, tail = codec.files.split("*")
        if tail.lower().endswith((".png", ".tif", ".tiff", ".bmp")) and "/" not in tail:
            prefix, suffix = head, tail
    return [f"{prefix}{i:0{digits}d}{suffix}" for i in range(n)]


def write_codec_stack(codec: Codec, images: npt.ArrayLike, dest: str | os.PathLike[str]) -> Path:
    """Write ``(frames, H, W)`` images of ``codec`` (8- or 16-bit) named by :func:`frame_file_names`,
    with the codec as ``codec.json``, as a new folder or a .zip (atomic); the folder or zip reads
    back in codec order (:func:`read_codec_stack`).

    Raises
    ------
    ValueError
        When there is not one image per frame, or the folder exists.
    """
    import cv2

    images = np.asarray(images)
    if images.ndim != 3 or len(images) != codec.n_frames:
        raise ValueError(f"the codec has {codec.n_frames} frames, got images of shape {images.shape}")
    files: dict[str, bytes] = {}
    for name, image in zip(frame_file_names(codec), images, strict=True):
        ext = PurePosixPath(name).suffix.lower()
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image))
        if not ok:
            raise OSError(f"OpenCV could not encode {name}")
        files[name] = buf.tobytes()
    files["codec.json"] = codec.to_json().encode()
    target = Path(dest)
    if target.suffix.lower() == ".zip":
        return write_files_zip_atomic(files, target)
    if target.exists():
        raise ValueError(f"{dest}: already exists; give a new folder or a .zip")
    return write_files_new_folder_atomic(files, target)


def write_capture(images: npt.ArrayLike, dest: str | os.PathLike[str], codec: Codec | None = None) -> Path:
    """Write a capture stack as a new folder or a .zip (atomic): the eleven named images of gcps-v1
    (``codec`` None or gcps-v1, :func:`metrology.core.io.write_stack`), else the codec's frames and
    its ``codec.json`` (:func:`write_codec_stack`)."""
    from metrology.core.codecs.model import is_gcps_v1
    from metrology.core.io import write_stack

    if is_gcps_v1(codec):
        return write_stack(images, dest)
    assert codec is not None
    return write_codec_stack(codec, images, dest)
