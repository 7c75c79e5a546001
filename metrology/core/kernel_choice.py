"""The one rule choosing between a compiled kernel (numba) and its numpy twin, for every kernel
that has both: the fused gcps-v1 decode (:func:`metrology.core.decode.use_compiled`) and the
pinhole model's distorted-projector tiles (:func:`metrology.core.geometry.pinhole_numpy.tile_kernels`).

Both give the same numbers. Importing numba and loading the kernels from its disk cache cost
0.5-1 s of CPU in a fresh process, more than the kernels save on the one frame a ``gcps measure``
process decodes and triangulates; a Celery worker imports and warms numba as it starts
(:func:`metrology.core.compiled.warm_all`), so there the kernels cost nothing more. This module
imports nothing heavy: it is read by the core's hot paths.
"""

from __future__ import annotations

import sys

COMPILED_MIN_PX = 1 << 25
"""Frames of at least this many pixels (32 Mpx) take the compiled kernels even in a process that has
not imported numba: there one frame saves more than numba's import costs (0.3-0.65 s)."""
COMPILED: bool | None = None
"""Force the choice: True the compiled kernels, False numpy's; None (default) decides with
:func:`use_compiled`. For tests and benchmarks."""


def use_compiled(pixels: int) -> bool:
    """Whether frames of ``pixels`` pixels take the compiled kernels: where numba is already
    imported in this process (a Celery worker preloads it: ``jobs.handlers.preload_job_code``) or
    the frame is large (:data:`COMPILED_MIN_PX`), unless :data:`COMPILED` forces the choice."""
    if COMPILED is not None:
        return COMPILED
    return "numba" in sys.modules or pixels >= COMPILED_MIN_PX
