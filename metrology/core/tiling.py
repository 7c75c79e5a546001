"""Row tiles of work, the threads that run them, and per-thread scratch arrays.

The hot loops (decoding, triangulation, the mixed-pixel filter) run tile by tile so that
their temporaries stay in cache, and write every temporary into a scratch array kept for
the thread: a tile then allocates nothing, which matters more than one would think, since
freshly allocated memory handed back to the system between tiles comes back page fault by
page fault.
"""

from __future__ import annotations

import functools
import math
import os
import threading
import weakref
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
import numpy.typing as npt

T = TypeVar("T")
U = TypeVar("U")

DEFAULT_TILE_PX = 1 << 17
"""Pixels per tile of work. A tile's call of the decoding kernel is about thirty numpy and
OpenCV calls, each with a few microseconds of fixed cost, so tiles must be large; but not
so large that their temporaries (about ten float32 arrays) fall out of the caches. Measured
for ``measure_height`` at 1280x1024, one thread: 12.3 ms at 32k pixels, 11.0 at 64k, 10.5 at
128k, 11.8 at 256k (benchmarks/decode.py has the method)."""

DEFAULT_THREADS = min(4, os.cpu_count() or 1)
"""Threads over tiles: the cores of the machine, at most four. The kernel spends most of its
time in numpy loops and OpenCV calls that release the GIL: measuring frame after frame at
1280x1024 on 2 cores, two threads take 6.3 ms where one takes 10.5 ms. After the machine has
been idle for ~10 ms the gain vanishes (10.7 ms either way on the reference VM, whose idle
virtual CPUs are slow to wake); it never costs time."""

MIN_TILE_PX = 1 << 15
"""Smallest tile when a frame is split finer to keep every thread busy."""


def row_tiles(height: int, width: int, tile_px: int | None = None) -> list[slice]:
    """Split ``height`` rows into slices of about ``tile_px`` pixels each (default :data:`DEFAULT_TILE_PX`)."""
    tile_px = DEFAULT_TILE_PX if tile_px is None else tile_px
    rows_per_tile = max(1, tile_px // max(1, width))
    return [slice(r, min(height, r + rows_per_tile)) for r in range(0, height, rows_per_tile)]


def run_tiled(
    run: Callable[[slice], object],
    height: int,
    width: int,
    threads: int | None = None,
    tile_px: int | None = None,
    *,
    first: Callable[[], object] | None = None,
) -> None:
    """Call ``run(rows)`` for every row tile of an ``(height, width)`` image, on ``threads`` threads.

    With several threads, tiles shrink (down to :data:`MIN_TILE_PX`) until there are at least
    two per thread, so that no thread is left with a long last tile; the caller works too, beside
    the ``threads - 1`` threads of a pool kept for this (so that ``threads`` threads hold the
    tiles' scratch arrays), each taking the next task until none is left. A helper
    that has not started by then is withdrawn: a core that wakes slowly, or is busy with another
    process, delays nothing (the call then takes what one thread takes).

    ``first``: one more task, taken before the tiles (the fused path's codec self-check, which then
    runs on one thread while the others start on the tiles). After a task raises, no other task
    starts; the exception is raised here.
    """
    n_threads = threads if threads is not None else DEFAULT_THREADS
    if n_threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    tile_px = DEFAULT_TILE_PX if tile_px is None else tile_px
    if n_threads > 1:
        tile_px = max(MIN_TILE_PX, min(tile_px, math.ceil(height * width / (2 * n_threads))))
    tasks: list[Callable[[], object]] = [] if first is None else [first]
    tasks += [functools.partial(run, rows) for rows in row_tiles(height, width, tile_px)]
    n_helpers = min(n_threads, len(tasks)) - 1
    if n_helpers == 0:
        for task in tasks:
            task()
        return
    lock = threading.Lock()
    taken = 0

    def work() -> None:
        nonlocal taken
        while True:
            with lock:
                if taken == len(tasks):
                    return
                task = tasks[taken]
                taken += 1
            try:
                task()
            except BaseException:
                with lock:
                    taken = len(tasks)
                raise

    # a pool of threads - 1 for the helpers: with the caller, threads threads ever hold tile scratch
    helpers = [_thread_pool(n_threads - 1).submit(work) for _ in range(n_helpers)]
    in_tiles = getattr(_local, "in_tiles", False)
    _local.in_tiles = True  # the caller's tiles see nested_threads as the pool's do
    try:
        work()
    finally:
        _local.in_tiles = in_tiles
        for helper in helpers:
            if not helper.cancel():
                helper.result()


def map_threads(func: Callable[[U], T], items: Sequence[U], threads: int | None = None) -> list[T]:
    """``[func(item) for item in items]``, on the pool's ``threads`` threads (default
    :data:`DEFAULT_THREADS`; in order). For work that releases the GIL (hashing, OpenCV, numpy);
    ``func`` must not wait for the pool itself."""
    n_threads = threads if threads is not None else DEFAULT_THREADS
    if n_threads <= 1 or len(items) <= 1:
        return [func(item) for item in items]
    return list(_thread_pool(n_threads).map(func, items))


def run_beside(func: Callable[[], T], threads: int | None = None) -> Callable[[], T]:
    """Start ``func()`` on a thread of the pool while the caller goes on; returns the function
    that waits for its result (re-raising its exception). With one thread (``threads`` 1, or a
    one-core default) ``func`` runs at once, in the caller's thread.

    ``func`` must not wait for the pool itself (``run_tiled`` with several threads): it could
    wait for its own thread."""
    n_threads = threads if threads is not None else DEFAULT_THREADS
    if n_threads <= 1:
        value = func()
        return lambda: value
    return _thread_pool(n_threads).submit(func).result


def nested_threads(threads: int | None = None) -> int | None:
    """``threads`` for a call of :func:`run_tiled` or :func:`map_threads` that may itself run on
    one of the pool's threads, or in a tile the caller of :func:`run_tiled` runs: 1 there (a nested
    call on the same pool would wait for workers that are all busy), ``threads`` elsewhere."""
    if getattr(_local, "in_tiles", False) or threading.current_thread().name.startswith(_THREAD_PREFIX):
        return 1
    return threads


_THREAD_PREFIX = "gcps-tile"
_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def _thread_pool(n_threads: int) -> ThreadPoolExecutor:
    """A pool of ``n_threads`` threads kept for the process (and its scratch arrays with it);
    a forked child (a Celery worker) gets its own, since threads do not survive a fork."""
    key = (os.getpid(), n_threads)
    with _pools_lock:
        pool = _pools.get(key)
        if pool is None:
            pool = _pools[key] = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix=_THREAD_PREFIX)
        return pool


