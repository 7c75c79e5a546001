"""Kept references: decoded reference planes reused by the measurements of one process, bounded in memory.

Many measurements share one reference capture. Decoding it (and reading its stack) once per
worker process instead of once per measurement saves a stack read and a decode per job. Entries
are keyed by whatever identifies a decoded reference exactly (the application uses the capture's
id and sha256, the rig values and the decoding options) and evicted least recently used first
when their arrays exceed ``max_bytes``; the newest reference is kept even when it alone exceeds
the bound (a 12 MP gcps-v1 reference holds about 195 MiB, more than a small bound), so that a
series measured against one large reference decodes it once: the bound then holds that one only.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np

from metrology.core.measure import Reference


def reference_nbytes(reference: Any) -> int:
    """Bytes held by the numpy arrays reachable from ``reference`` (dataclass fields, attributes,
    containers), each array counted once (a view counts as its base)."""
    seen: set[int] = set()
    total = 0
    stack = [reference]
    while stack:
        item = stack.pop()
        if id(item) in seen:
            continue
        seen.add(id(item))
        if isinstance(item, np.ndarray):
            base = item
            while isinstance(base.base, np.ndarray):
                base = base.base
            if base is not item:
                stack.append(base)
            else:
                total += item.nbytes
        elif isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
        elif dataclasses.is_dataclass(item) and not isinstance(item, type):
            stack.extend(getattr(item, f.name) for f in dataclasses.fields(item))
        elif hasattr(item, "__dict__") and not isinstance(item, type):
            stack.extend(vars(item).values())
    return total


@dataclass
class KeptReferenceStats:
    """Counters of a :class:`KeptReferences` (since it was created)."""

    hits: int = 0
    misses: int = 0
    evictions: int = 0


class KeptReferences:
    """Decoded references by key, at most ``max_bytes`` of arrays, least recently used evicted first.

    Thread-safe; two threads missing the same key at once may both prepare it (the second result
    is kept). A reference larger than ``max_bytes`` is kept alone (every other evicted); with
    ``max_bytes`` 0 none is kept.

    Parameters
    ----------
    max_bytes : int
        Largest total of the kept references' arrays, bytes, >= 0 (0 keeps none).
    """

    def __init__(self, max_bytes: int) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 0:
            raise ValueError(f"max_bytes must be a non-negative integer, got {max_bytes!r}")
        self.max_bytes = max_bytes
        self.stats = KeptReferenceStats()
        self._entries: OrderedDict[Hashable, tuple[Reference, int]] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    @property
    def nbytes(self) -> int:
        """Bytes of the kept references' arrays."""
        with self._lock:
            return sum(size for _ref, size in self._entries.values())

    def get(self, key: Hashable, prepare: Callable[[], Reference]) -> tuple[Reference, bool]:
        """The reference kept under ``key``, or ``prepare()`` kept under it; and whether it was kept (a hit)."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
                self.stats.hits += 1
                return entry[0], True
            self.stats.misses += 1
        reference = prepare()
        size = reference_nbytes(reference)
        with self._lock:
            if self.max_bytes > 0:
                self._entries[key] = (reference, size)
                self._entries.move_to_end(key)
                total = sum(s for _ref, s in self._entries.values())
                while total > self.max_bytes and len(self._entries) > 1:
                    _old_key, (_old, old_size) = self._entries.popitem(last=False)
                    total -= old_size
                    self.stats.evictions += 1
        return reference, False

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
