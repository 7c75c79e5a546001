"""Board-pose stacks of a known distorted pinhole rig, for the app's procam calibration tests.

A small rig (320x240 camera, fx 400, k1 -0.12; 320x240 projector, fx 420; baseline 122.07 mm)
sees a 7x5 inner-corner chessboard of 20 mm squares in six poses 290..330 mm away, tilted up to
25 degrees, rendered through the pinhole virtual rig (core/procam/virtual.py) with realistic 8-bit
noise and coded by an 8-step phase (period 16) + gray code on both axes (28 frames). The fourth
pose (index 3) puts a quarter of the board outside the camera image, so its board is not found:
the report has a ``board_not_found`` warning and five poses are used.
"""

from __future__ import annotations

import functools
import json

import numpy as np

from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, look_at_rig
from metrology.core.procam import parse_board
from metrology.core.procam.virtual import BoardPose, render_board
from metrology.core.simulate import realistic_8bit
from tests.app.stacks import SMALL_RIG, png, zip_bytes
from tests.shared_run import arrays_made_once

CAMERA = PinholeCamera(320, 240, ((400.0, 0, 161.3), (0, 400.4, 119.1), (0, 0, 1)), (-0.12, 0.08, 0.0008, -0.0005, 0.0))
PROJECTOR = PinholeProjector(320, 240, ((420.0, 0, 160.5), (0, 420.0, 150.0), (0, 0, 1)), (0.04, -0.02, 0.0, 0.0, 0.0))
TRUE_RIG: PinholeRig = look_at_rig(CAMERA, PROJECTOR, (120.0, 10.0, -20.0), (0.0, 0.0, 400.0))
BOARD_SPEC = "chessboard:7x5:20"
OPTIONS = {"fix_k3": True}  # six poses of a small board: k3 is not determined
ANGLES = [(0, 0, 0), (25, 0, 5), (-25, 0, -5), (0, 25, 10), (0, -25, -10), (18, 18, 0)]
SHIFTS = [(0, 0, 300), (-40, 25, 320), (40, -25, 290), (50, 50, 310), (-35, -30, 300), (40, 25, 330)]
UNUSABLE_POSE = 3

#: A crossed-axes rig of the camera's size: the rig the poses are uploaded to (then converted).
RIG_320 = {**SMALL_RIG, "width_px": 320, "height_px": 240}


def codec_dict(axes: str = "uv", width: int = 320, height: int = 240, period: float = 16.0) -> dict:
    """gcps-codec/1: an 8-step phase (``period``) and 5 gray-code bits per axis, then white and black."""
    coded: dict[str, dict] = {}
    for n, axis in enumerate(axes):
        first = 13 * n
        coded[axis] = {
            "phase": [{"frames": list(range(first, first + 8)), "period": period}],
            "gray": {"frames": list(range(first + 8, first + 13)), "word": period, "origin": -0.5},
        }
    frames = 13 * len(axes)
    return {
        "codec": "gcps-codec/1",
        "frames": frames + 2,
        "projector": {"width": width, "height": height},
        "white": [frames],
        "black": [frames + 1],
        "axes": coded,
    }


CODEC = codec_dict()


@functools.cache
def pose_stacks() -> tuple[np.ndarray, ...]:
    """The six poses' ``(28, 240, 320)`` uint8 stacks (seeded: the same on every call), rendered once
    per test run (1.6 s of CPU) and read by the run's other workers (tests/shared_run.py)."""
    return arrays_made_once("procam-pose-stacks", render_pose_stacks)


def render_pose_stacks() -> tuple[np.ndarray, ...]:
    """Render the six poses of :func:`pose_stacks`."""
    board = parse_board(BOARD_SPEC)
    codec = codec_from_dict(CODEC)
    options = realistic_8bit(supersample=2)
    return tuple(
        render_board(TRUE_RIG, board, BoardPose.from_angles(*a, s).centred(board), codec, options, seed=i)
        for i, (a, s) in enumerate(zip(ANGLES, SHIFTS, strict=True))
    )


def pose_zip(images: np.ndarray, codec: dict | None = CODEC) -> bytes:
    """A capture zip: ``frame00.png``... and the codec's ``codec.json``."""
    members = {f"frame{index:02d}.png": png(image) for index, image in enumerate(images)}
    if codec is not None:
        members["codec.json"] = json.dumps(codec).encode()
    return zip_bytes(members)


@functools.cache
def pose_zips() -> tuple[bytes, ...]:
    return tuple(pose_zip(images) for images in pose_stacks())


def pose_name(index: int) -> str:
    return f"pose{index}.zip"
