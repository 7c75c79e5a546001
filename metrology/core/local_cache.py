"""A per-host cache of prepared arrays on local disk, shared by the processes of one machine.

Tables that take long to prepare (a distorted rig's undistortion tables, later decoded
references) are kept here so that a second process starts warm. It is a plain folder, never a
Django Storage:

- **where**: ``$GCPS_LOCAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/gcps``, else ``~/.cache/gcps``;
  one sub-folder per kind of entry (``pinhole``, ...), one file per entry;
- **key**: the SHA-256 of a canonical JSON of the software version, the kind and what the
  caller says the entry depends on (:func:`entry_key`); a new version never reads old tables;
- **file**: ``MAGIC``, the header's length (8 bytes, little-endian), the CRC-32 of what follows
  (8 bytes, little-endian), a JSON header (name, dtype, shape and offset of each array) and the
  arrays' bytes, 64-byte aligned. A read checks the CRC: a torn or corrupted file is reported (a
  warning), removed and treated as a miss. A CRC, not a cryptographic hash: it guards against
  torn writes and bad storage, which it detects but for one file in 4 billion, not against
  someone who can write the folder (who could write the tables themselves); and at ISA-L's speed
  (:mod:`metrology.core.deflate`) it costs 3 ms where SHA-256 cost 34 ms on a distorted rig's 35
  MB of tables, written by a first measurement and read by every later one;
- **writes** go to a temporary file in the entry's folder, then ``os.replace``: readers see the
  old file, the new one or none, never a part; two processes writing the same key race safely
  (the last replace wins, both files being whole). No ``fsync``: after a crash a torn file
  fails its CRC;
- **size bound**: ``$GCPS_LOCAL_CACHE_MAX_BYTES`` (default :data:`DEFAULT_MAX_BYTES`); after a
  write the least recently used entries (modification time, refreshed on every hit) are
  removed until the folder fits; a removal racing another process's is harmless;
- **failures** (a folder that cannot be created or written, a full disk) are warnings
  (:class:`LocalCacheWarning`), never errors: the caller computes the tables and goes on.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import struct
import threading
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from metrology.core.deflate import crc32

DIR_ENV = "GCPS_LOCAL_CACHE_DIR"
MAX_BYTES_ENV = "GCPS_LOCAL_CACHE_MAX_BYTES"
DEFAULT_MAX_BYTES = 2 << 30
"""Default size bound of the cache folder, bytes (2 GiB)."""
MAGIC = b"GCPSLC2\n"
"""The format's first bytes (version 2: a CRC-32 where version 1 had a SHA-256); a file of another
version is not a cache file (removed as corrupted, were its key ever asked for: the software
version in every key makes that unlikely)."""
SUFFIX = ".gcpsc"
ALIGN = 64
_HEAD = len(MAGIC) + 8 + 8
"""Bytes before the JSON header: the magic, the header's length and the CRC."""
STALE_TEMP_S = 3600.0
"""Temporary files older than this (a writer that died) are removed by the eviction pass."""


class LocalCacheWarning(UserWarning):
    """The local cache could not be read or written; the work goes on without it."""


def cache_dir() -> Path:
    """The cache folder: ``$GCPS_LOCAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/gcps``, else ``~/.cache/gcps``."""
    explicit = os.environ.get(DIR_ENV, "").strip()
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "gcps"


def max_bytes() -> int:
    """The size bound: ``$GCPS_LOCAL_CACHE_MAX_BYTES`` (bytes) or :data:`DEFAULT_MAX_BYTES`."""
    raw = os.environ.get(MAX_BYTES_ENV, "").strip()
    if not raw:
        return DEFAULT_MAX_BYTES
    try:
        return max(0, int(float(raw)))
    except ValueError:
        warnings.warn(f"{MAX_BYTES_ENV}={raw!r} is not a number; using {DEFAULT_MAX_BYTES}", LocalCacheWarning, 2)
        return DEFAULT_MAX_BYTES


