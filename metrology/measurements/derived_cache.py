"""A bounded cache of derived files (meshes, TIFF height maps) in a folder of the media storage.

A derived file is a pure function of stored results, so it can be deleted at any time and is
rebuilt on the next request. The cache holds at most ``max_bytes`` (``GCPS_MESH_CACHE_BYTES``):
after each insertion the least recently used files (modification time, refreshed on every hit)
are removed until the total fits. Files are written under a hidden temporary name in the cache
folder and renamed into place (``os.replace``), so two requests building the same missing file
never see or corrupt each other's partial output: the last rename wins and both are complete.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

STALE_TEMP_SECONDS = 3600.0
"""A temporary file older than this (a writer that died) is removed by :meth:`DerivedFileCache.evict`."""


class DerivedFileCache:
    """Files named ``name`` under ``root``, at most ``max_bytes`` in total, evicted least recently used first.

    Parameters
    ----------
    root : Path
        The cache folder (created on first write).
    max_bytes : int
        Largest total size of the cached files, bytes, >= 0 (0 keeps nothing once served).
    """

    def __init__(self, root: Path, max_bytes: int) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 0:
            raise ValueError(f"max_bytes must be a non-negative integer, got {max_bytes!r}")
        self.root = Path(root)
        self.max_bytes = max_bytes

    def _path(self, name: str) -> Path:
        if not name or "/" in name or "\\" in name or name.startswith("."):
            raise ValueError(f"cache name must be a plain file name, got {name!r}")
        return self.root / name

    def get(self, name: str) -> Path | None:
        """The cached file ``name`` (its use time refreshed), or None when it is not cached."""
        path = self._path(name)
        try:
            os.utime(path)
        except FileNotFoundError:
            return None
        return path

    def fill(self, name: str, chunks: Iterable[bytes]) -> Iterator[bytes]:
        """Pass ``chunks`` through while writing them to the cache as ``name``.

        The file appears under ``name`` only once the last chunk has been written (atomic rename);
        if the consumer stops early or a chunk raises, the temporary file is removed and nothing
        is cached. Then the cache is trimmed to ``max_bytes``.
        """
        final = self._path(name)
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f".{name}.{secrets.token_hex(6)}.tmp"
        try:
            with open(tmp, "wb") as out:
                for chunk in chunks:
                    out.write(chunk)
                    yield chunk
            os.replace(tmp, final)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        self.evict()

    @contextlib.contextmanager
    def store(self, name: str, suffix: str = "") -> Iterator[Path]:
        """Yield a temporary path (ending in ``suffix``) to write; on success it becomes ``name``.

        Then the cache is trimmed to ``max_bytes``.
        """
        final = self._path(name)
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f".{name}.{secrets.token_hex(6)}.tmp{suffix}"
        try:
            yield tmp
            os.replace(tmp, final)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        self.evict()

    def entries(self) -> list[tuple[float, int, Path]]:
        """(last use time, size in bytes, path) of every cached file, oldest use first."""
        found = []
        try:
            scan = list(os.scandir(self.root))
        except FileNotFoundError:
            return []
        for entry in scan:
            if entry.name.startswith(".") or not entry.is_file():
                continue
            with contextlib.suppress(FileNotFoundError):
                stat = entry.stat()
                found.append((stat.st_mtime, stat.st_size, Path(entry.path)))
        found.sort()
        return found

    def total_bytes(self) -> int:
        """Total size of the cached files, bytes."""
        return sum(size for _used, size, _path in self.entries())

    def evict(self) -> int:
        """Remove least recently used files until the total is at most ``max_bytes``; returns the bytes removed.

        Also removes temporary files older than :data:`STALE_TEMP_SECONDS` (left by a killed writer).
        """
        removed = 0
        entries = self.entries()
        total = sum(size for _used, size, _path in entries)
        for _used, size, path in entries:
            if total <= self.max_bytes:
                break
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += size
            total -= size
        now = time.time()
        with contextlib.suppress(FileNotFoundError):
            for entry in os.scandir(self.root):
                if entry.name.startswith(".") and ".tmp" in entry.name:
                    with contextlib.suppress(FileNotFoundError):
                        if now - entry.stat().st_mtime > STALE_TEMP_SECONDS:
                            os.unlink(entry.path)
        return removed

    def clear(self) -> None:
        """Remove every cached file (they are rebuilt on request)."""
        for _used, _size, path in self.entries():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
