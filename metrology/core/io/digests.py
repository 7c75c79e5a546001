"""The SHA-256 of a capture as files on disk (:func:`capture_files_digest`): what a cache keyed by a
capture (``gcps measure``'s kept references) hashes instead of the decoded frames, so that a hit
reads no image at all."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from metrology.core.tiling import map_threads


def file_sha256(path: Path) -> str:
    """SHA-256 (hex) of a file's bytes (``hashlib.file_digest``: read into one reused buffer, no
    bytes object per chunk)."""
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def capture_files_digest(source: str | os.PathLike[str], threads: int | None = None) -> str:
    """SHA-256 (hex) of a capture as files: of a folder, every regular file under it (recursively;
    junk, manifests and codec files included), each as its relative POSIX path, its size and the
    SHA-256 of its bytes, in sorted path order; of a file (a ``.zip``), its bytes. The files are
    hashed on the pool's ``threads`` (:func:`~metrology.core.tiling.map_threads`; hashlib releases
    the GIL). Any change to any file of the capture, a renamed, added or removed one too, changes it.

    Raises
    ------
    OSError
        If ``source`` does not exist or a file cannot be read.
    """
    path = Path(source)
    if path.is_file():
        return hashlib.sha256(b"gcps-capture-file|" + file_sha256(path).encode()).hexdigest()
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such file or folder")
    files = sorted((p for p in path.rglob("*") if p.is_file()), key=lambda p: p.relative_to(path).as_posix())
    digests = map_threads(file_sha256, files, threads)
    digest = hashlib.sha256(b"gcps-capture-folder|")
    for file, part in zip(files, digests, strict=True):
        digest.update(f"{file.relative_to(path).as_posix()}|{file.stat().st_size}|{part}\n".encode())
    return digest.hexdigest()


__all__ = ["capture_files_digest", "file_sha256"]
