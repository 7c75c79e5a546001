"""The calibration's steps return values and leave their inputs alone.

Correspondences are exact projections of the distorted virtual rig of test_virtual_calibration.py
(:func:`metrology.core.procam.virtual.true_corners`) plus Gaussian noise, so nothing is rendered.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from metrology.core.procam import calibrate_procam
from metrology.core.procam.advice import CalibrationWarning, high_rms_warnings
from metrology.core.procam.poses import PoseObservation, select_usable_poses
from metrology.core.procam.virtual import BoardPose, true_corners

from .test_virtual_calibration import BOARD, CENTRAL, RIG

NOISE_PX = 0.05
"""Noise of every camera and projector point, pixels (projector units), per coordinate."""


def observe(name: str, pose: BoardPose, rng: np.random.Generator) -> PoseObservation:
    cam, prj = true_corners(RIG, BOARD, pose)
    noisy_cam = cam + rng.normal(0.0, NOISE_PX, cam.shape)
    return PoseObservation(name, noisy_cam, prj + rng.normal(0.0, NOISE_PX, prj.shape))


def calibrate(poses: list[PoseObservation]):  # type: ignore[no-untyped-def]
    return calibrate_procam(poses, BOARD, (800, 600), (1024, 768), fix_k3=True)


def central(rng: np.random.Generator) -> list[PoseObservation]:
    return [observe(f"c{i}", p, rng) for i, p in enumerate(CENTRAL)]


def test_the_given_poses_are_not_changed_and_the_result_has_them_as_judged() -> None:
    """A pose left out (reversed projector list), one with outlier corners and default board
    points: the given observations keep every field as it was (arrays included); the result's
    ``poses`` have the board points filled in, the reason and cause set and the outliers marked."""
    poses = central(np.random.default_rng(11))
    assert poses[3].projector_px is not None and poses[2].camera_px is not None
    poses[3] = PoseObservation("c3", poses[3].camera_px, poses[3].projector_px[::-1].copy())
    cam = poses[2].camera_px.copy()
    cam[[0, 20, 40], 0] += 3.0
    poses[2] = PoseObservation("c2", cam, poses[2].projector_px)
    given = copy.deepcopy(poses)
    result = calibrate(poses)
    for before, after in zip(given, poses, strict=True):
        for field in before.__dataclass_fields__:
            a, b = getattr(before, field), getattr(after, field)
            assert (a is None and b is None) or np.array_equal(a, b), (after.name, field)
    judged = {p.name: p for p in result.poses}
    assert [p.name for p in result.poses] == [p.name for p in poses]
    assert judged["c3"].cause == "corner_order_flipped" and judged["c3"].reason is not None
    assert judged["c2"].outliers is not None and list(np.flatnonzero(judged["c2"].outliers)) == [0, 20, 40]
    assert all(p.object_mm is not None and np.array_equal(p.object_mm, BOARD.object_points()) for p in result.poses)
    assert result.report["poses_used"] == 7


def test_select_usable_poses_returns_a_new_selection() -> None:
    """The first step fills the board points and sets reasons on copies; ``leave_out`` returns
    another selection and leaves the first as it was."""
    poses = central(np.random.default_rng(0))[:3]
    assert poses[1].projector_px is not None
    poses[1] = PoseObservation("c1", poses[1].camera_px, np.full_like(poses[1].projector_px, np.nan))
    selection = select_usable_poses(poses, BOARD)
    assert [p.name for p in selection.used] == ["c0", "c2"] and set(selection.masks) == {"c0", "c2"}
    assert selection.poses[1].cause == "poorly_decoded" and poses[1].reason is None and poses[0].object_mm is None
    fewer = selection.leave_out({"c2": "test"}, "corner_order_flipped")
    assert [p.name for p in fewer.used] == ["c0"] and [p.name for p in selection.used] == ["c0", "c2"]


@pytest.mark.parametrize(("camera", "projector", "expected"), [(0.5, 0.4, 0), (1.5, 0.4, 1), (0.5, float("nan"), 0)])
def test_high_rms_names_the_other_causes(camera: float, projector: float, expected: int) -> None:
    others = [CalibrationWarning("coverage", "m", "a"), CalibrationWarning("board_unit", "m", "a")]
    found = high_rms_warnings(camera, projector, others)
    assert len(found) == expected
    if found:
        assert found[0].message.endswith("; see the other warnings (board_unit, coverage)")
