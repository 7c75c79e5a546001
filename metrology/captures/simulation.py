"""What the virtual rig may be asked to render: the shared presets and the bounds of a request.

The API, the pages and the demo start from the same presets (:data:`PRESETS`; the default is
``realistic``, the core's :meth:`SimulationOptions.realistic_8bit`). A request is checked here
before its job is queued, so a worker never receives a render it cannot finish: every scene
value finite and of a physical size, the scene's heights within the rig's depth range, every
option within a range where it still means something, and the render's memory below
``GCPS_MAX_SIMULATION_BYTES``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

#: Options of :class:`metrology.core.simulate.SimulationOptions` that differ from its defaults.
PRESETS: dict[str, dict[str, Any]] = {
    # 8-bit, 1.5 grey levels of noise, 0.7 px camera and 0.15 code projector blur, 3 x 3 sub-rays
    "realistic": {
        "bit_depth": 8,
        "noise_grey": 1.5,
        "camera_defocus_px": 0.7,
        "projector_defocus_codes": 0.15,
        "supersample": 3,
    },
    # exact rendering: 16-bit, no noise, no blur, one ray per pixel
    "noise-free": {"bit_depth": 16},
}
DEFAULT_PRESET = "realistic"

#: Upper bounds of the real-valued options (lower bounds are the core's): name -> (bound, why).
OPTION_MAXIMA: dict[str, tuple[float, str]] = {
    "ambient": (1.0, "fraction of full scale; 1 saturates every pixel"),
    "projector_gain": (2.0, "fraction of full scale; above 1 saturates"),
    "projector_gamma": (5.0, "projector response exponent"),
    "projector_defocus_codes": (8.0, "code units; two fringe periods blur every fringe away"),
    "camera_defocus_px": (20.0, "pixels"),
    "smoothing_codes": (8.0, "code units; two fringe periods"),
}
#: Camera noise above this fraction of full scale leaves no fringe to measure.
NOISE_MAX_FRACTION_OF_FULL_SCALE = 0.25
SEED_MAX = 2**32 - 1
#: No scene value (sizes, positions, heights) may exceed this multiple of the rig's size.
SCENE_SIZE_FACTOR = 10.0
#: Heights the renderer accepts: below the scene's plane down to the camera's height above it, above
#: it up to 95 % of that height (the paper's rig: -L to 0.95 L, its pupils at L).
DEPTH_BELOW_FRACTION = 1.0
DEPTH_ABOVE_FRACTION = 0.95

# Peak memory of render_stack, bytes per camera pixel and per sub-ray, with margin (tracemalloc,
# December 2026, after the renders' in-place passes): a warm process's render peaks at 220 B/px
# noise-free and 253 B/px realistic at one ray per pixel, about 130 B more per further sub-ray
# (1188 and 1323 B/px at 3x3); a process's first render at 640x480, 416 B/px (1x1) and 1474 B/px
# (3x3, realistic). A process's first render also loads the compiled kernels and tables, about
# 40 MB whatever the frame size, which is not the render's and not modelled here.
_BYTES_PER_PIXEL = 300
_BYTES_PER_SUBRAY = 140


def preset_options(preset: str, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The options of ``preset`` with ``overrides`` applied; raises ``ValueError`` on an unknown preset."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    return {**PRESETS[preset], **dict(overrides or {})}


def camera_height_mm(model: Any) -> float:
    """The camera's height above the plane the virtual rig places scenes on (the paper's L)."""
    from metrology.core.scenes import FIELD_WIDTH_MM

    return float(model.scene_distance_mm(FIELD_WIDTH_MM))


def depth_range_mm(model: Any) -> tuple[float, float]:
    """Heights (mm above the scene's plane) a scene may reach for the rig's ``model``:
    ``(-D, 0.95 D)``, ``D`` the camera's height (:func:`camera_height_mm`)."""
    height = camera_height_mm(model)
    return -DEPTH_BELOW_FRACTION * height, DEPTH_ABOVE_FRACTION * height


def estimated_render_bytes(model: Any, options: Any) -> int:
    """Peak memory of rendering a stack for ``rig`` with ``options``, bytes (every camera's).

    ``H W (300 + 140 s^2)`` with ``s`` the sub-rays per pixel along each axis: the traced peak
    is about 220 + 121 (s^2 - 1) bytes per pixel noise-free and 253 + 134 (s^2 - 1) realistic; a
    process's first realistic render up to 1474 B/px at ``s`` = 3 (640x480).
    """
    subrays = int(options.supersample) ** 2
    peak = sum(int(h) * int(w) for h, w in model.camera_shapes)  # every camera's cast is kept
    return peak * (_BYTES_PER_PIXEL + _BYTES_PER_SUBRAY * subrays)


def check_scene_values(model: Any, name: str, params: Mapping[str, Any]) -> None:
    """Every numeric scene parameter finite and within ``SCENE_SIZE_FACTOR`` times the rig's size
    (the camera's height above the scene's plane, the scenes' field width, the field's centre)."""
    from metrology.core.scenes import FIELD_WIDTH_MM

    limit = SCENE_SIZE_FACTOR * max(camera_height_mm(model), FIELD_WIDTH_MM, abs(model.scene_centre_x_mm or 0.0))
    for key, value in params.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue  # the scene itself refuses what is not a number
        if not math.isfinite(value) or abs(value) > limit:
            raise ValueError(
                f"scene.{key} must be a finite number of magnitude at most {limit:g} "
                f"({SCENE_SIZE_FACTOR:g} times the rig's largest dimension), got {value!r}"
            )


def check_scene_depth(model: Any, name: str, scene: Any) -> None:
    """The scene's heights within :func:`depth_range_mm`."""
    low, high = depth_range_mm(model)
    z_min, z_max = float(scene.z_min_mm), float(scene.z_max_mm)
    if not (low <= z_min and z_max < high):
        raise ValueError(
            f"scene {name!r} reaches heights {z_min:g} to {z_max:g} mm, outside the rig's depth range "
            f"{low:g} to {high:g} mm (below the reference plane down to the camera's height above it, "
            "above it up to 0.95 of that height)"
        )


def check_option_values(options: Any) -> None:
    """Upper bounds of the options (the core already refused non-finite and negative values)."""
    for key, (maximum, why) in OPTION_MAXIMA.items():
        value = getattr(options, key, None)
        if value is not None and value > maximum:
            raise ValueError(f"options.{key} must be at most {maximum:g} ({why}), got {value!r}")
    noise_max = NOISE_MAX_FRACTION_OF_FULL_SCALE * options.full_scale
    if options.noise_grey > noise_max:
        raise ValueError(
            f"options.noise_grey must be at most {noise_max:g} grey levels (a quarter of the "
            f"{options.bit_depth}-bit full scale), got {options.noise_grey!r}"
        )
    if options.seed > SEED_MAX:
        raise ValueError(f"options.seed must be at most {SEED_MAX}, got {options.seed!r}")


def check_render_memory(model: Any, options: Any, limit_bytes: int) -> None:
    """Refuse a render whose :func:`estimated_render_bytes` exceeds ``limit_bytes``."""
    needed = estimated_render_bytes(model, options)
    if needed > limit_bytes:
        gib = 1024**3
        height, width = model.shape
        raise ValueError(
            f"simulating a {width}x{height} px rig with supersample {options.supersample} needs "
            f"about {needed / gib:.2f} GiB, more than the limit of {limit_bytes / gib:.2f} GiB "
            "(GCPS_MAX_SIMULATION_BYTES); use a smaller rig or a lower supersample"
        )
