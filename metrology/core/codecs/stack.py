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

import contextlib
import fnmatch
import io
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO, TYPE_CHECKING, Any

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
from metrology.core.io.cameras import camera_folder, camera_folders
from metrology.core.io.exposures import EXPOSURES_FILE_NAME, Exposure, exposures_json, parse_exposures
from metrology.core.patterns import PATTERN_NAMES

if TYPE_CHECKING:
    import zipfile  # imported where a zip is read (_open_source)

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


@dataclass(frozen=True, eq=False)
class ExposureStack:
    """The images of a multi-exposure capture (docs/exposures.md), the input of
    :func:`metrology.core.codecs.exposures.decode_exposures` and of every measurement.

    Attributes
    ----------
    images : tuple of (frames, H, W) uint8 or uint16 arrays
        One stack per exposure in the codec's frame order, all of one shape and dtype, in the
        order of ``exposures``.
    exposures : tuple of Exposure
        From the least to the most exposed (:func:`~metrology.core.io.exposures.parse_exposures`);
        index ``i`` is exposure ``i`` of the maps ``exposure_u`` / ``exposure_v``.

    Raises
    ------
    ValueError
        On no exposure, a count mismatch, or stacks of different shapes or dtypes.
    """

    images: tuple[np.ndarray, ...]
    exposures: tuple[Exposure, ...]

    def __post_init__(self) -> None:
        if not self.images or len(self.images) != len(self.exposures):
            raise ValueError(f"{len(self.exposures)} exposures but {len(self.images)} stacks")
        first = self.images[0]
        for exposure, images in zip(self.exposures, self.images, strict=True):
            if not isinstance(images, np.ndarray) or images.ndim != 3:
                raise ValueError(f"exposure {exposure.name!r}: images must be a (frames, H, W) array")
            if images.shape != first.shape or images.dtype != first.dtype:
                raise ValueError(
                    f"exposure {exposure.name!r} has images {images.shape} {images.dtype}, unlike "
                    f"{self.exposures[0].name!r}'s {first.shape} {first.dtype}"
                )

    @property
    def dtype(self) -> np.dtype[Any]:
        return self.images[0].dtype

    @property
    def frame_shape(self) -> tuple[int, int]:
        """``(H, W)`` of every frame."""
        return (int(self.images[0].shape[1]), int(self.images[0].shape[2]))

    @classmethod
    def single(cls, images: npt.ArrayLike) -> ExposureStack:
        """One stack as a one-exposure capture (exposure time 1 us, a label only)."""
        return cls((np.asarray(images),), (Exposure(name="exp0", exposure_us=1.0),))


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
        sub: Callable[[str], _Source | None] | None = None,
    ):
        self.label = label
        self.names = names
        self.read = read
        self.size = size
        self.nested_codecs = nested_codecs or []
        self.sub = sub  # the source of a sub-folder (None when absent): multi-exposure captures


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

    def sub(name: str) -> _Source | None:
        folder = root / name
        if not folder.is_dir():
            return None
        names = sorted(child.name for child in folder.iterdir() if child.is_file() and not is_junk(child.name))

        def read_sub(member: str) -> bytes:
            return read(f"{name}/{member}")

        return _Source(
            f"{label}/{name}",
            names,
            read_sub,
            lambda member: (folder / member).stat().st_size,
            sub=lambda inner: sub(f"{name}/{inner}"),  # cam0/exp0/: a camera's exposures
        )

    return _Source(label, files, read, lambda name: (root / name).stat().st_size, nested, sub)


def _zip_source(label: str, archive: zipfile.ZipFile, max_bytes: int, max_ratio: float) -> _Source:
    files = checked_zip_members(archive, label, max_bytes=max_bytes, max_ratio=max_ratio)
    prefix, entries = strip_single_folder([info.filename for info in files])
    top = [e for e in entries if "/" not in e]

    def read(name: str) -> bytes:
        return read_zip_member(archive, prefix + name, label)

    def size(name: str) -> int:
        return archive.getinfo(prefix + name).file_size

    def sub(name: str) -> _Source | None:
        head = name + "/"
        if not any(e.startswith(head) for e in entries):
            return None
        inner = sorted(e[len(head) :] for e in entries if e.startswith(head) and "/" not in e[len(head) :])

        def read_sub(member: str) -> bytes:
            return read(head + member)

        def size_sub(member: str) -> int:
            return size(head + member)

        return _Source(f"{label}/{name}", inner, read_sub, size_sub, sub=lambda deeper: sub(f"{name}/{deeper}"))

    return _Source(label, sorted(top), read, size, _nested_codec_files(entries), sub)


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


