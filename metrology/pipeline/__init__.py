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
"""

from metrology.pipeline.acceptance import AcceptanceOptions, AcceptanceResult, acceptance, acceptance_pinhole
from metrology.pipeline.calibrate import CalibrateOptions, CalibrateResult, calibrate
from metrology.pipeline.characterize import CharacterizeOptions, CharacterizeResult, characterize, characterize_pinhole
from metrology.pipeline.measure import MeasureOptions, MeasureResult, measure
from metrology.pipeline.measure_pinhole import PinholeMeasureOptions, PinholeMeasureResult, measure_pinhole_stacks

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
