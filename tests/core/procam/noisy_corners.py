"""Exact board points of the procam tests' known distorted rig (tests/core/procam/virtual_rig.py) in
six poses, plus Gaussian noise of known sigma, and their calibration with or without the joint
refinement: no rendering involved."""

from __future__ import annotations

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
SIGMA_PX = 0.1
"""Noise of every camera and projector point, pixels (projector units), per coordinate."""


def observations(rng: np.random.Generator | None) -> list[PoseObservation]:
    out = []
    for i, (angles, shift) in enumerate(POSES):
        pose = BoardPose.from_angles(*angles, shift).centred(BOARD)
        cam, prj = true_corners(RIG, BOARD, pose)
        if rng is not None:
            cam = cam + rng.normal(0.0, SIGMA_PX, cam.shape)
            prj = prj + rng.normal(0.0, SIGMA_PX, prj.shape)
        out.append(PoseObservation(f"pose{i}", cam, prj))
    return out


def calibrate(obs: list[PoseObservation], joint: bool):  # type: ignore[no-untyped-def]
    return calibrate_procam(obs, BOARD, (800, 600), (1024, 768), fix_k3=True, joint=joint)
