"""The calibration's steps return values and leave their inputs alone; a warning cause that concerns
several poses (or pairs) gives one entry naming them all.

Correspondences are exact projections of the distorted virtual rig of test_virtual_calibration.py
(:func:`metrology.core.procam.virtual.true_corners`) plus Gaussian noise, so nothing is rendered.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from metrology.core.procam import calibrate_procam
from metrology.core.procam.advice import (
    CalibrationWarning,
    high_rms_warnings,
    inconsistent_pose_warnings,
    left_out_warnings,
    similar_poses_warnings,
)
from metrology.core.procam.diagnostics import PoseDiversity
from metrology.core.procam.poses import PoseObservation, select_usable_poses
from metrology.core.procam.virtual import BoardPose, true_corners
from tests.core.procam.virtual_rig import BOARD, CENTRAL, RIG

NOISE_PX = 0.05
"""Noise of every camera and projector point, pixels (projector units), per coordinate."""
DIVERSE = [
    ((25, 0, 5), (-40, 30, 520)),
    ((-25, 0, -5), (40, -30, 450)),
    ((0, 25, 10), (30, 40, 500)),
    ((0, -25, -10), (-30, -40, 470)),
]


def observe(name: str, pose: BoardPose, rng: np.random.Generator) -> PoseObservation:
    cam, prj = true_corners(RIG, BOARD, pose)
    noisy_cam = cam + rng.normal(0.0, NOISE_PX, cam.shape)
    return PoseObservation(name, noisy_cam, prj + rng.normal(0.0, NOISE_PX, prj.shape))


def calibrate(poses: list[PoseObservation]):  # type: ignore[no-untyped-def]
    return calibrate_procam(poses, BOARD, (800, 600), (1024, 768), fix_k3=True)


def entries(report: dict, cause: str) -> list[dict]:  # type: ignore[type-arg]
    return [w for w in report["warnings"] if w["cause"] == cause]


def test_twelve_poses_with_many_similar_pairs_give_one_similar_poses_entry() -> None:
    """Eight boards within a fraction of a degree and a few mm of each other, and four tilted 25
    degrees: the 28 near-identical pairs of the eight come as ONE ``similar_poses`` entry listing
    them (they were 28 entries), the same pairs as ``pose_diversity.near_identical_pairs``."""
    rng = np.random.default_rng(1)
    base = BoardPose.from_angles(5, -5, 20, (0, 0, 480)).centred(BOARD)
    poses = []
    for i in range(8):
        nudge = BoardPose.from_angles(0.3 * i, -0.2 * i, 0.1 * i, (0, 0, 0)).R
        twin = BoardPose(R=base.R @ nudge, t=base.t + np.array([0.5 * i, -0.4 * i, 0.8 * i]))
        poses.append(observe(f"s{i}", twin, rng))
    poses += [observe(f"d{i}", BoardPose.from_angles(*a, t).centred(BOARD), rng) for i, (a, t) in enumerate(DIVERSE)]
    report = calibrate(poses).report
    assert report["poses_used"] == 12
    similar = entries(report, "similar_poses")
    assert len(similar) == 1, similar
    (entry,) = similar
    expected = [[f"s{a}", f"s{b}"] for a in range(8) for b in range(a + 1, 8)]
    assert entry["pairs"] == expected == report["pose_diversity"]["near_identical_pairs"]
    assert entry["poses"] == [f"s{i}" for i in range(8)]
    assert entry["message"].startswith("28 pairs of poses are near-identical")
    assert all(f"({a}, {b})" in entry["message"] for a, b in expected)
    assert set(entry) == {"cause", "message", "action", "poses", "pairs"} and "each pair" in entry["action"]


def central(rng: np.random.Generator) -> list[PoseObservation]:
    return [observe(f"c{i}", p, rng) for i, p in enumerate(CENTRAL)]


def test_poses_left_out_for_one_cause_give_one_entry_each() -> None:
    """Of eight poses two have no board and two a reversed projector list: one ``board_not_found``
    entry for the two, one ``corner_order_flipped`` entry for the other two (its reason stated once
    for both), in the order of their first poses, and four poses used."""
    poses = central(np.random.default_rng(2))
    for i in (1, 6):
        poses[i] = PoseObservation(poses[i].name, None, None)
    for i in (2, 5):
        assert poses[i].projector_px is not None
        poses[i] = PoseObservation(poses[i].name, poses[i].camera_px, poses[i].projector_px[::-1].copy())
    report = calibrate(poses).report
    assert report["poses_used"] == 4
    left_out = [w for w in report["warnings"] if w["cause"] in ("board_not_found", "corner_order_flipped")]
    assert [(w["cause"], w["poses"]) for w in left_out] == [
        ("board_not_found", ["c1", "c6"]),
        ("corner_order_flipped", ["c2", "c5"]),
    ]
    assert left_out[0]["message"] == (
        "poses c1 and c6: the board was not found in their board images; these poses are left out."
    )
    flipped = left_out[1]["message"]
    assert flipped.startswith("poses c2 and c5: corner order mirrored or flipped (c2 and c5: corner order flipped")
    assert flipped.count("camera-to-projector rotation") == 1, flipped
    causes = [p["cause"] for p in report["poses"] if not p["used"]]
    assert causes == ["board_not_found", "corner_order_flipped", "corner_order_flipped", "board_not_found"]


def test_outlier_poses_give_one_entry_with_their_counts() -> None:
    """Two poses with a quarter of their camera corners moved by 2 px: one ``outlier_corners``
    entry naming both, with each one's count of outlier corners."""
    poses = central(np.random.default_rng(5))
    for i in (1, 4):
        assert poses[i].camera_px is not None
        cam = poses[i].camera_px.copy()
        cam[i::4, 0] += 2.0
        poses[i] = PoseObservation(poses[i].name, cam, poses[i].projector_px)
    report = calibrate(poses).report
    (entry,) = entries(report, "outlier_corners")
    assert entry["poses"] == ["c1", "c4"]
    counts = [sum(1 for c in report["poses"][i]["corners"] if c.get("outlier")) for i in (1, 4)]
    assert entry["message"].startswith(f"poses c1 and c4: {counts[0]} of 54 and {counts[1]} of 54 corners disagree")
    assert all(not report["poses"][i]["used"] for i in (1, 4))


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