def entry_key(kind: str, parts: Mapping[str, Any]) -> str:
    """The SHA-256 (hex) of ``{"kind", "version", **parts}`` as canonical JSON; ``parts`` must be
    JSON-serialisable (the rig's dict, the frame size, the options...)."""
    from metrology.version import software_version

    text = json.dumps({"kind": kind, "version": software_version(), **parts}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class CacheInfo:
    """What :func:`info` found: the folder, its bound, and per kind the entries and bytes."""

    path: Path
    max_bytes: int
    kinds: dict[str, tuple[int, int]]

    @property
    def entries(self) -> int:
        return sum(n for n, _ in self.kinds.values())

    @property
    def bytes(self) -> int:
        return sum(b for _, b in self.kinds.values())


def _warn(message: str) -> None:
    warnings.warn(message, LocalCacheWarning, stacklevel=3)


def _entry_path(root: Path, kind: str, key: str) -> Path:
    return root / kind / f"{key}{SUFFIX}"


def load(kind: str, key: str, root: Path | None = None) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``(kind, key)``, or None (absent, unreadable or corrupted: a
    corrupted file is removed with a warning). Arrays are views into one buffer read from the
    file, writable, in the dtypes and shapes stored."""
    path = _entry_path(root or cache_dir(), kind, key)
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            # a numpy buffer: numpy backs allocations of 4 MiB and more with huge pages where the
            # kernel offers them (a 10 MB kept reference: a few page faults instead of 2,600)
            buf = np.empty(size, np.uint8)
            got = fh.readinto(buf.data)
    except FileNotFoundError:
        return None
    except OSError as exc:
        _warn(f"local cache: cannot read {path}: {exc}")
        return None
    try:
        arrays = _decode(buf.data[:got], buf)
    except ValueError as exc:
        _warn(f"local cache: {path} is corrupted ({exc}); removed")
        _unlink(path)
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # least recently used: a hit refreshes the entry
    return arrays


def store(kind: str, key: str, arrays: Mapping[str, np.ndarray], root: Path | None = None) -> bool:
    """Store ``arrays`` under ``(kind, key)`` atomically, then evict down to the size bound.
    Returns False (after a warning) when the cache cannot be written."""
    root = root or cache_dir()
    folder = root / kind
    tmp_name = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        payload = _encode(arrays)
        import tempfile  # here: loading a kept entry (gcps measure's start-up) does without it

        fd, tmp_name = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=SUFFIX)
        with os.fdopen(fd, "wb") as fh:
            for chunk in payload:
                fh.write(chunk)
        os.chmod(tmp_name, 0o644)  # mkstemp's 0600 would hide the entry from the host's other users
        os.replace(tmp_name, _entry_path(root, kind, key))
        tmp_name = None
    except OSError as exc:
        _warn(f"local cache: cannot write {folder}: {exc}; going on without it")
        return False
    finally:
        if tmp_name is not None:
            _unlink(Path(tmp_name))
    evict(root, max_bytes())
    return True


_PENDING: list[threading.Thread] = []
_PENDING_LOCK = threading.Lock()


def store_later(kind: str, key: str, arrays: Mapping[str, np.ndarray], root: Path | None = None) -> None:
    """:func:`store` on a background thread, so that the caller goes on while the file is
    written; the arrays must not change afterwards. The thread is not a daemon: the interpreter
    waits for it before exiting, and :func:`wait` joins the pending ones."""
    thread = threading.Thread(target=store, args=(kind, key, dict(arrays), root), name="gcps-local-cache")
    with _PENDING_LOCK:
        _PENDING[:] = [t for t in _PENDING if t.is_alive()]
        _PENDING.append(thread)
    thread.start()


def wait() -> None:
    """Wait for the writes started by :func:`store_later`."""
    with _PENDING_LOCK:
        pending = list(_PENDING)
    for thread in pending:
        thread.join()


def _encode(arrays: Mapping[str, np.ndarray]) -> list[bytes | memoryview]:
    """The file's chunks: magic, header length, CRC-32, header, aligned array bytes."""
    entries: list[dict[str, Any]] = []
    blobs: list[bytes | memoryview] = []
    offset = 0
    for name, arr in arrays.items():
        a = np.ascontiguousarray(arr)
        pad = -offset % ALIGN
        if pad:
            blobs.append(b"\0" * pad)
            offset += pad
        entries.append({"name": name, "dtype": a.dtype.str, "shape": list(a.shape), "offset": offset})
        blobs.append(a.reshape(-1).view(np.uint8).data if a.size else memoryview(b""))
        offset += a.nbytes
    header = json.dumps({"arrays": entries}).encode()
    pad = -(_HEAD + len(header)) % ALIGN
    header += b" " * pad
    crc = crc32(header)
    for blob in blobs:
        crc = crc32(blob, crc)
    return [MAGIC, struct.pack("<Q", len(header)), struct.pack("<Q", crc), header, *blobs]


def _decode(view: memoryview, buf: np.ndarray) -> dict[str, np.ndarray]:
    """Inverse of :func:`_encode`; ``ValueError`` on a bad magic, length, CRC or header."""
    head = _HEAD
    if len(view) < head or bytes(view[: len(MAGIC)]) != MAGIC:
        raise ValueError("not a cache file")
    (n_header,) = struct.unpack("<Q", view[len(MAGIC) : len(MAGIC) + 8])
    if head + n_header > len(view):
        raise ValueError("truncated header")
    (stored,) = struct.unpack("<Q", view[len(MAGIC) + 8 : head])
    if crc32(view[head:]) != stored:
        raise ValueError("checksum mismatch")
    try:
        header = json.loads(bytes(view[head : head + n_header]))
        start = head + n_header
        out: dict[str, np.ndarray] = {}
        for e in header["arrays"]:
            dtype = np.dtype(e["dtype"])
            shape = tuple(int(n) for n in e["shape"])
            count = int(np.prod(shape, dtype=np.int64))
            out[e["name"]] = np.frombuffer(buf, dtype, count, start + int(e["offset"])).reshape(shape)
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"bad header: {exc}") from exc
    return out


