"""The stereo model prepared: rectification, matching along epipolar lines, triangulation."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from metrology.core.geometry.base import GeometryError

if TYPE_CHECKING:
    from metrology.core.geometry.stereo import StereoRig


def prepare_stereo(rig: StereoRig, axis: str) -> Any:
    raise GeometryError("the stereo model does not measure yet (its rig file is read and checked)")
