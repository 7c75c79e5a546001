"""Exact board points of the procam tests' known distorted rig (tests/core/procam/virtual_rig.py) in
six poses (or any others), plus Gaussian noise of known sigma, and their calibration with or
without the joint refinement: no rendering involved. ``FACING`` are five boards facing the camera
at one distance, which cannot tell the focal length from the distance."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from metrology.core.procam.calibrate import PoseObservation, calibrate_procam
from metrology.core.procam.virtual import BoardPose, true_corners

from .virtual_rig import BOARD, RIG

POSES = [
    ((0, 0, 0), (0, 0, 480)),
    ((25, 0, 5), (-40, 30, 520)),
    ((-25, 0, -5), (40, -30, 450)),
    ((0, 25, 10), (30, 40, 500)),
    ((0, -25, -10), (-30, -40, 470)),
    ((18, 18, 0), (50, 20, 530)),
]
FACING = [
    ((1.0, -0.5, 0.0), (0, 0, 500)),
    ((-1.2, 0.8, 15.0), (-60, 40, 500)),
    ((0.6, 1.4, -12.0), (60, -40, 500)),
    ((-0.8, -1.1, 8.0), (50, 50, 500)),
    ((1.3, 0.4, -18.0), (-50, -50, 500)),
]
"""Boards facing the camera (tilted at most 1.4 degrees, turned in their plane), all 500 mm away."""
SIGMA_PX = 0.1
"""Noise of every camera and projector point, pixels (projector units), per coordinate."""


def board_poses(plan: Sequence[tuple[tuple[float, float, float], tuple[float, float, float]]]) -> list[BoardPose]:
    """``(tilt_x, tilt_y, spin)`` degrees and a shift (mm) per pose: the boards, centred."""
    return [BoardPose.from_angles(*angles, shift).centred(BOARD) for angles, shift in plan]


def noisy(
    poses: Sequence[BoardPose], rng: np.random.Generator | None, sigma: float = SIGMA_PX
) -> list[PoseObservation]:
    """Each board's exact camera and projector points plus Gaussian noise ``sigma`` (none without ``rng``)."""
    out = []
    for i, pose in enumerate(poses):
        cam, prj = true_corners(RIG, BOARD, pose)
        if rng is not None:
            cam = cam + rng.normal(0.0, sigma, cam.shape)
            prj = prj + rng.normal(0.0, sigma, prj.shape)
        out.append(PoseObservation(f"pose{i}", cam, prj))
    return out


def observations(rng: np.random.Generator | None) -> list[PoseObservation]:
    """The six poses of ``POSES``, noise ``SIGMA_PX``."""
    return noisy(board_poses(POSES), rng)


def calibrate(obs: list[PoseObservation], joint: bool):  # type: ignore[no-untyped-def]
    return calibrate_procam(obs, BOARD, (800, 600), (1024, 768), fix_k3=True, joint=joint)
