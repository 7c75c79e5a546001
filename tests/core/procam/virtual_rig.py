"""The known distorted pinhole rig of the procam calibration tests (800 x 600 camera, 1024 x 768
projector), its chessboard (9 x 6 inner corners, 20 mm squares), the 8 board poses planned to reach
the edges of both images (tests/core/procam/test_virtual_calibration.py tells how), the codec and
the rendering options, and the flatness of a plane measured with a rig."""

from __future__ import annotations

import functools

import numpy as np

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.model import Codec
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, look_at_rig
from metrology.core.procam import parse_board
from metrology.core.procam.virtual import BoardPose, plan_board_poses
from metrology.core.simulate import realistic_8bit

CAMERA = PinholeCamera(
    800, 600, ((1000.0, 0, 403.2), (0, 1001.0, 297.6), (0, 0, 1)), (-0.12, 0.08, 0.0008, -0.0005, 0.0)
)
PROJECTOR = PinholeProjector(
    1024, 768, ((1300.0, 0, 515.0), (0, 1300.0, 460.0), (0, 0, 1)), (0.04, -0.02, 0.0, 0.0, 0.0)
)
RIG = look_at_rig(CAMERA, PROJECTOR, (150.0, 10.0, -20.0), (0.0, 0.0, 500.0))
BOARD = parse_board("chessboard:9x6:20")
OPTIONS = realistic_8bit(supersample=2)
W, H = PROJECTOR.width - 1, PROJECTOR.height - 1
# (tilt_x, tilt_y, spin) degrees, and the projector point the board's outer corner reaches for
PLAN = [
    ((-14, 14, 20), (W, H / 4)),
    ((-20, 0, -20), (0, H / 2)),
    ((14, -14, -20), (0, H)),
    ((14, -14, -25), (W, H / 2)),
    ((-30, 0, -20), (W, 0)),
    ((14, -14, -25), (W, 0)),
    ((30, 0, 25), (0, H / 4)),
    ((21, -21, 20), (0, 3 * H / 4)),
]


@functools.cache
def planned_poses() -> tuple[BoardPose, ...]:
    """The board poses of :data:`PLAN` (:func:`plan_board_poses`), planned on first use: 0.6-1.7 s
    of CPU that every pytest worker paid while collecting when they were planned at import."""
    return tuple(plan_board_poses(RIG, BOARD, PLAN))


# the poses this test used before: boards around the middle of both images
CENTRAL_ANGLES = [
    (0, 0, 0),
    (25, 0, 5),
    (-25, 0, -5),
    (0, 25, 10),
    (0, -25, -10),
    (18, 18, 0),
    (-18, 18, 15),
    (18, -18, -15),
]
CENTRAL_SHIFTS = [
    (0, 0, 480),
    (-40, 30, 520),
    (40, -30, 450),
    (30, 40, 500),
    (-30, -40, 470),
    (50, 20, 530),
    (-50, -20, 490),
    (0, 40, 460),
]
CENTRAL = [BoardPose.from_angles(*a, s).centred(BOARD) for a, s in zip(CENTRAL_ANGLES, CENTRAL_SHIFTS, strict=True)]


def make_codec(width: int = 1024, height: int = 768, period: float = 32.0) -> Codec:
    def axis(first: int) -> dict[str, object]:
        return {
            "phase": [{"frames": list(range(first, first + 8)), "period": period}],
            "gray": {"frames": list(range(first + 8, first + 13)), "word": period, "origin": -0.5},
        }

    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 28,
            "projector": {"width": width, "height": height},
            "white": [26],
            "black": [27],
            "axes": {"u": axis(0), "v": axis(13)},
        }
    )


CODEC = make_codec()


def pose(i: int) -> BoardPose:
    return planned_poses()[i]


@functools.cache
def rendered_pose(i: int) -> np.ndarray:
    """``render_board(RIG, BOARD, pose(i), CODEC, OPTIONS, seed=i)``: the (28, 600, 800) uint8 stack
    of pose ``i``, rendered once per test process (4 to 30 s each, most of the procam tests' time)
    and shared by the tests that calibrate from these poses (tests/core/procam/test_virtual_calibration.py,
    tests/pipeline/test_pipeline_procam.py, which share an ``xdist_group`` so that they run in one
    worker). Read-only: a caller that wrote into it would change the others' input."""
    from metrology.core.procam.virtual import render_board

    images = render_board(RIG, BOARD, pose(i), CODEC, OPTIONS, seed=i)
    images.setflags(write=False)
    return images


def plane_flatness_mm(rig: PinholeRig, u: np.ndarray, v: np.ndarray) -> float:
    """RMS distance of the triangulated points to their total-least-squares plane, mm, after
    dropping points more than 5 robust sigmas (1.4826 MAD) off (the field's edge pixels)."""
    from metrology.core.geometry.base import triangulate_frame

    prepared = rig.prepare(rig.shape, (rig.projector.width, rig.projector.height))
    xyz = triangulate_frame(prepared, u, v, heights=False).points_mm
    pts = xyz.reshape(-1, 3).astype(np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    for _ in range(3):
        centred = pts - pts.mean(axis=0)
        normal = np.linalg.svd(centred, full_matrices=False)[2][2]
        r = centred @ normal
        robust = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        pts = pts[np.abs(r - np.median(r)) < 5 * robust]
    return float(np.sqrt(np.mean(r**2)))
