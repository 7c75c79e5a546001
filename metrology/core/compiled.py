"""The core's compiled kernels (numba, ``cache=True``: machine code kept next to each module) and
:func:`warm_all`, which loads every one, compiling it where its cache is missing or stale.

A process pays numba's first call of a kernel: about 0.3 s to load it from the cache, 1 s to
compile it (a fresh installation). Celery workers warm them all as they start
(:func:`metrology.jobs.handlers.preload_job_code`), so no job pays it; the test script warms them
once before its parallel workers start (``python -m metrology.core.compiled``), so that they do
not each compile the same kernels. ``gcps`` commands never import numba unless a distorted rig
needs :mod:`.geometry.pinhole_kernels` (see :func:`metrology.core.decode.use_compiled`).
"""

from __future__ import annotations

import importlib

KERNEL_MODULES = (
    "metrology.core.decode_kernels",
    "metrology.core.codecs.kernels",
    "metrology.core.geometry.pinhole_kernels",
)
"""Modules of compiled kernels with a ``warm()`` (the stereo model's kernels compile on first use)."""


def warm_all() -> None:
    """Load (or compile) every kernel of :data:`KERNEL_MODULES`."""
    for name in KERNEL_MODULES:
        importlib.import_module(name).warm()


if __name__ == "__main__":
    warm_all()
