"""Row tiles, the thread pool that runs them, per-thread scratch arrays, freed-memory retention."""

import itertools
import threading
import time

import numpy as np
import pytest

from metrology.core.allocation import retain_freed_memory
from metrology.core.tiling import (
    MIN_TILE_PX,
    Scratch,
    _thread_pool,
    map_threads,
    nested_threads,
    row_tiles,
    run_tiled,
    scratch_nbytes,
    thread_scratch,
)


def test_row_tiles_cover_the_rows_once():
    tiles = row_tiles(1000, 1280, tile_px=1 << 17)
    assert tiles[0].start == 0 and tiles[-1].stop == 1000
    assert all(a.stop == b.start for a, b in itertools.pairwise(tiles))
    assert {t.stop - t.start for t in tiles[:-1]} == {(1 << 17) // 1280}
    assert row_tiles(3, 100_000, tile_px=10) == [slice(0, 1), slice(1, 2), slice(2, 3)]  # a row at least


def test_run_tiled_splits_for_every_thread_and_reuses_its_threads():
    seen: list[tuple[slice, str]] = []
    lock = threading.Lock()

    def run(rows: slice) -> None:
        with lock:
            seen.append((rows, threading.current_thread().name))

    run_tiled(run, 512, 512, threads=2)  # 256k px: split to 4 tiles of 64k px for 2 threads
    assert sorted(r.start for r, _ in seen) == [0, 128, 256, 384]
    for _ in range(5):
        run_tiled(run, 512, 512, threads=2)
    names = {name for _, name in seen}
    caller = threading.current_thread().name
    pool_threads = names - {caller}  # the caller takes tiles too, beside one thread of the pool (if it starts in time)
    assert len(pool_threads) <= 1 and all(name.startswith("gcps-tile") for name in pool_threads)  # one pool, kept
    seen.clear()
    run_tiled(run, 64, 64, threads=2)  # smaller than MIN_TILE_PX: one tile, run in the caller
    assert [r for r, _ in seen] == [slice(0, 64)] and MIN_TILE_PX > 64 * 64
    assert seen[0][1] == threading.current_thread().name
    with pytest.raises(ValueError, match="threads"):
        run_tiled(run, 10, 10, threads=0)


def test_scratch_returns_the_same_array_and_never_shares_names():
    scratch = Scratch()
    a = scratch.get("a", (4, 5), np.float32)
    assert scratch.get("a", (4, 5), np.float32) is a
    b = scratch.get("b", (4, 5), np.float32)
    assert not np.shares_memory(a, b)
    assert a.flags.c_contiguous and a.dtype == np.float32
    assert scratch.nbytes == Scratch.CHUNK_BYTES + 64  # both cut from one chunk (and its alignment slack)
    assert thread_scratch() is thread_scratch()
    assert scratch_nbytes() >= scratch.nbytes
    other: list[Scratch] = []
    worker = threading.Thread(target=lambda: other.append(thread_scratch()))
    worker.start()
    worker.join()
    assert other[0] is not thread_scratch()


def test_scratch_buffers_are_aligned_chunks_and_grow_apart():
    """Buffers are cut from chunks of CHUNK_BYTES (huge pages where offered), 64-byte aligned; a
    buffer larger than what is left of the chunk gets a new one; a name that asks for more
    gets a new buffer, never one overlapping another name's."""
    scratch = Scratch()
    small = [scratch.get(name, (3, 7), np.uint8) for name in "abc"]
    assert all(view.ctypes.data % 64 == 0 for view in small)
    big = scratch.get("big", (Scratch.CHUNK_BYTES // 4,), np.float32)  # a whole chunk of its own
    assert big.nbytes == Scratch.CHUNK_BYTES and big.ctypes.data % 64 == 0
    grown = scratch.get("a", (100, 100), np.float64)
    for view in (*small[1:], big):
        assert not np.shares_memory(grown, view)
    assert scratch.nbytes >= 2 * Scratch.CHUNK_BYTES
    grown[...] = 1.0
    big[...] = 2.0
    small[1][...] = 3
    assert (grown == 1.0).all() and (big == 2.0).all() and (small[1] == 3).all()


def test_retain_freed_memory_applies_on_glibc():
    import platform

    applied = retain_freed_memory()
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert applied is True


def test_nested_threads_is_one_on_a_thread_of_the_pool():
    assert nested_threads(3) == 3 and nested_threads() is None
    assert map_threads(lambda threads: nested_threads(threads), [2, None], threads=2) == [1, 1]


def test_run_tiled_runs_first_once_before_the_tiles_and_withdraws_unstarted_helpers():
    order: list[object] = []
    lock = threading.Lock()

    def run(rows: slice) -> None:
        with lock:
            order.append(rows.start)

    run_tiled(run, 512, 512, threads=2, first=lambda: order.append("first"))
    assert order.count("first") == 1 and sorted(r for r in order if r != "first") == [0, 128, 256, 384]  # type: ignore[type-var]
    order.clear()
    run_tiled(run, 512, 512, threads=1, first=lambda: order.append("first"))
    assert order == ["first", 0, 256]  # one thread: in order, tiles of DEFAULT_TILE_PX
    # with the helpers' pool busy, the caller takes every tile and does not wait for a helper
    release = threading.Event()
    busy = _thread_pool(1).submit(release.wait, 10)  # the pool of threads=2's one helper
    order.clear()
    run_tiled(run, 512, 512, threads=2)
    assert sorted(order) == [0, 128, 256, 384] and not busy.done()  # type: ignore[type-var]
    release.set()
    busy.result()


def test_a_tile_that_raises_stops_the_others_and_raises_in_the_caller():
    started: list[int] = []

    def run(rows: slice) -> None:
        started.append(rows.start)
        if rows.start == 0:
            raise RuntimeError("tile 0")
        time.sleep(0.002)

    with pytest.raises(RuntimeError, match="tile 0"):
        run_tiled(run, 4096, 512, threads=2, first=lambda: None)  # 16 tiles of 256 rows
    assert 0 in started and len(started) < 16  # the tiles not started by then never start


def test_nested_threads_is_one_in_the_callers_tiles():
    seen: list[int | None] = []
    run_tiled(lambda rows: seen.append(nested_threads(2)), 512, 512, threads=2)
    assert seen == [1, 1, 1, 1] and nested_threads(2) == 2
