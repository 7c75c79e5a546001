"""High-dynamic-range scenes on the virtual rig: multi-exposure captures (docs/exposures.md).

The camera sees ``I = t * full_scale * rho(X, Y) * (ambient + gain * E_f)`` (grey levels, then
camera noise of ``noise_grey``, rounded and clipped to ``[0, full_scale]``: 8-bit captures
saturate at 255, 16-bit ones at 65535), with ``t = exposure_us * gain * projector_brightness /
unit_exposure_us`` the exposure relative to the one at which the plain renderer's radiometry holds,
and ``rho`` a reflectance map over the scene's coordinates (:class:`HdrReflectance`: a specular
patch on a dark matte part, a range of ``patch / matte_min``, 1000:1 by default). Geometry and
truth are those of :func:`~metrology.core.simulate.render.render_capture`'s cast path (any model,
any codec): every exposure sees the same scene, with independent noise. A stereo rig's cameras
(:func:`render_stereo_exposures`) see one reflectance map over the scene, each through
:func:`~metrology.core.simulate.stereo.cast_stereo`'s geometry.
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
from metrology.core.geometry.stereo import StereoRig
from metrology.core.io.exposures import Exposure
from metrology.core.scenes import Scene
from metrology.core.simulate.cast import CastTruth, ScenePlacement, cast_truth
from metrology.core.simulate.frames import RenderedCapture
from metrology.core.simulate.options import SimulationOptions
from metrology.core.simulate.render import default_placement
from metrology.core.simulate.series import stack_seed
from metrology.core.simulate.stereo import (
    ProjectorPlacement,
    StereoCapture,
    StereoCast,
    camera_rigs,
    cast_stereo,
    lighting_projector,
)

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
    camera (the agent's virtual camera) see one part. For a stereo rig, camera 0's field under the
    projector that lights its renders (:func:`render_stereo_exposures`)."""
    where = placement if placement is not None else default_placement(model)
    if model.cameras > 1:  # a stereo rig: camera 0's field, lit as render_stereo_exposures lights it
        if not isinstance(model, StereoRig):
            raise ValueError(f"the virtual rig renders two-camera stereo rigs, not a {model.short_label} rig")
        pinhole, where = camera_rigs(model, where, lighting_projector(model, where))[0]
        truth = cast_truth(pinhole.prepare(pinhole.shape, projector_size), scene, where)
    else:
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
    cast: tuple[CastTruth, CastTruth] | None = None,
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
    cast : (CastTruth, CastTruth), optional
        The scene already cast (:func:`cast_exposures`: the pixel centres' truth and the sub-pixel
        rays'), e.g. kept by a caller rendering one scene at several exposures: the same images.
    """
    ordered = _ordered(exposures, unit_exposure_us)
    opts = options if options is not None else SimulationOptions()
    codec = codec if codec is not None else gcps_v1_codec()
    where = placement if placement is not None else default_placement(model)
    truth, rays = cast if cast is not None else cast_exposures(model, scene, codec, opts.supersample, where)
    rays.check_sub_rays(model.shape, opts.supersample)
    rho_map = reflectance if reflectance is not None else _spanning(rays, where)
    factors = tuple(e.relative_exposure / unit_exposure_us for e in ordered)
    stacks = _exposure_frames(codec, rays, where, rho_map, factors, opts, _seed_base(opts, scene))
    rendered = RenderedCapture.from_truth(stacks[-1], truth, codec, opts)
    return RenderedExposures(
        ExposureStack(stacks, ordered), rendered, _centre_reflectance(truth, where, rho_map), factors
    )


def cast_exposures(
    model: GeometryModel, scene: Scene, codec: Codec, supersample: int, placement: ScenePlacement
) -> tuple[CastTruth, CastTruth]:
    """What :func:`render_exposures` renders from: ``scene`` at ``placement`` cast through ``model``
    prepared with ``codec``'s projector size, the pixel centres' truth and the ``supersample`` x
    ``supersample`` sub-pixel rays' (the truth itself when 1)."""
    prepared = model.prepare(model.shape, (codec.projector_width, codec.projector_height))
    truth = cast_truth(prepared, scene, placement)
    rays = truth if supersample == 1 else cast_truth(prepared, scene, placement, supersample=supersample)
    return truth, rays


def _ordered(exposures: Sequence[Exposure], unit_exposure_us: float) -> tuple[Exposure, ...]:
    """``exposures`` least exposed first, after checking ``unit_exposure_us`` and that there is one."""
    if not (math.isfinite(unit_exposure_us) and unit_exposure_us > 0):
        raise ValueError(f"unit_exposure_us must be a finite number > 0, got {unit_exposure_us!r}")
    if not exposures:
        raise ValueError("give at least one exposure")
    return tuple(sorted(exposures, key=lambda e: (e.relative_exposure, e.name)))


def _seed_base(opts: SimulationOptions, scene: Scene) -> list[int]:
    """The scene's noise entropy as a list of ints (exposure ``i`` seeds ``[*base, i]``)."""
    entropy = stack_seed(opts, scene).entropy
    return [int(e) for e in np.ravel(np.asarray(entropy, dtype=object))]


def _spanning(rays: CastTruth, where: ScenePlacement) -> HdrReflectance:
    """:meth:`HdrReflectance.spanning` the scene coordinates the rays hit."""
    X, Y, _ = where.scene_coordinates(rays.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    return HdrReflectance.spanning(X[hit], Y[hit])


def _exposure_frames(
    codec: Codec,
    rays: CastTruth,
    where: ScenePlacement,
    rho_map: HdrReflectance,
    factors: tuple[float, ...],
    opts: SimulationOptions,
    base: list[int],
) -> tuple[np.ndarray, ...]:
    """One ``(frames, H, W)`` stack of ``codec`` per relative exposure ``t`` of ``factors``: the
    rays' coordinates rendered under the albedo ``t * rho`` (1 where no ray hits), exposure ``i``'s
    noise seeded by ``[*base, i]``."""
    X, Y, _ = where.scene_coordinates(rays.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    albedo = np.where(hit, rho_map(np.where(hit, X, 0.0), np.where(hit, Y, 0.0)), 1.0)
    return tuple(
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


def _centre_reflectance(truth: CastTruth, where: ScenePlacement, rho_map: HdrReflectance) -> FloatArray:
    """(H, W) float64: the reflectance each lit pixel centre sees, NaN where not lit."""
    lit = truth.lit
    Xc, Yc, _ = where.scene_coordinates(truth.points_mm)
    return np.where(lit, rho_map(np.where(lit, Xc, 0.0), np.where(lit, Yc, 0.0)), np.nan)


@dataclass(frozen=True, eq=False)
class RenderedStereoExposures:
    """A rendered multi-exposure capture of a stereo rig and its truth.

    Attributes
    ----------
    stacks : (ExposureStack, ExposureStack)
        Each camera's exposures, camera 0 first (what :func:`~metrology.core.measure.measure`
        takes as the object of a stereo rig), the same exposures for both.
    capture : StereoCapture
        The geometry's truth per camera (its cameras' ``images`` are the most exposed stacks).
    reflectance : (H0, W0) float64
        The reflectance each pixel centre of camera 0 sees (NaN where not lit).
    relative_exposures : tuple of float
        ``t`` of each exposure (module docstring).
    """

    stacks: tuple[ExposureStack, ExposureStack]
    capture: StereoCapture
    reflectance: FloatArray
    relative_exposures: tuple[float, ...]

    @property
    def points_mm(self) -> FloatArray:
        """``(H0, W0, 3)`` float64: the point each camera-0 pixel centre sees, camera 0's frame, mm."""
        return self.capture.points_mm


def render_stereo_exposures(
    rig: StereoRig,
    scene: Scene,
    exposures: Sequence[Exposure],
    codec: Codec,
    options: SimulationOptions | None = None,
    *,
    placement: ScenePlacement,
    reflectance: HdrReflectance | None = None,
    unit_exposure_us: float = 1000.0,
    projector: ProjectorPlacement | None = None,
    cast: StereoCast | None = None,
) -> RenderedStereoExposures:
    """Render ``scene`` under ``reflectance`` at each exposure through both cameras of a stereo rig
    (:func:`~metrology.core.simulate.stereo.render_stereo_capture`'s geometry, this module's
    radiometry: ``I = t * full_scale * rho * (ambient + gain * E_f)``, clipped).

    Parameters
    ----------
    rig : StereoRig
    scene : Scene
        Its geometry (its own reflectance is replaced by ``reflectance``).
    exposures : sequence of Exposure
        Any order; each camera's stack holds them least exposed first.
    codec : Codec
        Its projector size must be the rig's.
    options : SimulationOptions, optional
        Default noise-free 16-bit. Camera 0's exposure ``i`` is seeded as :func:`render_exposures`
        seeds it, camera 1's by the scene's seed, 1 and ``i``.
    placement : ScenePlacement
        Where the scene's reference plane sits in camera 0's frame.
    reflectance : HdrReflectance, optional
        Over the scene's coordinates (one part for both cameras); default
        :meth:`HdrReflectance.spanning` the field camera 0 sees (1000:1).
    unit_exposure_us : float
        The exposure time at which ``t = 1``, microseconds, > 0.
    projector : ProjectorPlacement, optional
        Default :func:`~metrology.core.simulate.stereo.default_projector`.
    cast : StereoCast, optional
        The scene already cast (:func:`~metrology.core.simulate.stereo.cast_stereo` with
        ``options.supersample``).
    """
    ordered = _ordered(exposures, unit_exposure_us)
    opts = options if options is not None else SimulationOptions()
    if cast is None:
        cast = cast_stereo(rig, scene, codec, placement, projector=projector, supersample=opts.supersample)
    else:
        cast.check_supersample(opts.supersample)
    rho_map = reflectance if reflectance is not None else _spanning(cast.sub_rays[0], cast.placements[0])
    factors = tuple(e.relative_exposure / unit_exposure_us for e in ordered)
    base = _seed_base(opts, scene)
    stacks, cameras = [], []
    for index in range(2):
        frames = _exposure_frames(
            codec,
            cast.sub_rays[index],
            cast.placements[index],
            rho_map,
            factors,
            opts,
            [*base, index] if index else base,
        )
        stacks.append(ExposureStack(frames, ordered))
        cameras.append(RenderedCapture.from_truth(frames[-1], cast.truths[index], codec, opts))
    return RenderedStereoExposures(
        stacks=(stacks[0], stacks[1]),
        capture=StereoCapture(cameras=(cameras[0], cameras[1]), projector=cast.projector),
        reflectance=_centre_reflectance(cast.truths[0], cast.placements[0], rho_map),
        relative_exposures=factors,
    )