def _unlink(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def _entries(root: Path) -> list[tuple[Path, os.stat_result]]:
    found: list[tuple[Path, os.stat_result]] = []
    if not root.is_dir():
        return found
    for folder in root.iterdir():
        if not folder.is_dir():
            continue
        for path in folder.iterdir():
            try:
                st = path.stat()
            except OSError:
                continue
            if path.name.startswith(".tmp-"):
                if time.time() - st.st_mtime > STALE_TEMP_S:
                    _unlink(path)
                continue
            if path.suffix == SUFFIX:
                found.append((path, st))
    return found


def evict(root: Path | None = None, bound: int | None = None) -> int:
    """Remove the least recently used entries until the folder holds at most ``bound`` bytes
    (default :func:`max_bytes`); returns the number removed."""
    root = root or cache_dir()
    bound = max_bytes() if bound is None else bound
    entries = sorted(_entries(root), key=lambda e: e[1].st_mtime)
    total = sum(st.st_size for _, st in entries)
    removed = 0
    for path, st in entries:
        if total <= bound:
            break
        _unlink(path)
        total -= st.st_size
        removed += 1
    return removed


def info(root: Path | None = None) -> CacheInfo:
    """Entries and bytes per kind."""
    root = root or cache_dir()
    kinds: dict[str, tuple[int, int]] = {}
    for path, st in _entries(root):
        n, b = kinds.get(path.parent.name, (0, 0))
        kinds[path.parent.name] = (n + 1, b + st.st_size)
    return CacheInfo(path=root, max_bytes=max_bytes(), kinds=kinds)


def clear(root: Path | None = None) -> int:
    """Remove every entry; returns the number removed."""
    root = root or cache_dir()
    entries = _entries(root)
    for path, _ in entries:
        _unlink(path)
    return len(entries)


__all__ = [
    "CacheInfo",
    "LocalCacheWarning",
    "cache_dir",
    "clear",
    "entry_key",
    "evict",
    "info",
    "load",
    "max_bytes",
    "store",
    "store_later",
    "wait",
]