@contextlib.contextmanager
def _open_source(
    source: str | os.PathLike[str] | IO[bytes], max_bytes: int, max_ratio: float, *, rewind: bool = False
) -> Iterator[_Source]:
    """The files of a capture folder, zip or zip file object (rewound after reading when ``rewind``)."""
    if isinstance(source, (str, os.PathLike)) and Path(source).is_dir():
        path = Path(source)
        yield _folder_source(repr(path.name or str(path)), path)
        return
    import zipfile  # here, past a folder's return: reading a folder (gcps measure's start-up) does without it

    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label = repr(path.name or str(path))
        if not path.is_file():
            raise StackError(f"capture {label} does not exist")
        if path.stat().st_size > max_bytes:
            raise StackError(f"capture {label} is larger than the limit of {max_bytes} bytes")
        if not zipfile.is_zipfile(path):
            raise StackError(f"capture {label} is not a zip file (nor a folder)")
        with zipfile.ZipFile(path) as archive:
            yield _zip_source(label, archive, max_bytes, max_ratio)
        return
    name = getattr(source, "name", None)
    label = repr(Path(name).name) if isinstance(name, str) and name else "upload"
    start = source.tell() if rewind else 0
    data = source.read(max_bytes + 1)
    if rewind:
        source.seek(start)
    if len(data) > max_bytes:
        raise StackError(f"capture {label} is larger than the limit of {max_bytes} bytes")
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise StackError(f"capture {label} is not a zip file ({exc})") from None
    with archive:
        yield _zip_source(label, archive, max_bytes, max_ratio)


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
        images, mixed shapes or bit depths, unsafe or oversized zips, a multi-exposure capture
        (read by :func:`read_exposure_stack`).
    CodecError
        If the capture's ``codec.json`` is invalid.
    """
    with _open_source(source, max_bytes, max_ratio) as src:
        if EXPOSURES_FILE_NAME in src.names:
            raise StackError(
                f"capture {src.label} is a multi-exposure capture ({EXPOSURES_FILE_NAME}); read it as one "
                "(docs/exposures.md)"
            )
        return _read(src, codec, max_pixels)


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
    with _open_source(source, max_bytes, max_ratio, rewind=True) as src:
        return _own_codec(src)


def is_exposure_capture(
    source: str | os.PathLike[str] | IO[bytes],
    *,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> bool:
    """True when the capture holds ``exposures.json`` at its top (a multi-exposure capture,
    docs/exposures.md). A file object is rewound. StackError as :func:`read_codec_stack`."""
    with _open_source(source, max_bytes, max_ratio, rewind=True) as src:
        return EXPOSURES_FILE_NAME in src.names


@dataclass(frozen=True, eq=False)
class ExposureCodecStack:
    """A multi-exposure capture read in codec order.

    Attributes
    ----------
    stack : ExposureStack
        One ``(frames, H, W)`` stack per exposure, least exposed first.
    codec : Codec
    codec_source : str
        As :attr:`CodecStack.codec_source`.
    """

    stack: ExposureStack
    codec: Codec
    codec_source: str

    @property
    def bit_depth(self) -> int:
        return 8 if self.stack.dtype == np.uint8 else 16


def read_exposure_stack(
    source: str | os.PathLike[str] | IO[bytes],
    codec: Codec | None = None,
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> ExposureCodecStack:
    """Read a multi-exposure capture (docs/exposures.md): ``exposures.json`` and one complete
    stack per exposure in its sub-folder, ``codec.json`` optionally at the top.

    Parameters
    ----------
    source : path or binary file object
        A folder, a ``.zip``, or a readable binary file object holding a zip.
    codec : Codec, optional
        Default the capture's top ``codec.json``, else gcps-v1 when the exposures hold the
        eleven named patterns.

    Raises
    ------
    StackError
        Naming the exposure and the file: no or a bad ``exposures.json``, an exposure's folder
        missing, a frame missing or unreadable, a ``codec.json`` inside an exposure's folder,
        exposures of different shapes or bit depths.
    CodecError
        If the top ``codec.json`` is invalid.
    """
    with _open_source(source, max_bytes, max_ratio) as src:
        label = src.label
        if EXPOSURES_FILE_NAME not in src.names:
            raise StackError(f"capture {label} has no {EXPOSURES_FILE_NAME}: it is not a multi-exposure capture")
        exposures = parse_exposures(src.read(EXPOSURES_FILE_NAME), label)
        _check_no_nested_codec(src)
        origin = "given"
        if codec is None:
            codec = _own_codec(src)
            origin = CODEC_FILE_NAME
        return _read_exposures(src, exposures, codec, origin, max_pixels)


def _read_exposures(
    src: _Source, exposures: tuple[Exposure, ...], codec: Codec | None, origin: str, max_pixels: int
) -> ExposureCodecStack:
    """The stacks of ``exposures`` in their sub-folders of ``src`` (a capture's top, or one camera's
    folder of a stereo capture); ``codec`` None: gcps-v1 by the names, else refused."""
    label = src.label
    assert src.sub is not None
    stacks: list[np.ndarray] = []
    first: tuple[str, np.ndarray] | None = None
    for exposure in exposures:
        sub = src.sub(exposure.name)
        if sub is None:
            raise StackError(
                f"capture {label} has no folder {exposure.name}/ for exposure {exposure.name!r} of "
                f"{EXPOSURES_FILE_NAME}"
            )
        if codec is None:  # no codec.json: gcps-v1 by the names, else refused
            read = _read(sub, None, max_pixels)
            codec, origin = read.codec, read.codec_source
        else:
            read = _read(sub, codec, max_pixels)
        images = read.images
        if first is not None and (images.shape != first[1].shape or images.dtype != first[1].dtype):
            raise StackError(
                f"capture {label}: exposure {exposure.name!r} has frames of shape {images.shape[1:]} "
                f"{images.dtype} but exposure {first[0]!r} has {first[1].shape[1:]} {first[1].dtype}"
            )
        if first is None:
            first = (exposure.name, images)
        stacks.append(images)
    assert codec is not None
    return ExposureCodecStack(ExposureStack(tuple(stacks), exposures), codec, origin)


def is_camera_capture(
    source: str | os.PathLike[str] | IO[bytes],
    *,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> bool:
    """True when the capture holds a ``cam0/`` sub-folder (a capture of several cameras,
    :mod:`metrology.core.io.cameras`). A file object is rewound. StackError as :func:`read_codec_stack`."""
    with _open_source(source, max_bytes, max_ratio, rewind=True) as src:
        assert src.sub is not None
        return src.sub(camera_folder(0)) is not None


@dataclass(frozen=True, eq=False)
class CameraCodecStacks:
    """A capture of several cameras read in codec order.

    Attributes
    ----------
    stacks : tuple of (frames, H_c, W_c) arrays, or of ExposureStack
        One stack per camera, camera 0 first; for a multi-exposure capture (``exposures.json`` at
        the top) each camera's :class:`ExposureStack`, the same exposures for every camera.
    codec : Codec
    codec_source : str
        As :attr:`CodecStack.codec_source`.
    """

    stacks: tuple[np.ndarray | ExposureStack, ...]
    codec: Codec
    codec_source: str

    @property
    def bit_depth(self) -> int:
        """8 or 16: the cameras' frames share one bit depth (checked when read)."""
        return 8 if self.stacks[0].dtype == np.uint8 else 16

    @property
    def exposures(self) -> tuple[Exposure, ...] | None:
        """The exposures of a multi-exposure capture (every camera's, least exposed first), None
        for a capture of single stacks."""
        first = self.stacks[0]
        return first.exposures if isinstance(first, ExposureStack) else None

    @property
    def frame_shapes(self) -> tuple[tuple[int, int], ...]:
        """``(H_c, W_c)`` of each camera's frames, camera 0 first."""
        return tuple(
            stack.frame_shape if isinstance(stack, ExposureStack) else (int(stack.shape[1]), int(stack.shape[2]))
            for stack in self.stacks
        )


