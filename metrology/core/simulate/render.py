"""The virtual rig's one entry: a capture of any codec, through any geometric model.

:func:`render_capture` renders a scene (:mod:`metrology.core.scenes`) as a capture stack of a
codec and returns it with its ground truth; :func:`render_series` renders a stage series.

- On a model that reads the paper's light codes (:attr:`~metrology.core.geometry.base.GeometryModel.light_codes`)
  with the scene on its reference plane R, the paper's exact forward model renders it
  (:mod:`metrology.core.simulate.paper_rig`: area sampling of sub-rays, the projector's blur in
  code space): gcps-v1 stacks directly, any other codec rendered with one ray per pixel from
  its true light codes (:func:`~metrology.core.simulate.paper_rig.crossed_rig_truth`). This is the
  fast path, and the oracle every existing crossed-axes result was checked against
  (:func:`uses_paper_renderer` chooses it).
- Every other model (or placement) is ray cast through its seam (:mod:`metrology.core.simulate.cast`)
  and the codec's frames rendered from the true projector coordinates
  (:func:`~metrology.core.codecs.render.render_codec`). Without a placement, a model with a
  plane of its own takes the scene on it; one without (a pinhole camera) takes the scene's
  reference plane facing the camera at the distance where its field fills the image's width.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec, gcps_v1_codec, is_gcps_v1
from metrology.core.codecs.render import render_codec
from metrology.core.geometry.base import GeometryModel
from metrology.core.scenes import FIELD_WIDTH_MM, Scene, StageScene
from metrology.core.simulate.cast import CastTruth, ScenePlacement, cast_truth
from metrology.core.simulate.frames import RenderedCapture, _from_cast
from metrology.core.simulate.options import SimulationOptions, _is_int, camera_image
from metrology.core.simulate.paper_rig import (
    RenderedStack,
    crossed_rig_truth,
    paper_series,
    render_flat_frames,
    render_stack,
)
from metrology.core.simulate.series import series_seed, stack_seed

if TYPE_CHECKING:
    from metrology.core.simulate.stereo import StereoCast

FloatArray = npt.NDArray[np.float64]


def uses_paper_renderer(
    model: GeometryModel,
    codec: Codec | None,
    options: SimulationOptions,
    placement: ScenePlacement | None,
    scene: Scene | None = None,
) -> bool:
    """True when the paper's exact forward model renders the capture (module docstring): the one
    place that chooses it. It serves a model with light codes and a height-field scene on its
    plane, for gcps-v1 stacks, and for other codecs with one ray per pixel (it gives the true light
    codes of the pixel centres only; sub-pixel rays of another codec are cast). A triangle mesh
    (:class:`~metrology.core.scenes.MeshScene`) is always cast."""
    return (
        model.light_codes is not None
        and placement is None
        and (scene is None or scene.height_field)
        and (is_gcps_v1(codec) or options.supersample == 1)
    )


def default_placement(model: GeometryModel, field_width_mm: float = FIELD_WIDTH_MM) -> ScenePlacement:
    """The scene on the model's own plane (a model with a field centre there), or facing the camera
    at :meth:`~metrology.core.geometry.base.GeometryModel.scene_distance_mm`."""
    if model.scene_centre_x_mm is not None:
        return ScenePlacement.model_plane()
    return ScenePlacement.facing_camera(model.scene_distance_mm(field_width_mm))


def render_capture(
    model: GeometryModel,
    scene: Scene,
    codec: Codec | None = None,
    options: SimulationOptions | None = None,
    *,
    placement: ScenePlacement | None = None,
) -> RenderedCapture:
    """Render ``scene`` as a capture of ``codec`` through ``model`` (module docstring).

    Parameters
    ----------
    model : GeometryModel
    scene : Scene
    codec : Codec, optional
        The codec to render (None: gcps-v1, the paper's eleven patterns).
    options : SimulationOptions, optional
        Default noise-free 16-bit.
    placement : ScenePlacement, optional
        Where the scene's reference plane sits in the model frame (default :func:`default_placement`).

    The camera noise is seeded by :func:`~metrology.core.simulate.series.stack_seed` of the
    options and the scene, on either path.

    Raises
    ------
    ValueError
        On a scene that reaches the camera, or a codec the model's projector does not match.
    """
    opts = options if options is not None else SimulationOptions()
    if model.cameras > 1:
        return _render_cameras(model, scene, codec or gcps_v1_codec(), opts, placement or default_placement(model))
    noise_seed = stack_seed(opts, scene)
    if uses_paper_renderer(model, codec, opts, placement, scene):
        rendered = render_stack(model, scene, opts)  # type: ignore[arg-type]
        return _from_paper(model, rendered, codec, opts, noise_seed)
    if codec is None:  # the eleven patterns as a codec, at the built-in projector size
        codec = gcps_v1_codec()
    prepared = model.prepare(model.shape, (codec.projector_width, codec.projector_height))
    where = placement if placement is not None else default_placement(model)
    truth = cast_truth(prepared, scene, where)
    sub_rays = truth if opts.supersample == 1 else cast_truth(prepared, scene, where, supersample=opts.supersample)
    return _from_cast(scene, where, truth, sub_rays, codec, opts, noise_seed)


def _render_cameras(
    model: GeometryModel, scene: Scene, codec: Codec, opts: SimulationOptions, placement: ScenePlacement
) -> RenderedCapture:
    """A model of several cameras (a stereo rig): :func:`~metrology.core.simulate.stereo.render_stereo_capture`
    with its default projector (the rig's calibrated one, else a pinhole projector half-way between
    the cameras aimed at the scene), camera 0's capture carrying the others' stacks."""
    from metrology.core.geometry.stereo import StereoRig
    from metrology.core.simulate.stereo import render_stereo_capture

    if not isinstance(model, StereoRig):
        raise ValueError(f"the virtual rig renders two-camera stereo rigs, not a {model.short_label} rig")
    rendered = render_stereo_capture(model, scene, codec, opts, placement=placement)
    first, *others = rendered.cameras
    return replace(first, other_cameras=tuple(c.images for c in others))


def render_flats(
    model: GeometryModel,
    scene: Scene,
    options: SimulationOptions | None = None,
    *,
    placement: ScenePlacement | None = None,
    reflectance: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
    projector_size: tuple[int, int] | None = None,
    rays: CastTruth | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The noise-free camera images of ``scene`` under a white and under a black projector frame,
    through any model (the paper's light path where :func:`uses_paper_renderer` takes a gcps-v1
    stack: :func:`~metrology.core.simulate.paper_rig.render_flat_frames`, unless ``reflectance``
    or ``projector_size`` is given). ``reflectance``: a map ``rho(X, Y)`` over the scene
    coordinates replacing the scene's own albedo, e.g.
    :class:`~metrology.core.simulate.exposures.HdrReflectance`; ``projector_size``: the projector's
    (width, height) in its units, which bounds the lit field as the codec's frames do
    (:func:`~metrology.core.simulate.exposures.render_exposures` renders them on this path).
    ``rays``: the scene already cast on this path, ``cast_truth(model.prepare(model.shape,
    projector_size), scene, placement, supersample=options.supersample)`` (a caller rendering the
    flats at several exposures casts once; the same images).

    Elsewhere the scene is cast as :func:`render_capture` casts it (``options.supersample`` rays
    per pixel and axis): ``I = full_scale * albedo * (ambient + gain * lit * e)`` with ``e = 1``
    (white) or 0 (black), ``lit`` where the projector's image reaches the point unshadowed,
    area-averaged to pixels, then the camera's defocus blur.

    Returns
    -------
    white, black : (H, W) float64 arrays
        Grey levels of the output depth, unquantised and unclipped (the caller adds noise).
    """

    opts = options if options is not None else SimulationOptions()
    paper = reflectance is None and projector_size is None and uses_paper_renderer(model, None, opts, placement, scene)
    if paper and rays is None:
        return render_flat_frames(model, scene, opts)  # type: ignore[arg-type]
    if paper:
        raise ValueError("rays are cast on the cast path; the paper rig's flats trace their own")
    where = placement if placement is not None else default_placement(model)
    if rays is None:
        rays = cast_truth(model.prepare(model.shape, projector_size), scene, where, supersample=opts.supersample)
    else:
        rays.check_sub_rays(model.shape, opts.supersample)
    X, Y, _ = where.scene_coordinates(rays.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    rho = reflectance if reflectance is not None else scene.albedo
    albedo = np.where(hit, rho(np.where(hit, X, 0.0), np.where(hit, Y, 0.0)), 1.0)
    lit = np.isfinite(rays.u) | np.isfinite(rays.v)  # a model without a projector size gives no v
    height, width = model.shape
    frames = []
    for emitted in (1.0, 0.0):
        intensity = albedo * (opts.ambient + opts.projector_gain * lit * emitted) * float(opts.full_scale)
        img = camera_image(intensity, height, width, opts)
        frames.append(np.asarray(img, dtype=np.float64))
    return frames[0], frames[1]


def render_camera_flats(
    model: GeometryModel,
    scene: Scene,
    options: SimulationOptions | None = None,
    *,
    placement: ScenePlacement | None = None,
    reflectance: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
    cast: StereoCast | None = None,
) -> tuple[tuple[FloatArray, FloatArray], ...]:
    """Each camera's noise-free ``(white, black)`` images, camera 0 first: :func:`render_flats` for a
    model of one camera; for a stereo rig, :func:`render_flats` of each camera's pinhole rig with the
    projector that lights :func:`render_capture`'s stereo frames
    (:func:`~metrology.core.simulate.stereo.lighting_projector`, bounded by the rig's projector
    size), the scene placed in that camera's frame. ``reflectance``: as :func:`render_flats`'s, one
    map over the scene's coordinates for every camera (stereo rigs only). ``cast``: the stereo
    scene already cast with that projector (:func:`~metrology.core.simulate.stereo.cast_stereo` of
    ``placement``, its default projector and ``options.supersample``; what
    :func:`render_capture` casts): its sub-rays light the flats (the same images, no cast).

    Returns
    -------
    tuple of (white, black)
        One pair of ``(H_c, W_c)`` float64 arrays per camera, grey levels as :func:`render_flats`'s.
    """
    opts = options if options is not None else SimulationOptions()
    if model.cameras == 1:
        if reflectance is not None or cast is not None:
            raise ValueError("render_camera_flats takes a reflectance map or a cast for stereo rigs; use render_flats")
        return (render_flats(model, scene, opts, placement=placement),)
    from metrology.core.geometry.stereo import StereoRig
    from metrology.core.simulate.stereo import camera_rigs, lighting_projector

    if not isinstance(model, StereoRig):
        raise ValueError(f"the virtual rig renders two-camera stereo rigs, not a {model.short_label} rig")
    if cast is not None:
        cast.check_supersample(opts.supersample)
    where = placement if placement is not None else default_placement(model)
    size = (round(model.projector.width), round(model.projector.height))
    projector = lighting_projector(model, where, None)
    return tuple(
        render_flats(
            pinhole,
            scene,
            opts,
            placement=in_camera,
            reflectance=reflectance,
            projector_size=size,
            rays=None if cast is None else cast.sub_rays[index],
        )
        for index, (pinhole, in_camera) in enumerate(camera_rigs(model, where, projector))
    )


def render_series(
    model: GeometryModel,
    z_in_mm: Sequence[float],
    repeats: int,
    options: SimulationOptions | None = None,
    *,
    codec: Codec | None = None,
    scene_factory: Callable[[float], Scene] | None = None,
    placement: ScenePlacement | None = None,
) -> Iterator[tuple[float, int, RenderedCapture]]:
    """Render a stage series (paper section 5): ``repeats`` captures at each ``Z_in``, the plane
    moved along the reference plane's normal.

    Capture ``(i, r)`` is :func:`render_capture` of the stage scene at position ``i`` with
    ``options.seed = series_seed(seed, i, r)`` (so a series rendered capture by capture, as the
    application's jobs do, has the same images).

    Raises
    ------
    ValueError
        If ``repeats`` < 1 or a position is not finite (checked before rendering).
    """
    opts = options if options is not None else SimulationOptions()
    if not _is_int(repeats) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    positions = [float(z) for z in z_in_mm]
    for z in positions:
        if not math.isfinite(z):
            raise ValueError(f"z_in_mm must be finite, got {z!r}")
    factory: Callable[[float], Scene] = scene_factory or (lambda z: StageScene(z_in_mm=z))
    if uses_paper_renderer(model, codec, opts, placement):
        return (
            (z, r, _from_paper(model, stack, codec, stack.options, stack_seed(stack.options, stack.scene)))
            for z, r, stack in paper_series(model, positions, int(repeats), opts, factory)  # type: ignore[arg-type]
        )
    return _cast_series(model, positions, int(repeats), opts, codec, factory, placement)


def _cast_series(
    model: GeometryModel,
    positions: list[float],
    repeats: int,
    opts: SimulationOptions,
    codec: Codec | None,
    factory: Callable[[float], Scene],
    placement: ScenePlacement | None,
) -> Iterator[tuple[float, int, RenderedCapture]]:
    for index, z in enumerate(positions):
        for repeat in range(repeats):
            capture_opts = replace(opts, seed=series_seed(opts.seed, index, repeat))
            yield z, repeat, render_capture(model, factory(z), codec, capture_opts, placement=placement)


def _from_paper(
    model: GeometryModel,
    rendered: RenderedStack,
    codec: Codec | None,
    opts: SimulationOptions,
    seed: int | np.random.SeedSequence,
) -> RenderedCapture:
    prepared = model.prepare()
    points = prepared.points_from_heights(rendered.truth_mm.astype(np.float64))
    if is_gcps_v1(codec):
        u = rendered.codes
        v = np.full(u.shape, np.nan)
        images = rendered.images
    else:
        assert codec is not None
        u, v = crossed_rig_truth(rendered, model, codec.projector_width, codec.projector_height)  # type: ignore[arg-type]
        coded_u, coded_v = (u if "u" in codec.axes else None), (v if "v" in codec.axes else None)
        images = render_codec(codec, coded_u, coded_v, opts, seed=seed)
    return RenderedCapture(
        images=images,
        truth_mm=rendered.truth_mm,
        points_mm=points,
        u=u,
        v=v,
        edges=rendered.edges,
        codec=codec,
        options=opts,
    )
