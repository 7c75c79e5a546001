"""What the virtual rig's renders return: :class:`RenderedCapture`, one camera's frames and ground
truth, and how a ray-cast truth becomes one (shared by :mod:`.render` and :mod:`.stereo`)."""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec
from metrology.core.codecs.render import render_codec
from metrology.core.scenes import Scene
from metrology.core.simulate.cast import CastTruth, ScenePlacement
from metrology.core.simulate.options import SimulationOptions
from metrology.core.simulate.paper_rig import EDGE_JUMP_MM

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class RenderedCapture:
    """One simulated capture of a codec and its ground truth per camera pixel.

    Attributes
    ----------
    images : (frames, H, W) uint8 or uint16 array
        Camera images in the codec's frame order.
    truth_mm : (H, W) float32 array
        Height above the scene's reference plane of the point each pixel centre sees, mm; NaN
        where the point is not lit by the coded field (shadow, outside the projector).
    points_mm : (H, W, 3) float64 array
        That point in the model frame, mm (NaN where not lit).
    u, v : (H, W) float64 arrays
        Its true projector coordinates, projector units (NaN where not lit; ``v`` NaN on the
        paper's rig rendered without a projector size).
    edges : (H, W) bool array
        Pixels at a depth discontinuity (a height jump of more than ``EDGE_JUMP_MM`` to a
        4-neighbour) or at a lit/unlit boundary.
    codec : Codec or None
        The codec rendered (None: gcps-v1).
    options : SimulationOptions
    other_cameras : tuple of (frames, H_c, W_c) arrays
        For a model of several cameras (:attr:`~metrology.core.geometry.base.GeometryModel.cameras`):
        the stacks of cameras 1, 2, ...; ``images`` and every truth are camera 0's. Empty otherwise.
    """

    images: np.ndarray
    truth_mm: npt.NDArray[np.float32]
    points_mm: FloatArray
    u: FloatArray
    v: FloatArray
    edges: npt.NDArray[np.bool_]
    codec: Codec | None
    options: SimulationOptions
    other_cameras: tuple[np.ndarray, ...] = ()

    @property
    def camera_stacks(self) -> tuple[np.ndarray, ...]:
        """Every camera's ``(frames, H_c, W_c)`` stack, camera 0 first (one for a one-camera model)."""
        return (self.images, *self.other_cameras)

    @property
    def capture(self) -> np.ndarray | tuple[np.ndarray, ...]:
        """What :func:`~metrology.core.measure.measure` takes: ``images`` for a one-camera model,
        else :attr:`camera_stacks`."""
        return self.images if not self.other_cameras else self.camera_stacks

    @property
    def lit(self) -> npt.NDArray[np.bool_]:
        """Pixels whose centre sees a lit point (``isfinite(truth_mm)``)."""
        return np.isfinite(self.truth_mm)

    @classmethod
    def from_truth(
        cls, images: np.ndarray, truth: CastTruth, codec: Codec | None, options: SimulationOptions
    ) -> RenderedCapture:
        """``images`` with the ground truth of the pixel centres' ``truth``: heights, points and
        projector coordinates, NaN where not lit, and the edges."""
        lit = truth.lit
        return cls(
            images=images,
            truth_mm=np.where(lit, truth.height_mm, np.nan).astype(np.float32),
            points_mm=np.where(lit[..., None], truth.points_mm, np.nan),
            u=truth.u,
            v=truth.v,
            edges=_edges(truth.height_mm, lit),
            codec=codec,
            options=options,
        )


def _edges(height: FloatArray, lit: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    edges = np.zeros(height.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        jump_x = (np.abs(np.diff(height, axis=1)) > EDGE_JUMP_MM) | (lit[:, 1:] != lit[:, :-1])
        jump_y = (np.abs(np.diff(height, axis=0)) > EDGE_JUMP_MM) | (lit[1:, :] != lit[:-1, :])
    edges[:, 1:] |= jump_x
    edges[:, :-1] |= jump_x
    edges[1:, :] |= jump_y
    edges[:-1, :] |= jump_y
    return edges


KEPT_ALBEDOS = 2
"""How many of the last albedo maps :func:`_kept_albedo` keeps (a stereo capture's two cameras)."""
_ALBEDOS: list[tuple[weakref.ref[Scene], weakref.ref[ScenePlacement], weakref.ref[CastTruth], FloatArray]] = []


def _kept_albedo(scene: Scene, placement: ScenePlacement, rays: CastTruth) -> FloatArray:
    """``(H s, W s)`` float64: the scene's albedo at the points the rays hit, 1 where they hit
    nothing. Kept for the last :data:`KEPT_ALBEDOS` (scene, placement, rays) objects, compared by
    identity and held weakly (a map is dropped with its rays): a kept cast rendered again with new
    noise (a Monte Carlo's renders, :func:`~metrology.core.simulate.stereo.render_stereo_capture`
    with ``cast``) does not recompute it. The kept map is read-only; a cast's arrays are not
    modified after the cast."""
    _ALBEDOS[:] = [entry for entry in _ALBEDOS if entry[2]() is not None]
    for kept_scene, kept_placement, kept_rays, albedo in _ALBEDOS:
        if kept_scene() is scene and kept_placement() is placement and kept_rays() is rays:
            return albedo
    X, Y, _ = placement.scene_coordinates(rays.points_mm)
    hit = np.isfinite(X) & np.isfinite(Y)
    albedo = np.where(hit, scene.albedo(np.where(hit, X, 0.0), np.where(hit, Y, 0.0)), 1.0)
    albedo.flags.writeable = False
    try:
        entry = (weakref.ref(scene), weakref.ref(placement), weakref.ref(rays, _drop_albedos), albedo)
    except TypeError:  # an object that cannot be referenced weakly (__slots__): not kept
        return albedo
    _ALBEDOS[:] = [*_ALBEDOS, entry][-KEPT_ALBEDOS:]
    return albedo


def _drop_albedos(_: object) -> None:
    """Forget the albedo maps of rays that no longer exist (their memory is freed with them)."""
    _ALBEDOS[:] = [entry for entry in _ALBEDOS if entry[2]() is not None]


def _from_cast(
    scene: Scene,
    placement: ScenePlacement,
    truth: CastTruth,
    sub_rays: CastTruth,
    codec: Codec,
    opts: SimulationOptions,
    seed: int | np.random.SeedSequence,
) -> RenderedCapture:
    """The codec's frames from the sub-rays' true coordinates, the truth from the pixel centres'."""
    albedo = _kept_albedo(scene, placement, sub_rays)
    images = render_codec(
        codec,
        sub_rays.u if "u" in codec.axes else None,
        sub_rays.v if "v" in codec.axes else None,
        opts,
        albedo=albedo,
        seed=seed,
    )
    return RenderedCapture.from_truth(images, truth, codec, opts)
