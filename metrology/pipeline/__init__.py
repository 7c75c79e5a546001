"""One pipeline for the ``gcps`` command line and the job handlers (free of Django).

Each function takes image stacks (arrays), a rig's geometric model (any of
:data:`metrology.core.geometry.MODELS`), a codec and typed options, and returns a typed result
carrying its options (``to_dict``), the software version and per-phase timings; callers only load
their inputs, call, and store the result. Files:

- :mod:`.measure`: :func:`measure`, heights or depths, points and sigma of an object capture;
  :func:`prepare_reference`, the reference plane kept for many measurements;
- :mod:`.calibrate`: :func:`calibrate`, the paper's L and alpha (and d) on a master block;
- :mod:`.characterize`: :func:`characterize`, linearity and accuracy from a stage series;
- :mod:`.acceptance`: :func:`acceptance`, VDI/VDE 2634-2 flatness, probing and spacing errors;
- :mod:`.calibrate_procam`: projector-camera calibration from board poses;
- :mod:`.kept_references`: decoded references kept per process, bounded in memory;
- :mod:`.common`: what every result carries (phase timings, the JSON-safe form).

The package loads its modules when a name is first used (PEP 562), so that importing one light
module (``metrology.pipeline.common``) does not import every pipeline and what they need
(scipy, OpenCV). The functions share their modules' names, so they are imported from the
modules (``from metrology.pipeline.measure import measure``); the package itself offers the
options and result types.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_MEMBERS: dict[str, str] = {
    "AcceptanceOptions": "acceptance",
    "AcceptanceResult": "acceptance",
    "CalibrateOptions": "calibrate",
    "CalibrateResult": "calibrate",
    "CharacterizeOptions": "characterize",
    "CharacterizeResult": "characterize",
    "MeasureOptions": "measure",
    "MeasureResult": "measure",
    "prepare_reference": "measure",
}
"""Each public name and the module of this package that defines it."""

__all__ = [
    "AcceptanceOptions",
    "AcceptanceResult",
    "CalibrateOptions",
    "CalibrateResult",
    "CharacterizeOptions",
    "CharacterizeResult",
    "MeasureOptions",
    "MeasureResult",
    "prepare_reference",
]

if TYPE_CHECKING:  # pragma: no cover
    from metrology.pipeline.acceptance import AcceptanceOptions, AcceptanceResult
    from metrology.pipeline.calibrate import CalibrateOptions, CalibrateResult
    from metrology.pipeline.characterize import CharacterizeOptions, CharacterizeResult
    from metrology.pipeline.measure import MeasureOptions, MeasureResult, prepare_reference


def __getattr__(name: str) -> Any:
    module = _MEMBERS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
