"""A small stereo rig for the application's tests (not a test module): two 160x120 distorted cameras
150 mm apart, the projector of :mod:`tests.stereo_rig` between them (not calibrated in the rig file),
scenes facing camera 0 at 500 mm (pixels of about 1 mm), and noise-free 16-bit captures of it zipped
in memory as ``cam0/``, ``cam1/`` with ``codec.json`` at the top."""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np

from metrology.core.codecs.stack import write_camera_stacks
from metrology.core.geometry.pinhole import PinholeCamera, look_at_rig
from metrology.core.geometry.stereo import StereoProjector, StereoRig
from metrology.core.scenes import make_scene
from metrology.core.simulate.stereo import StereoCapture, render_stereo_capture
from tests.stereo_rig import LENS, PLACEMENT, PROJ_H, PROJ_W, PROJECTOR, Z0, codec, codec_dict

CODEC = codec_dict("u")
CAMERA0 = PinholeCamera(
    160, 120, ((500.0, 0.0, 79.6), (0.0, 500.5, 59.4), (0.0, 0.0, 1.0)), (-0.1, 0.05, 0.0006, -0.0004, 0.0)
)
CAMERA1 = PinholeCamera(
    160, 120, ((497.0, 0.0, 80.6), (0.0, 498.0, 58.9), (0.0, 0.0, 1.0)), (-0.08, 0.03, -0.0003, 0.0005, 0.0)
)
_POSE1 = look_at_rig(CAMERA1, LENS, (150.0, 4.0, 8.0), (0.0, 0.0, Z0))
RIG = StereoRig(camera0=CAMERA0, camera1=CAMERA1, R=_POSE1.R, T=_POSE1.T, projector=StereoProjector(PROJ_W, PROJ_H))
"""The rig file of the tests' stereo rig (its projector's size only)."""


def _wide(camera: PinholeCamera) -> PinholeCamera:
    (fx, _, cx), (_, fy, cy), _row = camera.K
    return PinholeCamera(160, 120, ((fx * 0.32, 0.0, cx), (0.0, fy * 0.32, cy), (0.0, 0.0, 1.0)), camera.dist)


WIDE_RIG = StereoRig(
    camera0=_wide(CAMERA0), camera1=_wide(CAMERA1), R=_POSE1.R, T=_POSE1.T, projector=StereoProjector(PROJ_W, PROJ_H)
)
WIDE_CODEC = {
    "codec": "gcps-codec/1",
    "frames": 15,
    "projector": {"width": PROJ_W, "height": PROJ_H},
    "white": [13],
    "black": [14],
    "axes": {
        "u": {
            "phase": [{"frames": list(range(8)), "period": 64.0, "shift": 1, "origin": -0.5, "waveform": "sine"}],
            "gray": {"frames": list(range(8, 13)), "word": 64.0, "order": "msb_first", "origin": -0.5},
        }
    },
}
"""A coarser codec for :data:`WIDE_RIG` (periods of 64 projector px, about 10 of its camera pixels)."""
""":data:`RIG` with focal lengths of 160 px: the virtual rig's scenes (a field 500 mm wide) then sit at
500 mm, where its cameras converge (the application places scenes where camera 0 sees that field)."""


def render(scene: str, **params: float) -> StereoCapture:
    """Noise-free 16-bit frames of :data:`CODEC` of ``make_scene(scene, **params)`` facing camera 0
    at :data:`~tests.stereo_rig.Z0` mm, lit by :data:`~tests.stereo_rig.PROJECTOR`."""
    return render_stereo_capture(RIG, make_scene(scene, **params), codec("u"), placement=PLACEMENT, projector=PROJECTOR)


def cameras_zip(stacks: tuple[np.ndarray, ...] | list[np.ndarray]) -> bytes:
    """One stack per camera zipped as ``cam0/``, ``cam1/`` ... with :data:`CODEC`'s ``codec.json``."""
    with tempfile.TemporaryDirectory(prefix="gcps-stereo-") as tmp:
        path = write_camera_stacks(stacks, Path(tmp) / "capture.zip", codec("u"))
        return path.read_bytes()


def upload_file(data: bytes, name: str = "capture.zip") -> io.BytesIO:
    handle = io.BytesIO(data)
    handle.name = name
    return handle