def read_camera_stacks(
    source: str | os.PathLike[str] | IO[bytes],
    codec: Codec | None = None,
    cameras: int = 2,
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_ratio: float = DEFAULT_MAX_RATIO,
) -> CameraCodecStacks:
    """Read a capture of ``cameras`` cameras (:mod:`metrology.core.io.cameras`): ``cam0/``,
    ``cam1/`` ... each a complete stack of the codec's frames, ``codec.json`` optionally at the top;
    or, with ``exposures.json`` at the top (docs/exposures.md, "Stereo rigs"), each camera's folder
    holding one sub-folder per exposure (``cam0/exp0/``, ``cam0/exp1/`` ..., ``cam1/exp0/`` ...),
    one manifest for every camera.

    Parameters
    ----------
    source : path or binary file object
        A folder, a ``.zip``, or a readable binary file object holding a zip.
    codec : Codec, optional
        Default the capture's top ``codec.json``, else gcps-v1 when the cameras hold the eleven
        named patterns.
    cameras : int
        How many cameras the rig has.

    Raises
    ------
    StackError
        Naming the camera and the file: a camera's folder missing, a frame missing or unreadable
        (the codec's frame count), a ``codec.json`` inside a camera's folder, the cameras' bit
        depths differing; for a multi-exposure capture also a bad ``exposures.json`` or an
        exposure's folder missing in a camera (naming both).
    CodecError
        If the top ``codec.json`` is invalid.
    """
    with _open_source(source, max_bytes, max_ratio) as src:
        label = src.label
        _check_no_nested_codec(src)
        origin = "given"
        if codec is None:
            codec = _own_codec(src)
            origin = CODEC_FILE_NAME
        exposures = None
        if EXPOSURES_FILE_NAME in src.names:
            exposures = parse_exposures(src.read(EXPOSURES_FILE_NAME), label)
        assert src.sub is not None
        stacks: list[np.ndarray | ExposureStack] = []
        for index, folder in enumerate(camera_folders(cameras)):
            sub = src.sub(folder)
            if sub is None:
                raise StackError(
                    f"capture {label} has no folder {folder}/ for camera {index} (a rig of {cameras} cameras: "
                    f"{', '.join(f + '/' for f in camera_folders(cameras))})"
                )
            read: CodecStack | ExposureCodecStack
            try:
                read = (
                    _read(sub, codec, max_pixels)
                    if exposures is None
                    else _read_exposures(sub, exposures, codec, origin, max_pixels)
                )
            except StackError as exc:
                raise StackError(f"camera {index}: {exc}") from None
            if codec is None:
                codec, origin = read.codec, read.codec_source
            images = read.images if isinstance(read, CodecStack) else read.stack
            if stacks and images.dtype != stacks[0].dtype:
                raise StackError(
                    f"capture {label}: camera {index}'s frames are {8 * images.dtype.itemsize}-bit but camera "
                    f"0's are {8 * stacks[0].dtype.itemsize}-bit"
                )
            stacks.append(images)
    assert codec is not None
    return CameraCodecStacks(tuple(stacks), codec, origin)


