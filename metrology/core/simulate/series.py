"""Seeds and stage positions of simulated captures: one definition for ``gcps simulate``, the
application's simulation jobs and the reports, so that any capture of a series can be rendered
alone with the same images."""

from __future__ import annotations

import json
import math
import zlib

import numpy as np

from metrology.core.scenes import Scene
from metrology.core.simulate.options import SimulationOptions, _is_int


def stack_seed(options: SimulationOptions, scene: Scene) -> np.random.SeedSequence:
    """The noise seed of :func:`render_stack`: ``options.seed`` and a digest of the scene.

    Captures of different scenes (a reference and an object) thus get independent noise with
    the same options, while a capture is reproducible from its seed and scene parameters.
    """
    digest = zlib.crc32(json.dumps(scene.params(), sort_keys=True, default=str).encode())
    return np.random.SeedSequence([options.seed, digest])


def series_seed(seed: int, position_index: int, repeat: int) -> int:
    """The noise seed (``SimulationOptions.seed``) of one capture of a stage series.

    ``SeedSequence([seed, position index, repeat])`` reduced to one 32-bit integer: capture
    ``(i, r)`` of a series seeded ``seed`` is :func:`render_stack` of the stage scene at
    position ``i`` with ``options.seed = series_seed(seed, i, r)``, so a series rendered
    capture by capture (the application's jobs) has the same images as :func:`render_series`
    (``gcps simulate --scene stage``). The reference of a series uses ``seed`` itself.

    Raises
    ------
    ValueError
        If an argument is not a non-negative integer (naming it).
    """
    for name, value in (("seed", seed), ("position_index", position_index), ("repeat", repeat)):
        if not _is_int(value) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    state = np.random.SeedSequence([int(seed), int(position_index), int(repeat)]).generate_state(1, np.uint32)
    return int(state[0])


def stage_positions(start_mm: float, stop_mm: float, step_mm: float) -> list[float]:
    """Stage positions Z_in from ``start_mm`` to ``stop_mm`` *inclusive*, every ``step_mm``, mm.

    ``start + i step`` for ``i = 0, 1, ...`` while it does not pass ``stop`` (1e-9 of a step of
    slack for rounding; values rounded to 1e-9 mm): ``0:8:3`` gives 0, 3, 6 and ``0:8:4`` gives
    0, 4, 8. The one definition used by ``gcps simulate --z-in``, the dashboard and reports.

    Raises
    ------
    ValueError
        If a value is not finite, ``step_mm <= 0`` or ``stop_mm < start_mm`` (naming it).
    """
    for name, value in (("start_mm", start_mm), ("stop_mm", stop_mm), ("step_mm", step_mm)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{name} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
    if step_mm <= 0:
        raise ValueError(f"step_mm must be positive, got {step_mm!r}")
    if stop_mm < start_mm:
        raise ValueError(f"stop_mm ({stop_mm!r}) must not be below start_mm ({start_mm!r})")
    count = math.floor((stop_mm - start_mm) / step_mm + 1e-9) + 1
    return [round(start_mm + i * step_mm, 9) for i in range(count)]
