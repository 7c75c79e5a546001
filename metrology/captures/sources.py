"""Where image stacks come from: one small interface, the virtual rig today.

A real camera/projector driver implements :class:`CaptureSource` (project a codec's patterns,
grab one frame each) and is registered in :data:`SOURCES`; nothing else changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from metrology.captures.simulation import (
    check_option_values,
    check_render_memory,
    check_scene_depth,
    check_scene_values,
)


@dataclass(frozen=True)
class CaptureRequest:
    """What to capture: the scene in front of the rig and the acquisition options."""

    role: str
    scene: Mapping[str, Any]
    options: Mapping[str, Any] = field(default_factory=dict)
    z_in_mm: float | None = None
    repeat: int = 0
    codec: Any = None
    """The codec to project (a :class:`~metrology.core.codecs.model.Codec`; None: gcps-v1)."""


@dataclass(frozen=True)
class AcquiredStack:
    """An acquired stack: ``images`` (frames, H, W) uint8/uint16 in the codec's order, and what is known of it."""

    images: np.ndarray
    bit_depth: int
    truth_mm: np.ndarray | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)
    other_cameras: tuple[np.ndarray, ...] = ()
    """A rig of several cameras: the stacks of cameras 1, 2, ... (``images`` and ``truth_mm`` are camera 0's)."""

    @property
    def camera_stacks(self) -> tuple[np.ndarray, ...]:
        """Every camera's stack, camera 0 first."""
        return (self.images, *self.other_cameras)


@runtime_checkable
class CaptureSource(Protocol):
    """A source of capture stacks for a rig."""

    name: str

    def check(self, rig, request: CaptureRequest) -> None:
        """Raise ``ValueError`` naming the problem if ``request`` cannot be captured (called before queueing)."""

    def acquire(self, rig, request: CaptureRequest) -> AcquiredStack:
        """Capture the stack (called in a worker)."""


class VirtualRigSource:
    """Renders the stack of any codec through any model with the core's virtual rig
    (:func:`metrology.core.simulate.render_capture`)."""

    name = "virtual"

    def _build(self, rig, request: CaptureRequest):
        from metrology.core.scenes import make_scene
        from metrology.core.simulate import SimulationOptions

        scene_spec = dict(request.scene)
        scene_name = scene_spec.pop("name", None)
        if not isinstance(scene_name, str) or not scene_name:
            raise ValueError('scene.name is required, e.g. {"name": "plane", ...}')
        if scene_name == "stage" and request.z_in_mm is not None:
            scene_spec.setdefault("z_in_mm", request.z_in_mm)
        check_scene_values(rig, scene_name, scene_spec)
        try:
            scene = make_scene(scene_name, rig=rig, **scene_spec)
        except TypeError as exc:
            raise ValueError(f"scene {scene_name!r}: {exc}") from None
        check_scene_depth(rig, scene_name, scene)
        try:
            options = SimulationOptions(**dict(request.options))
        except TypeError as exc:
            raise ValueError(f"simulation options: {exc}") from None
        check_option_values(options)
        return scene, options

    def check(self, rig, request: CaptureRequest) -> None:
        """Build the scene and options, and bound their values and the render's memory."""
        from django.conf import settings

        _scene, options = self._build(rig, request)
        check_render_memory(rig, options, settings.GCPS_MAX_SIMULATION_BYTES)

    def acquire(self, rig, request: CaptureRequest) -> AcquiredStack:
        from metrology.core.simulate import render_capture

        scene, options = self._build(rig, request)
        rendered = render_capture(rig, scene, request.codec, options)
        images = np.asarray(rendered.images)
        bit_depth = int(getattr(options, "bit_depth", 16 if images.dtype == np.uint16 else 8))
        truth = getattr(rendered, "truth_mm", None)
        return AcquiredStack(
            images=images,
            bit_depth=bit_depth,
            truth_mm=truth,
            metadata={"source": self.name},
            other_cameras=tuple(np.asarray(other) for other in rendered.other_cameras),
        )


SOURCES: dict[str, CaptureSource] = {VirtualRigSource.name: VirtualRigSource()}


def get_source(name: str) -> CaptureSource:
    try:
        return SOURCES[name]
    except KeyError:
        raise ValueError(f"unknown capture source {name!r}; known: {', '.join(sorted(SOURCES))}") from None
