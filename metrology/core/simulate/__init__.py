"""The virtual rig: captures of any codec through any geometric model, with exact ground truth.

Files:

- :mod:`.render`: the one entry, :func:`render_capture` and :func:`render_series` (any model,
  any codec), choosing the renderer in one place (:func:`~.render.uses_paper_renderer`);
- :mod:`.paper_rig`: the paper's exact crossed-axes forward model and gcps-v1 renderer
  (:func:`render_stack`, :func:`render_flat_frames`), the oracle of the paper's rig;
- :mod:`.cast`: ground truth of any model by ray casting a placed scene through its seam;
- :mod:`.options`: :class:`SimulationOptions` and the two presets;
- :mod:`.series`: noise seeds and stage positions shared by every renderer and caller;
- :mod:`.exposures`: high-dynamic-range scenes (a reflectance map of 1000:1) rendered at several
  exposures, as multi-exposure captures (:func:`~.exposures.render_exposures`).

No file I/O: writing a capture stack is :mod:`metrology.core.io`'s job.
"""

from metrology.core.simulate.cast import CastTruth, ScenePlacement, cast_truth
from metrology.core.simulate.options import SimulationOptions, noise_free_16bit, realistic_8bit
from metrology.core.simulate.paper_rig import (
    RenderedStack,
    crossed_rig_truth,
    emitted_pattern,
    render_flat_frames,
    render_stack,
)
from metrology.core.simulate.render import (
    RenderedCapture,
    default_placement,
    render_camera_flats,
    render_capture,
    render_flats,
    render_series,
    uses_paper_renderer,
)
from metrology.core.simulate.series import series_seed, stack_seed, stage_positions

__all__ = [
    "CastTruth",
    "RenderedCapture",
    "RenderedStack",
    "ScenePlacement",
    "SimulationOptions",
    "cast_truth",
    "crossed_rig_truth",
    "default_placement",
    "emitted_pattern",
    "noise_free_16bit",
    "realistic_8bit",
    "render_camera_flats",
    "render_capture",
    "render_flat_frames",
    "render_flats",
    "render_series",
    "render_stack",
    "series_seed",
    "stack_seed",
    "stage_positions",
    "uses_paper_renderer",
]
