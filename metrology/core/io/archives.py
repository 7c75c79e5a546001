"""Reading the files of a capture stack from a folder or a zip, with the zip-bomb and unsafe-name
checks made before anything is decompressed."""

from __future__ import annotations

import contextlib
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path, PurePosixPath
from typing import IO, TYPE_CHECKING

from metrology.core.io.errors import StackError
from metrology.core.patterns import PATTERN_NAMES

if TYPE_CHECKING:
    import zipfile  # imported where a zip is read: a folder's reading (gcps measure's start-up) does without it

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".tif", ".tiff", ".bmp")
"""Accepted image file extensions (compared case-insensitively)."""


JUNK_NAMES: frozenset[str] = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})
"""File names ignored in stacks, besides ``__MACOSX/`` and AppleDouble ``._*`` files."""


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


def is_junk(relpath: str) -> bool:
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


def strip_single_folder(entries: list[str]) -> tuple[str, list[str]]:
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


def checked_zip_members(
    archive: zipfile.ZipFile, label: str, *, max_bytes: int, max_ratio: float
) -> list[zipfile.ZipInfo]:
    """The file members of a capture zip, checked before anything is decompressed.

    Refused (:class:`StackError` naming the problem): more than ``MAX_ARCHIVE_MEMBERS`` entries,
    an absolute or ``..`` member name, more than ``max_bytes`` bytes once expanded, a member over
    1 MiB whose compression ratio exceeds ``max_ratio`` (a zip bomb), a member name twice.
    Folders and junk files (``__MACOSX/``, ``.DS_Store``...) are left out.
    """
    infos = archive.infolist()
    if len(infos) > MAX_ARCHIVE_MEMBERS:
        raise StackError(f"capture stack {label} holds {len(infos)} entries, more than {MAX_ARCHIVE_MEMBERS}")
    for info in infos:
        _check_member_name(label, info.filename)
    files = [info for info in infos if not info.is_dir() and not is_junk(info.filename)]
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
    return files


def read_zip_member(archive: zipfile.ZipFile, member: str, label: str) -> bytes:
    """The bytes of one member of a checked zip, refusing a corrupt, unreadable (encrypted,
    unsupported method) or larger-than-declared member with a :class:`StackError`."""
    import zipfile

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
    return data


def _read_zip(
    label: str,
    archive: zipfile.ZipFile,
    *,
    max_bytes: int,
    max_ratio: float,
) -> dict[str, tuple[str, bytes]]:
    """Pattern name -> (member name, bytes) of a stack zip, checked before decompression."""
    files = checked_zip_members(archive, label, max_bytes=max_bytes, max_ratio=max_ratio)
    prefix, entries = strip_single_folder([info.filename for info in files])
    matched = _match_patterns(label, entries)
    members = {pattern: prefix + entry for pattern, entry in matched.items()}
    return {pattern: (member, read_zip_member(archive, member, label)) for pattern, member in members.items()}


def _read_folder(label: str, folder: Path, *, max_bytes: int) -> dict[str, tuple[str, bytes]]:
    def listing(where: Path, prefix: str) -> list[str]:
        entries = []
        for child in sorted(where.iterdir()):
            rel = prefix + child.name
            if is_junk(rel):
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


@contextlib.contextmanager
def _open_zip(label: str, source: Path | IO[bytes]) -> Iterator[zipfile.ZipFile]:
    import zipfile

    try:
        archive = zipfile.ZipFile(source)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise StackError(f"capture stack {label} is not a zip file ({exc})") from None
    with archive:
        yield archive
