"""Atomic writes: a temporary file beside the destination, renamed into place (``os.replace``),
so no partial output is ever visible under the final name."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO


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
    tmp = final.with_name(f".{final.stem}.{os.urandom(6).hex()}.tmp{final.suffix}")
    try:
        yield tmp
        if not tmp.exists():
            raise OSError(f"writing {final.name} produced no file")
        os.replace(tmp, final)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_binary_file(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """Yield a new binary file, open for writing, that becomes ``path`` on success
    (:func:`atomic_path`); created with the umask's permissions (``os.open``), unlike mkstemp's 0600."""
    with atomic_path(path) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as fh:
            yield fh


def _write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    with atomic_binary_file(path) as fh:
        fh.write(data)


def write_text_atomic(text: str, path: str | os.PathLike[str]) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (a reader sees the old file or the whole new one)."""
    _write_bytes_atomic(path, text.encode("utf-8"))


def write_files_zip_atomic(files: dict[str, bytes], path: str | os.PathLike[str], *, compress: bool = True) -> Path:
    """Write ``files`` (member name -> bytes) as a new zip at ``path``: written to a temporary
    file and renamed into place, so a reader never sees half a zip. PNG data compresses no
    further: ``compress=False`` stores the members."""
    import zipfile  # here: writing a height map (gcps measure) does without it

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", compression=method) as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    return target


def write_files_new_folder_atomic(files: dict[str, bytes], path: str | os.PathLike[str]) -> Path:
    """Write ``files`` (file name -> bytes) as the new folder ``path``: written as a temporary
    sibling folder and renamed into place, so the folder appears whole or not at all."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = target.with_name(f".{target.name}.{os.urandom(6).hex()}.tmp")
    tmp_dir.mkdir()
    try:
        for name, data in files.items():
            path_in = tmp_dir / name
            if "/" in name:  # a file in a sub-folder (multi-exposure captures)
                path_in.parent.mkdir(parents=True, exist_ok=True)
            path_in.write_bytes(data)
        os.rename(tmp_dir, target)
    finally:
        if tmp_dir.exists():
            import shutil  # here: only a failed write has a folder to remove

            shutil.rmtree(tmp_dir)
    return target