def write_camera_stacks(
    stacks: Sequence[npt.ArrayLike | ExposureStack], dest: str | os.PathLike[str], codec: Codec | None = None
) -> Path:
    """Write one stack per camera as ``cam0/``, ``cam1/`` ... of a new folder or ``.zip`` (atomic; the
    eleven named images of gcps-v1 when ``codec`` is None or gcps-v1, else the codec's frames and its
    ``codec.json`` at the top). :class:`ExposureStack` s (every camera's, of the same exposures) are
    written as ``cam0/exp0/`` ... with one ``exposures.json`` at the top. Reads back with
    :func:`read_camera_stacks`.

    Raises
    ------
    ValueError
        When a stack does not have one image per frame, the folder exists, or the cameras' stacks
        mix single and multi-exposure ones or differ in their exposures.
    """
    files: dict[str, bytes] = {}
    multi = [isinstance(stack, ExposureStack) for stack in stacks]
    if any(multi):
        first = stacks[0]
        if not all(multi) or any(s.exposures != first.exposures for s in stacks):  # type: ignore[union-attr]
            raise ValueError("a multi-exposure capture of several cameras has the same exposures for every camera")
        assert isinstance(first, ExposureStack)
        files[EXPOSURES_FILE_NAME] = exposures_json(first.exposures).encode()
    for folder, stack in zip(camera_folders(len(stacks)), stacks, strict=True):
        if isinstance(stack, ExposureStack):
            for exposure, images in zip(stack.exposures, stack.images, strict=True):
                own = _stack_files(codec, images)
                files.update({f"{folder}/{exposure.name}/{name}": data for name, data in own.items()})
        else:
            files.update({f"{folder}/{name}": data for name, data in _stack_files(codec, np.asarray(stack)).items()})
    return _write_new(_with_codec_file(files, codec), dest)


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


__all__ = [
    "CODEC_FILE_NAME",
    "CameraCodecStacks",
    "CodecError",
    "CodecStack",
    "ExposureCodecStack",
    "ExposureStack",
    "is_camera_capture",
    "is_exposure_capture",
    "read_camera_stacks",
    "read_capture_codec",
    "read_codec_stack",
    "read_exposure_stack",
    "select_frames",
    "write_camera_stacks",
    "write_exposure_stack",
]


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


