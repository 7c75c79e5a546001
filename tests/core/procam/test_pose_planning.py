"""Pose planning on the virtual rig: the board reaches a projector edge as far as both images allow,
seen whole by the camera and lit whole by the projector; the edges' angle to the pixel grid."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metrology.core.geometry.pinhole import look_at_rig
from metrology.core.procam.virtual import (
    BoardPose,
    board_in_view,
    board_outline_mm,
    edge_angles_deg,
    plan_board_poses,
    pose_reaching,
    project_points,
    true_corners,
)

from .virtual_rig import BOARD, CAMERA, PROJECTOR, RIG


def outline(pose: BoardPose) -> tuple[np.ndarray, np.ndarray]:
    """The printed board's outline in the camera (pixels) and the projector (projector units)."""
    return project_points(RIG, board_outline_mm(BOARD) @ pose.R.T + pose.t)


@pytest.mark.parametrize(("target", "axis", "edge"), [((1023, 383.5), 0, 1023), ((511.5, 767), 1, 767)])
def test_the_board_reaches_the_projector_edge(target: tuple[float, float], axis: int, edge: float) -> None:
    """Right and bottom edges: the outline ends within the 4 px margin plus one step of the search
    (1/50 of the way to the centre, about 10 px) of the edge, inside both images."""
    pose = pose_reaching(RIG, BOARD, (15, -15, 20), target)
    assert pose is not None and board_in_view(RIG, BOARD, pose)
    cam, prj = outline(pose)
    reach = np.abs(prj[:, axis] - edge).min()
    assert 4.0 <= reach + 0.5 <= 4.0 + 11.0, reach
    assert np.isfinite(cam).all() and cam.min() >= 3.5 and (cam <= [795.5, 595.5]).all()


def test_the_camera_stops_the_board_short_of_the_left_edge() -> None:
    """The projector's left edge is in the camera's view only near the camera, where the board
    barely fits in its image: the board stops at the camera image's edge, 117 px short."""
    pose = pose_reaching(RIG, BOARD, (15, -15, 20), (0, 383.5))
    assert pose is not None
    cam, prj = outline(pose)
    assert prj[:, 0].min() > 100
    assert min(cam[:, 0].min(), cam[:, 1].min()) < 3.5 + 11.0


def test_the_top_edge_is_out_of_the_cameras_view() -> None:
    """The camera does not see the projector's top 48 rows at any depth: the board stops short of
    the projector's top edge by more than that, at the camera's top edge instead."""
    pose = pose_reaching(RIG, BOARD, (15, -15, 20), (511.5, 0))
    assert pose is not None
    cam, prj = outline(pose)
    assert prj[:, 1].min() > 48
    assert cam[:, 1].min() < 3.5 + 11.0


@pytest.mark.slow
def test_no_pose_fits() -> None:
    big = replace(BOARD, size_mm=200.0)
    assert pose_reaching(RIG, big, (0, 0, 20), (1023, 383.5)) is None
    plan = [((0, 0, 20), (1023, 383.5)), ((0, 170, 20), (1023, 383.5))]  # the second faces away
    with pytest.raises(ValueError, match=r"plan\[1\]: the board at angles \(0, 170, 20\) fits"):
        plan_board_poses(RIG, BOARD, plan)


def test_board_in_view_refuses_a_board_aside_behind_or_facing_away() -> None:
    ahead = BoardPose.from_angles(0, 0, 20, (0, 0, 480)).centred(BOARD)
    assert board_in_view(RIG, BOARD, ahead)
    assert not board_in_view(RIG, BOARD, BoardPose(R=ahead.R, t=ahead.t + np.array([300.0, 0.0, 0.0])))
    assert not board_in_view(RIG, BOARD, BoardPose(R=ahead.R, t=-ahead.t))
    away = BoardPose.from_angles(0, 170, 20, (0, 0, 480)).centred(BOARD)
    assert not board_in_view(RIG, BOARD, away)


def test_edge_angles_of_a_fronto_parallel_board() -> None:
    """No distortion, fx = fy, the board square to the camera's axis and turned by the spin: every
    edge at the spin's angle to the pixel grid (folded into 0..45 degrees)."""
    square = ((1000.0, 0.0, 403.2), (0.0, 1000.0, 297.6), (0.0, 0.0, 1.0))
    plain = look_at_rig(
        replace(CAMERA, K=square, dist=()), replace(PROJECTOR, dist=()), (150.0, 10.0, -20.0), (0, 0, 500)
    )
    for spin, expected in ((20.0, 20.0), (-25.0, 25.0), (70.0, 20.0), (0.0, 0.0)):
        pose = BoardPose.from_angles(0, 0, spin, (0, 0, 480)).centred(BOARD)
        angles = edge_angles_deg(plain, BOARD, pose)
        assert angles.shape == (BOARD.rows * (BOARD.cols - 1) + BOARD.cols * (BOARD.rows - 1),)
        assert np.allclose(angles, expected, atol=1e-6), (spin, angles.min(), angles.max())
    cam, _ = true_corners(plain, BOARD, BoardPose.from_angles(0, 0, 0, (0, 0, 480)).centred(BOARD))
    assert np.allclose(cam[1] - cam[0], [1000.0 * 20.0 / 480.0, 0.0], atol=1e-6)