def test_inconsistent_poses_give_one_entry_with_each_ones_figures() -> None:
    loo = {"a": 0.2, "b": 5.0, "c": 0.2, "d": 0.2, "e": 4.0, "f": float("nan")}
    (entry,) = inconsistent_pose_warnings(loo)
    assert entry.cause == "inconsistent_pose" and entry.poses == ("b", "e")
    assert entry.message.startswith("poses b and e are not predicted by the other poses")
    assert entry.message.endswith("left out in turn: b 5.00 px against 0.20 px, e 4.00 px against 0.20 px.")
    (one,) = inconsistent_pose_warnings({"a": 0.2, "b": 5.0, "c": 0.25, "d": 0.22})
    assert one.poses == ("b",) and one.message.startswith("pose b is not predicted by the other poses")
    assert inconsistent_pose_warnings({"a": 0.2, "b": 0.3}) == []


def test_a_single_similar_pair_keeps_its_message() -> None:
    diversity = PoseDiversity(
        names=("p0", "p1", "p2"),
        tilts_deg=(20.0, 20.5, 40.0),
        max_angle_deg=30.0,
        similar_pairs=(("p0", "p1"),),
        distances_mm=(500.0, 501.0, 480.0),
    )
    (entry,) = similar_poses_warnings(diversity, 3)
    assert entry.to_dict() == {
        "cause": "similar_poses",
        "message": "poses p0 and p1 are near-identical (board orientations within 3.0 degrees and positions "
        "within 5%); the second adds almost nothing.",
        "action": "Replace one of them by a pose tilted by 20 to 40 degrees in another direction.",
        "poses": ["p0", "p1"],
        "pairs": [["p0", "p1"]],
    }
    narrow = PoseDiversity(("p0", "p1"), (1.0, 2.0), 4.0, (), (500.0, 500.0))
    (range_entry,) = similar_poses_warnings(narrow, 2)
    assert "span only 4.0 degrees" in range_entry.message and "poses" not in range_entry.to_dict()


def test_left_out_entries_come_in_the_order_of_their_first_pose() -> None:
    poses = [
        PoseObservation("a", None, None, reason="x", cause="poorly_decoded"),
        PoseObservation("b", None, None, reason="board not found in the board image", cause="board_not_found"),
        PoseObservation("c", None, None),
        PoseObservation("d", None, None, reason="y", cause="poorly_decoded"),
        PoseObservation("e", None, None, reason="z", cause="something else"),
    ]
    found = left_out_warnings(poses)
    assert [(w.cause, w.poses) for w in found] == [("poorly_decoded", ("a", "d")), ("board_not_found", ("b",))]
    assert found[0].message == (
        "poses a and d: too little of the board decoded (a: x; d: y); these poses are left out."
    )
    assert found[1].message == "pose b: the board was not found in its board image; the pose is left out."


@pytest.mark.parametrize(("camera", "projector", "expected"), [(0.5, 0.4, 0), (1.5, 0.4, 1), (0.5, float("nan"), 0)])
def test_high_rms_names_the_other_causes(camera: float, projector: float, expected: int) -> None:
    others = [CalibrationWarning("coverage", "m", "a"), CalibrationWarning("board_unit", "m", "a")]
    found = high_rms_warnings(camera, projector, others)
    assert len(found) == expected
    if found:
        assert found[0].message.endswith("; see the other warnings (board_unit, coverage)")
