"""A virtual stereo pair of known K, dist, R, T and chessboard images rendered through it (tests of
``gcps calibrate-stereo`` and of :mod:`metrology.core.stereo_calibration`).

Each camera's image is the board's albedo (``metrology.core.procam.virtual.board_truth``, anti-aliased,
2x2 supersampled and averaged) through that camera alone: camera 0 sees board pose ``(R_b, t_b)``,
camera 1 ``(R R_b, R t_b + T)``. Grey level ``20 + 220 albedo`` plus Gaussian noise, 8 bits.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.model import Codec
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, look_at_rig
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.virtual import BoardPose, board_truth, render_board
from metrology.core.simulate import realistic_8bit

WIDTH, HEIGHT = 320, 256
BOARD = BoardSpec("chessboard", 9, 7, 22.0)
K0 = np.array([[350.0, 0.0, 161.5], [0.0, 351.0, 126.0], [0.0, 0.0, 1.0]])
D0 = np.array([-0.12, 0.08, 0.0006, -0.0004, 0.0])
K1 = np.array([[362.0, 0.0, 157.0], [0.0, 361.5, 130.5], [0.0, 0.0, 1.0]])
D1 = np.array([-0.09, 0.05, -0.0005, 0.0007, 0.0])
C1 = np.array([110.0, 3.0, -4.0])
"""Camera 1's centre in camera 0's frame, mm."""
R1 = cv2.Rodrigues(np.array([0.015, np.radians(7.0), 0.01]))[0]
T1 = -R1 @ C1
"""Camera 1's pose: ``X_c1 = R1 X_c0 + T1``."""
PROJECTOR_SIZE = (1280.0, 800.0)

POSE_ANGLES: tuple[tuple[float, float, float, tuple[float, float, float]], ...] = (
    (0.0, 0.0, 5.0, (40.0, 0.0, 520.0)),
    (25.0, 0.0, -10.0, (0.0, -45.0, 500.0)),
    (-25.0, 5.0, 15.0, (80.0, 45.0, 540.0)),
    (5.0, 28.0, 0.0, (-10.0, 40.0, 480.0)),
    (-5.0, -28.0, 20.0, (90.0, -40.0, 520.0)),
    (20.0, 20.0, -20.0, (0.0, 45.0, 560.0)),
    (-20.0, -20.0, 10.0, (85.0, -45.0, 500.0)),
    (15.0, -18.0, 25.0, (40.0, 0.0, 600.0)),
)
"""Board poses: tilt about x, tilt about y, spin (degrees) and the board centre in camera 0's frame (mm)."""


def _camera_rig(K: np.ndarray, dist: np.ndarray) -> PinholeRig:
    """A pinhole rig whose camera is ``K, dist`` (its projector unused: only the albedo is rendered)."""
    k = tuple(tuple(float(x) for x in row) for row in K)
    return PinholeRig(
        camera=PinholeCamera(WIDTH, HEIGHT, k, tuple(float(x) for x in dist)),  # type: ignore[arg-type]
        projector=PinholeProjector(1280.0, 800.0, k),  # type: ignore[arg-type]
        R=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
        T=(100.0, 0.0, 0.0),
    )


def board_poses() -> list[BoardPose]:
    """:data:`POSE_ANGLES` as board poses in camera 0's frame."""
    return [BoardPose.from_angles(ax, ay, spin, t).centred(BOARD) for ax, ay, spin, t in POSE_ANGLES]


def render_camera(K: np.ndarray, dist: np.ndarray, pose: BoardPose, seed: int, noise: float = 1.0) -> np.ndarray:
    """One camera's 8-bit image ``(HEIGHT, WIDTH)`` of the board at ``pose`` (in that camera's frame)."""
    _, _, albedo = board_truth(_camera_rig(K, dist), BOARD, pose, supersample=2)
    grey = albedo.reshape(HEIGHT, 2, WIDTH, 2).mean(axis=(1, 3))
    rng = np.random.default_rng(seed)
    return np.clip(np.round(20.0 + 220.0 * grey + rng.normal(0.0, noise, grey.shape)), 0, 255).astype(np.uint8)


