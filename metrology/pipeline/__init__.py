"""One measurement pipeline for the ``gcps`` command line and the job handlers (free of Django).

Each function takes image stacks (arrays), a rig and typed options, and returns a typed result
carrying its options (``to_dict``), the software version and per-phase timings; callers only
load their inputs, call, and store the result:

- :func:`measure` (:mod:`.measure`): height map of an object.
- :func:`calibrate` (:mod:`.calibrate`): L and alpha (and d) on a master block.
- :func:`characterize` (:mod:`.characterize`): linearity and accuracy from a stage series.
- :func:`acceptance` (:mod:`.acceptance`): VDI/VDE 2634-2 flatness, probing and spacing errors.
"""

from metrology.pipeline.acceptance import AcceptanceOptions, AcceptanceResult, acceptance
from metrology.pipeline.calibrate import CalibrateOptions, CalibrateResult, calibrate
from metrology.pipeline.characterize import CharacterizeOptions, CharacterizeResult, characterize
from metrology.pipeline.measure import MeasureOptions, MeasureResult, measure

__all__ = [
    "AcceptanceOptions",
    "AcceptanceResult",
    "CalibrateOptions",
    "CalibrateResult",
    "CharacterizeOptions",
    "CharacterizeResult",
    "MeasureOptions",
    "MeasureResult",
    "acceptance",
    "calibrate",
    "characterize",
    "measure",
]
