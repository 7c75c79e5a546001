"""One measurement pipeline for the ``gcps`` command line and the job handlers (free of Django).

Each function takes image stacks (arrays), a rig and typed options, and returns a typed result
carrying its options (``to_dict``), the software version and per-phase timings; callers only
load their inputs, call, and store the result:

- :func:`measure` (:mod:`.measure`): height map of an object (crossed-axes rig, any codec coding u).
- :func:`measure_pinhole_stacks` (:mod:`.measure_pinhole`): points, depth or heights and sigma
  with a pinhole rig.
- :func:`calibrate` (:mod:`.calibrate`): L and alpha (and d) on a master block.
- :func:`characterize` (:mod:`.characterize`): linearity and accuracy from a stage series.
- :func:`acceptance` (:mod:`.acceptance`): VDI/VDE 2634-2 flatness, probing and spacing errors.
- :func:`characterize_pinhole`, :func:`acceptance_pinhole`: the same with a pinhole rig.

The names load on first use (PEP 562): importing this package, or one of its modules such as
:mod:`.common`, imports none of the other pipelines; the light :mod:`.jsonsafe` (``json_safe``,
numpy only) imports neither SciPy nor OpenCV, which keeps ``django.setup()`` and the command
line's start fast. A Celery worker imports them all as it starts
(:func:`metrology.jobs.handlers.preload_job_code`), so its first job does not pay for them.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from metrology.pipeline.acceptance import AcceptanceOptions, AcceptanceResult, acceptance, acceptance_pinhole
    from metrology.pipeline.calibrate import CalibrateOptions, CalibrateResult, calibrate
    from metrology.pipeline.characterize import (
        CharacterizeOptions,
        CharacterizeResult,
        characterize,
        characterize_pinhole,
    )
    from metrology.pipeline.measure import MeasureOptions, MeasureResult, measure
    from metrology.pipeline.measure_pinhole import PinholeMeasureOptions, PinholeMeasureResult, measure_pinhole_stacks

#: Where each public name lives: the submodule of this package that defines it.
_SOURCE: dict[str, str] = {
    "AcceptanceOptions": "acceptance",
    "AcceptanceResult": "acceptance",
    "CalibrateOptions": "calibrate",
    "CalibrateResult": "calibrate",
    "CharacterizeOptions": "characterize",
    "CharacterizeResult": "characterize",
    "MeasureOptions": "measure",
    "MeasureResult": "measure",
    "PinholeMeasureOptions": "measure_pinhole",
    "PinholeMeasureResult": "measure_pinhole",
    "acceptance": "acceptance",
    "acceptance_pinhole": "acceptance",
    "calibrate": "calibrate",
    "characterize": "characterize",
    "characterize_pinhole": "characterize",
    "measure": "measure",
    "measure_pinhole_stacks": "measure_pinhole",
}

__all__ = [
    "AcceptanceOptions",
    "AcceptanceResult",
    "CalibrateOptions",
    "CalibrateResult",
    "CharacterizeOptions",
    "CharacterizeResult",
    "MeasureOptions",
    "MeasureResult",
    "PinholeMeasureOptions",
    "PinholeMeasureResult",
    "acceptance",
    "acceptance_pinhole",
    "calibrate",
    "characterize",
    "characterize_pinhole",
    "measure",
    "measure_pinhole_stacks",
]


def __getattr__(name: str) -> Any:
    module = _SOURCE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # found once; later look-ups do not come here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """This package, with the functions :func:`measure`, :func:`calibrate`, :func:`characterize` and
    :func:`acceptance` kept over their submodules of the same names.

    Loading a submodule binds it on its package (``metrology.pipeline.measure = <module>``); with
    the names loaded eagerly the package's ``from .measure import measure`` then rebound the
    function. Loaded lazily, the submodule may be imported first (``from metrology.pipeline.measure
    import MeasureOptions``), so the binding is intercepted here: the package attribute stays the
    function, as before.
    """

    def __setattr__(self, name: str, value: object) -> None:
        if isinstance(value, types.ModuleType) and _SOURCE.get(name) == name:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
