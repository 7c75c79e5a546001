"""High-dynamic-range scenes on the virtual rig: multi-exposure captures (docs/exposures.md).

The camera sees ``I = t * full_scale * rho(X, Y) * (ambient + gain * E_f)`` (grey levels, then
camera noise of ``noise_grey``, rounded and clipped to ``[0, full_scale]``: 8-bit captures
saturate at 255, 16-bit ones at 65535), with ``t = exposure_us * gain * projector_brightness /
unit_exposure_us`` the exposure relative to the one at which the plain renderer's radiometry holds,
and ``rho`` a reflectance map over the scene's coordinates (:class:`HdrReflectance`: a specular
patch on a dark matte part, a range of ``patch / matte_min``, 1000:1 by default). Geometry and
truth are those of :func:`~metrology.core.simulate.render.render_capture`'s cast path (any model,
any codec): every exposure sees the same scene, with independent noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec, gcps_v1_codec
from metrology.core.codecs.render import render_codec
from metrology.core.codecs.stack import ExposureStack
from metrology.core.geometry.base import GeometryModel
from metrology.core.io.exposures import Exposure
from metrology.core.scenes import Scene
from metrology.core.simulate.cast import ScenePlacement, cast_truth
from metrology.core.simulate.frames import RenderedCapture
from metrology.core.simulate.options import SimulationOptions
from metrology.core.simulate.render import default_placement
from metrology.core.simulate.series import stack_seed

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class HdrReflectance:
    """A specular patch on a dark matte part: reflectance over scene coordinates ``(X, Y)``, mm.

    The matte part's reflectance rises log-linearly along X from ``matte_min`` at ``x0_mm`` to
    ``matte_max`` at ``x1_mm`` (clamped beyond); a disk of ``patch_radius_mm`` around
    ``(patch_x_mm, patch_y_mm)`` reflects ``patch``. The range is ``patch / matte_min``.
    """

    x0_mm: float
    x1_mm: float
    patch_x_mm: float
    patch_y_mm: float
    patch_radius_mm: float
    matte_min: float = 0.001
    matte_max: float = 0.03
    patch: float = 1.0

    def __post_init__(self) -> None:
        if not (0 < self.matte_min <= self.matte_max and self.patch > 0 and self.x1_mm != self.x0_mm):
            raise ValueError("HdrReflectance needs 0 < matte_min <= matte_max, patch > 0 and x1_mm != x0_mm")

    @property
    def dynamic_range(self) -> float:
        """Largest over smallest reflectance."""
        return max(self.patch, self.matte_max) / min(self.patch, self.matte_min)

    def __call__(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        """Reflectance at ``(X, Y)``: float64 array of their broadcast shape."""
        x, y = np.asarray(X, np.float64), np.asarray(Y, np.float64)
        s = np.clip((x - self.x0_mm) / (self.x1_mm - self.x0_mm), 0.0, 1.0)
        rho = self.matte_min * (self.matte_max / self.matte_min) ** s
        in_patch = (x - self.patch_x_mm) ** 2 + (y - self.patch_y_mm) ** 2 <= self.patch_radius_mm**2
        return np.where(in_patch, self.patch, rho)

    @classmethod
    def spanning(cls, X: npt.ArrayLike, Y: npt.ArrayLike, **changes: float) -> HdrReflectance:
        """The default map over the lit scene coordinates ``X, Y`` (finite values): the ramp across
        X's extent, the patch at the centre with a quarter of Y's extent as radius."""
        x, y = np.asarray(X, np.float64), np.asarray(Y, np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        x0, x1 = float(x[ok].min()), float(x[ok].max())
        y0, y1 = float(y[ok].min()), float(y[ok].max())
        params: dict[str, float] = {
            "x0_mm": x0,
            "x1_mm": x1,
            "patch_x_mm": (x0 + x1) / 2,
            "patch_y_mm": (y0 + y1) / 2,
            "patch_radius_mm": (y1 - y0) / 4,
        }
        params.update(changes)
        return cls(**params)


def scene_reflectance(
    model: GeometryModel,
    scene: Scene,
    projector_size: tuple[int, int],
    *,
    placement: ScenePlacement | None = None,
    **changes: float,
) -> HdrReflectance:
    """The default map of :func:`render_exposures` (:meth:`HdrReflectance.spanning` the lit field
    of pixel centres, with ``changes``) for ``scene`` seen through ``model`` by a projector of
    ``projector_size`` (width, height): a fixed map, so that the frames of every exposure of a
    camera (the agent's virtual camera) see one part."""
    where = placement if placement is not None else default_placement(model)
    truth = cast_truth(model.prepare(model.shape, projector_size), scene, where)
    X, Y, _ = where.scene_coordinates(truth.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    return HdrReflectance.spanning(X[hit], Y[hit], **changes)


@dataclass(frozen=True, eq=False)
class RenderedExposures:
    """A rendered multi-exposure capture and its truth.

    Attributes
    ----------
    stack : ExposureStack
        One ``(frames, H, W)`` stack of ``truth.codec`` per exposure, least exposed first.
    truth : RenderedCapture
        The geometry's truth (``truth_mm``, ``points_mm``, ``u``, ``v``, ``edges``; its ``images``
        are the most exposed stack's).
    reflectance : (H, W) float64
        The reflectance each pixel's centre sees (NaN where not lit).
    relative_exposures : tuple of float
        ``t`` of each exposure (module docstring).
    """

    stack: ExposureStack
    truth: RenderedCapture
    reflectance: FloatArray
    relative_exposures: tuple[float, ...]


def render_exposures(
    model: GeometryModel,
    scene: Scene,
    exposures: Sequence[Exposure],
    codec: Codec | None = None,
    options: SimulationOptions | None = None,
    *,
    reflectance: HdrReflectance | None = None,
    unit_exposure_us: float = 1000.0,
    placement: ScenePlacement | None = None,
) -> RenderedExposures:
    """Render ``scene`` under ``reflectance`` at each exposure (module docstring).

    Parameters
    ----------
    model : GeometryModel
    scene : Scene
        Its geometry (its own reflectance is replaced by ``reflectance``).
    exposures : sequence of Exposure
        Any order; the stack holds them least exposed first.
    codec : Codec, optional
        Default gcps-v1 (the eleven patterns) at the built-in projector size.
    options : SimulationOptions, optional
        Default noise-free 16-bit. Exposure ``i``'s noise is seeded by the scene's seed and ``i``.
    reflectance : HdrReflectance, optional
        Default :meth:`HdrReflectance.spanning` the lit field (1000:1).
    unit_exposure_us : float
        The exposure time at which ``t = 1``, microseconds, > 0.
    placement : ScenePlacement, optional
        Default :func:`~metrology.core.simulate.render.default_placement`.
    """
    if not (math.isfinite(unit_exposure_us) and unit_exposure_us > 0):
        raise ValueError(f"unit_exposure_us must be a finite number > 0, got {unit_exposure_us!r}")
    if not exposures:
        raise ValueError("give at least one exposure")
    opts = options if options is not None else SimulationOptions()
    codec = codec if codec is not None else gcps_v1_codec()
    ordered = tuple(sorted(exposures, key=lambda e: (e.relative_exposure, e.name)))
    prepared = model.prepare(model.shape, (codec.projector_width, codec.projector_height))
    where = placement if placement is not None else default_placement(model)
    truth = cast_truth(prepared, scene, where)
    rays = truth if opts.supersample == 1 else cast_truth(prepared, scene, where, supersample=opts.supersample)
    X, Y, _ = where.scene_coordinates(rays.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    rho_map = reflectance if reflectance is not None else HdrReflectance.spanning(X[hit], Y[hit])
    albedo = np.where(hit, rho_map(np.where(hit, X, 0.0), np.where(hit, Y, 0.0)), 1.0)
    entropy = stack_seed(opts, scene).entropy
    base = [int(e) for e in np.ravel(np.asarray(entropy, dtype=object))]
    factors = tuple(e.relative_exposure / unit_exposure_us for e in ordered)
    stacks = tuple(
        render_codec(
            codec,
            rays.u if "u" in codec.axes else None,
            rays.v if "v" in codec.axes else None,
            opts,
            albedo=albedo * t,
            seed=np.random.SeedSequence([*base, index]),
        )
        for index, t in enumerate(factors)
    )
    lit = truth.lit
    Xc, Yc, _ = where.scene_coordinates(truth.points_mm)
    centre = np.where(lit, rho_map(np.where(lit, Xc, 0.0), np.where(lit, Yc, 0.0)), np.nan)
    rendered = RenderedCapture.from_truth(stacks[-1], truth, codec, opts)
    return RenderedExposures(ExposureStack(stacks, ordered), rendered, centre, factors)