def render_pair(pose: BoardPose, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras' images of the board at ``pose`` (camera 0's frame)."""
    in_camera1 = BoardPose(R=R1 @ pose.R, t=R1 @ pose.t + T1)
    return render_camera(K0, D0, pose, seed), render_camera(K1, D1, in_camera1, seed + 1000)


@dataclass(frozen=True)
class StereoBoardCaptures:
    """Pose captures written to disk: ``folders[i]/cam0/board.png`` and ``folders[i]/cam1/board.png``."""

    folders: tuple[Path, ...]


def write_captures(root: Path, count: int = len(POSE_ANGLES)) -> StereoBoardCaptures:
    """The first ``count`` poses rendered and written as capture folders ``root/pose_NN/cam{0,1}/board.png``."""
    folders = []
    for i, pose in enumerate(board_poses()[:count]):
        folder = root / f"pose_{i:02d}"
        for camera, image in zip(("cam0", "cam1"), render_pair(pose, seed=i), strict=True):
            (folder / camera).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / camera / "board.png"), image)
        folders.append(folder)
    return StereoBoardCaptures(folders=tuple(folders))


# --------------------------------------------------------------------------- a projector between them
PROJECTOR = PinholeProjector(
    640, 400, ((520.0, 0.0, 322.0), (0.0, 521.0, 205.0), (0.0, 0.0, 1.0)), (0.03, -0.02, 0.0, 0.0, 0.0)
)
"""A distorted 640x400 projector for the codec-stack poses (``--projector``)."""
PROJECTOR_CENTRE = (55.0, -45.0, -10.0)
"""The projector's centre in camera 0's frame, mm (between the cameras, above them); it looks at
the boards' middle, ``(45, 0, 520)``."""


def projector_pose() -> tuple[np.ndarray, np.ndarray]:
    """The projector's pose ``X_p = R_p X_c0 + T_p``: ``(R_p (3, 3), T_p (3,))``."""
    rig = look_at_rig(_camera_rig(K0, D0).camera, PROJECTOR, PROJECTOR_CENTRE, (45.0, 0.0, 520.0))
    return np.asarray(rig.R, np.float64), np.asarray(rig.T, np.float64)


def make_stack_codec() -> Codec:
    """Both axes coded: 8-step phase of period 32 and 5 gray bits each, a white and a black frame."""

    def axis(first: int) -> dict[str, object]:
        return {
            "phase": [{"frames": list(range(first, first + 8)), "period": 32.0}],
            "gray": {"frames": list(range(first + 8, first + 13)), "word": 32.0, "origin": -0.5},
        }

    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 28,
            "projector": {"width": PROJECTOR.width, "height": PROJECTOR.height},
            "white": [26],
            "black": [27],
            "axes": {"u": axis(0), "v": axis(13)},
        }
    )


def render_stack_pair(pose: BoardPose, codec: Codec, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras' codec stacks ``(frames, HEIGHT, WIDTH)`` uint8 of the board at ``pose`` (camera
    0's frame), lit by :data:`PROJECTOR` (realistic 8-bit renders, one ray per pixel)."""
    R_p, T_p = projector_pose()
    options = realistic_8bit(supersample=1)
    stacks = []
    for k, (K, dist, R_c, T_c) in enumerate(((K0, D0, np.eye(3), np.zeros(3)), (K1, D1, R1, T1))):
        # the projector's pose from camera k: X_p = R_p R_c^T (X_ck - T_c) + T_p
        R = R_p @ R_c.T
        T = T_p - R @ T_c
        base = _camera_rig(K, dist)
        rig = PinholeRig(
            camera=base.camera,
            projector=PROJECTOR,
            R=tuple(tuple(float(x) for x in row) for row in R),  # type: ignore[arg-type]
            T=(float(T[0]), float(T[1]), float(T[2])),
        )
        in_camera = BoardPose(R=R_c @ pose.R, t=R_c @ pose.t + T_c)
        stacks.append(render_board(rig, BOARD, in_camera, codec, options, seed=seed * 2 + k))
    return stacks[0], stacks[1]
