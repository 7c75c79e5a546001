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

from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.virtual import BoardPose, board_truth

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