def _write_new(files: dict[str, bytes], dest: str | os.PathLike[str]) -> Path:
    """Write ``files`` as a new folder or a .zip (atomic); ValueError when the folder exists."""
    target = Path(dest)
    if target.suffix.lower() == ".zip":
        return write_files_zip_atomic(files, target)
    if target.exists():
        raise ValueError(f"{dest}: already exists; give a new folder or a .zip")
    return write_files_new_folder_atomic(files, target)


def _frame_files(codec: Codec, images: np.ndarray) -> dict[str, bytes]:
    """File name -> encoded bytes of each frame of ``codec``."""
    import cv2

    from metrology.core.io.images import encode_params

    files: dict[str, bytes] = {}
    for name, image in zip(frame_file_names(codec), images, strict=True):
        ext = PurePosixPath(name).suffix.lower()
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image), encode_params(ext))
        if not ok:
            raise OSError(f"OpenCV could not encode {name}")
        files[name] = buf.tobytes()
    return files


def write_exposure_stack(stack: ExposureStack, dest: str | os.PathLike[str], codec: Codec | None = None) -> Path:
    """Write a multi-exposure capture as a new folder or a .zip (atomic): ``exposures.json``, one
    sub-folder per exposure (the eleven named images of gcps-v1 when ``codec`` is None or gcps-v1,
    else the codec's frames) and, for another codec, its ``codec.json`` at the top. Reads back with
    :func:`read_exposure_stack`.

    Raises
    ------
    ValueError
        When a stack does not have one image per frame, or the folder exists.
    """
    files: dict[str, bytes] = {EXPOSURES_FILE_NAME: exposures_json(stack.exposures).encode()}
    for exposure, images in zip(stack.exposures, stack.images, strict=True):
        files.update({f"{exposure.name}/{name}": data for name, data in _stack_files(codec, images).items()})
    return _write_new(_with_codec_file(files, codec), dest)


def _stack_files(codec: Codec | None, images: np.ndarray) -> dict[str, bytes]:
    """One stack's files: the eleven named images of gcps-v1 (``codec`` None or gcps-v1), else the
    codec's frames (ValueError unless there is one image per frame)."""
    from metrology.core.codecs.model import is_gcps_v1
    from metrology.core.io import encode_stack

    if is_gcps_v1(codec):
        return encode_stack(images)
    assert codec is not None
    if len(images) != codec.n_frames:
        raise ValueError(f"the codec has {codec.n_frames} frames, got images of shape {images.shape}")
    return _frame_files(codec, images)


def _with_codec_file(files: dict[str, bytes], codec: Codec | None) -> dict[str, bytes]:
    """``files`` and, for a codec other than gcps-v1, its ``codec.json`` at the top."""
    from metrology.core.codecs.model import is_gcps_v1

    if not is_gcps_v1(codec):
        assert codec is not None
        files[CODEC_FILE_NAME] = codec.to_json().encode()
    return files


def write_codec_stack(codec: Codec, images: npt.ArrayLike, dest: str | os.PathLike[str]) -> Path:
    """Write ``(frames, H, W)`` images of ``codec`` (8- or 16-bit) named by :func:`frame_file_names`,
    with the codec as ``codec.json``, as a new folder or a .zip (atomic); the folder or zip reads
    back in codec order (:func:`read_codec_stack`).

    Raises
    ------
    ValueError
        When there is not one image per frame, or the folder exists.
    """
    images = np.asarray(images)
    if images.ndim != 3 or len(images) != codec.n_frames:
        raise ValueError(f"the codec has {codec.n_frames} frames, got images of shape {images.shape}")
    files = _frame_files(codec, images)
    files["codec.json"] = codec.to_json().encode()
    return _write_new(files, dest)


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


def write_cameras_capture(
    stacks: Sequence[npt.ArrayLike], dest: str | os.PathLike[str], codec: Codec | None = None
) -> Path:
    """Write the capture of a rig's cameras (one ``(frames, H_c, W_c)`` stack each, camera 0 first):
    a single camera's as :func:`write_capture`, several as ``cam0/``, ``cam1/`` ...
    (:func:`write_camera_stacks`)."""
    if len(stacks) == 1:
        return write_capture(stacks[0], dest, codec)
    return write_camera_stacks(stacks, dest, codec)
