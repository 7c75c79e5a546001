"""Keep freed memory in the process, so that the next frame's arrays do not page-fault.

A measurement allocates a dozen frame-sized arrays (5 MB each at 1280x1024). glibc serves
such blocks with ``mmap`` and gives them back to the kernel when freed, so every new array
is faulted in again page by page: on the reference machine (a VM) that costs 4 ms per 5 MB
array, more than decoding it. Raising glibc's ``mmap`` and trim thresholds keeps freed blocks
in the heap for reuse; the price is a resident size that stays at its high-water mark, which
is what a process that measures frame after frame wants.

Processes that measure repeatedly (the ``gcps`` command, Celery workers, the benchmarks)
call :func:`retain_freed_memory` once at start; the library never does it on import.
"""

from __future__ import annotations

import ctypes
import functools
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MAX_MMAP_THRESHOLD = 32 * 1024 * 1024  # glibc's upper limit for M_MMAP_THRESHOLD on 64-bit


@functools.cache
def retain_freed_memory(trim_threshold_bytes: int = 1 << 30) -> bool:
    """Ask glibc to serve blocks up to 32 MB from the heap and to keep up to
    ``trim_threshold_bytes`` of freed heap instead of returning it to the kernel.

    Returns
    -------
    bool
        True if the settings were applied (glibc), False elsewhere (a no-op).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        # the process's own symbols, libc's among them: no ``ctypes.util.find_library("c")``, which
        # imports tempfile and subprocess and runs ``ldconfig -p`` (20-40 ms of every start-up)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, _MAX_MMAP_THRESHOLD) == 1
    return mallopt(_M_TRIM_THRESHOLD, min(trim_threshold_bytes, 2**31 - 1)) == 1 and ok