class Scratch:
    """Named scratch arrays of one thread, reused from tile to tile and call to call.

    ``get(name, shape, dtype)`` returns an uninitialised C-contiguous array: a view of the
    name's buffer, which grows when a larger array is asked for (a frame's last, shorter
    tile shares it). Two names never share memory. A repeated look-up is one dict access
    (the kernels make about thirty per tile).

    The buffers are cut from chunks of at least :data:`CHUNK_BYTES` (64-byte aligned): numpy
    backs allocations of 4 MiB and more with huge pages where the kernel offers them, so a
    thread's first tile faults in a few 2 MiB pages instead of a few thousand 4 KiB ones
    (about 3 us each on a virtual machine), which a one-frame process (``gcps measure``) pays.
    """

    _MAX_VIEWS = 256  # beyond this (many frame sizes seen), forget the cached views
    CHUNK_BYTES = 8 << 20
    _ALIGN = 64

    def __init__(self) -> None:
        _all_scratch.add(self)
        self._buffers: dict[str, np.ndarray] = {}
        self._views: dict[tuple[str, tuple[int, ...], npt.DTypeLike], np.ndarray] = {}
        self._chunk = np.empty(0, np.uint8)  # the free end of the current chunk

    def get(self, name: str, shape: tuple[int, ...], dtype: npt.DTypeLike) -> np.ndarray:
        key = (name, shape, dtype)
        view = self._views.get(key)
        if view is not None:
            return view
        n_bytes = math.prod(shape) * np.dtype(dtype).itemsize
        buffer = self._buffers.get(name)
        if buffer is None or buffer.nbytes < n_bytes:
            buffer = self._buffers[name] = self._carve(n_bytes)
            self._views = {k: v for k, v in self._views.items() if k[0] != name}  # views of the old buffer
        if len(self._views) >= self._MAX_VIEWS:
            self._views.clear()
        view = self._views[key] = buffer[:n_bytes].view(dtype).reshape(shape)
        return view

    def _carve(self, n_bytes: int) -> np.ndarray:
        """``n_bytes`` of the current chunk (a new chunk where it has too few left)."""
        size = -(-n_bytes // self._ALIGN) * self._ALIGN
        if self._chunk.nbytes < size:
            chunk = np.empty(max(self.CHUNK_BYTES, size) + self._ALIGN, np.uint8)
            self._chunk = chunk[-chunk.ctypes.data % self._ALIGN :]
        buffer, self._chunk = self._chunk[:n_bytes], self._chunk[size:]
        return buffer

    @property
    def nbytes(self) -> int:
        """Bytes held: the chunks that the buffers and the free end are cut from (a chunk is freed
        once no buffer is cut from it: every name in it has grown out of it)."""
        chunks = {id(a.base): a.base for a in (*self._buffers.values(), self._chunk) if a.base is not None}
        return sum(chunk.nbytes for chunk in chunks.values())


_all_scratch: weakref.WeakSet[Scratch] = weakref.WeakSet()


def scratch_nbytes() -> int:
    """Bytes held by the scratch arrays of all live threads (a part of the memory footprint)."""
    return sum(scratch.nbytes for scratch in list(_all_scratch))


_local = threading.local()


def thread_scratch() -> Scratch:
    """The calling thread's :class:`Scratch` (created on first use, freed with the thread)."""
    scratch: Scratch | None = getattr(_local, "scratch", None)
    if scratch is None:
        scratch = _local.scratch = Scratch()
    return scratch
