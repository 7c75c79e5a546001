"""A bounded folder of derived files (meshes, TIFF height maps) in a Django storage.

A derived file is a pure function of stored results, so it can be deleted at any time and is
built again by a job the next time it is asked for. The folder holds at most ``max_bytes``
(``GCPS_MESH_CACHE_BYTES``): after each file is stored the oldest files (by the storage's
modification time, which every backend has, a local folder as an S3 bucket) are removed until
the total fits, except the file just stored. Only the storage API is used (``listdir``,
``size``, ``get_modified_time``, ``delete``): no local path.
"""

from __future__ import annotations

import contextlib
from datetime import datetime

from django.core.files.storage import Storage


class DerivedFiles:
    """The files of ``storage`` under ``prefix``, at most ``max_bytes`` in total, oldest removed first.

    Parameters
    ----------
    storage : Storage
        Where the files live (the default storage).
    prefix : str
        Their folder in it, without a trailing slash (``"derived"``).
    max_bytes : int
        Largest total size of the files, bytes, >= 0 (0 keeps only the file just stored).
    """

    def __init__(self, storage: Storage, prefix: str, max_bytes: int) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 0:
            raise ValueError(f"max_bytes must be a non-negative integer, got {max_bytes!r}")
        self.storage = storage
        self.prefix = prefix.rstrip("/")
        self.max_bytes = max_bytes

    def entries(self) -> list[tuple[datetime, int, str]]:
        """(modification time, size in bytes, storage name) of every file, oldest first."""
        try:
            _folders, files = self.storage.listdir(self.prefix)
        except FileNotFoundError:
            return []
        found = []
        for file in files:
            name = f"{self.prefix}/{file}"
            with contextlib.suppress(FileNotFoundError, OSError):
                found.append((self.storage.get_modified_time(name), self.storage.size(name), name))
        found.sort()
        return found

    def total_bytes(self) -> int:
        """Total size of the files, bytes."""
        return sum(size for _when, size, _name in self.entries())

    def trim(self, keep: str | None = None) -> int:
        """Remove the oldest files until the total is at most ``max_bytes``, never ``keep``.

        Returns the bytes removed.
        """
        entries = self.entries()
        total = sum(size for _when, size, _name in entries)
        removed = 0
        for _when, size, name in entries:
            if total <= self.max_bytes:
                break
            if name == keep:
                continue
            with contextlib.suppress(FileNotFoundError, OSError):
                self.storage.delete(name)
                removed += size
            total -= size
        return removed

    def clear(self) -> None:
        """Remove every file (they are built again when asked for)."""
        for _when, _size, name in self.entries():
            with contextlib.suppress(FileNotFoundError, OSError):
                self.storage.delete(name)
