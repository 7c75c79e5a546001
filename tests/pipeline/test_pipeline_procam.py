"""metrology.pipeline.calibrate_procam: options validated (ValueError naming the option), stacks of
virtual board renders observed with progress and calibrated to the known rig."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from metrology.pipeline.calibrate_procam import ProcamOptions, ProcamPose, calibrate_procam_stacks
from tests.core.procam.virtual_rig import CODEC, PROJECTOR, RIG, make_codec, rendered_pose

# the board renders are shared with tests/core/procam/test_virtual_calibration.py (rendered once per process)
RENDERS = pytest.mark.xdist_group("procam-board-renders")


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"board": "chessboard:9x6"}, "board"),
        ({"board": "chessboard:9x6:20", "window": 0}, "window must be 1..200"),
        ({"board": "chessboard:9x6:20", "min_decoded": 1.5}, "min_decoded must be within 0..1"),
        ({"board": "chessboard:9x6:20", "fix_k3": "yes"}, "fix_k3 must be true or false"),
        ({"board": "chessboard:9x6:20", "colour": 1}, "unknown procam calibration option"),
        ({"window": 10}, "board is required"),
    ],
)
def test_bad_options_are_named(data: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ProcamOptions.from_dict(data)


def test_options_round_trip() -> None:
    options = ProcamOptions(board="chessboard:9x6:20", window=12, min_decoded=0.3, fix_k3=True)
    assert ProcamOptions.from_dict(options.to_dict()) == options


def test_stacks_mismatch_is_named() -> None:
    images = np.zeros((CODEC.n_frames, 60, 80), np.uint8)
    other = np.zeros((CODEC.n_frames, 61, 80), np.uint8)
    options = ProcamOptions(board="chessboard:9x6:20")
    with pytest.raises(ValueError, match="pose b: image size"):
        calibrate_procam_stacks([ProcamPose("a", images, CODEC), ProcamPose("b", other, CODEC)], options)
    small = make_codec(width=800, height=600)
    with pytest.raises(ValueError, match="pose b: projector 800x600 differs from 1024x768"):
        calibrate_procam_stacks([ProcamPose("a", images, CODEC), ProcamPose("b", images, small)], options)
    with pytest.raises(ValueError, match="no poses"):
        calibrate_procam_stacks([], options)


@pytest.mark.slow
@RENDERS
def test_virtual_stacks_calibrate_with_progress() -> None:
    poses = [ProcamPose(f"p{i}", rendered_pose(i), CODEC) for i in range(6)]
    seen: list[tuple[int, str]] = []
    options = ProcamOptions(board="chessboard:9x6:20")
    result = calibrate_procam_stacks(poses, options, lambda percent, phase: seen.append((percent, phase)))
    assert seen == [(15 * i, f"observe p{i}") for i in range(6)] + [(90, "calibrate")]
    report = result.report
    assert report["poses_used"] == 6 and report["software_version"] == result.software_version
    assert set(report["timings_s"]) == {"observe", "calibrate"}
    assert result.camera_size == (800, 600) and result.projector_size == (1024, 768)
    K, Kt = np.asarray(result.rig.projector.K), np.asarray(PROJECTOR.K)
    assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.005 and abs(K[1, 1] / Kt[1, 1] - 1) < 0.005, K
    assert abs(np.linalg.norm(result.rig.T) / np.linalg.norm(RIG.T) - 1) < 0.005
    # linear virtual projector: the measured gamma (about 1) is written into the rig
    assert result.rig.projector.gamma is not None and abs(result.rig.projector.gamma - 1.0) < 0.1


@pytest.mark.slow
@RENDERS
def test_stacks_given_as_functions_are_read_one_at_a_time() -> None:
    """Poses whose images are functions are read in turn, and each stack is released before the
    next is read (weak references to the earlier stacks are dead when a loader runs); the result
    equals that of the same stacks given as arrays (to 1e-5, OpenCV's threads reorder sums)."""
    import gc
    import weakref

    def render(i: int) -> np.ndarray:
        """A stack of its own (the weak references below follow it), equal to a fresh render."""
        return rendered_pose(i).copy()

    alive: list[weakref.ref[np.ndarray]] = []
    still_held: list[int] = []

    def loader(i: int):  # type: ignore[no-untyped-def]
        def load() -> np.ndarray:
            gc.collect()
            still_held.extend(k for k, ref in enumerate(alive) if ref() is not None)
            images = render(i)
            alive.append(weakref.ref(images))
            return images

        return load

    options = ProcamOptions(board="chessboard:9x6:20")
    seen: list[tuple[int, str]] = []
    lazy = calibrate_procam_stacks(
        [ProcamPose(f"p{i}", loader(i), CODEC) for i in range(3)], options, lambda p, s: seen.append((p, s))
    )
    assert still_held == [] and len(alive) == 3
    assert seen == [(30 * i, f"{verb} p{i}") for i in range(3) for verb in ("read", "observe")] + [(90, "calibrate")]
    assert set(lazy.report["timings_s"]) == {"read", "observe", "calibrate"}
    eager = calibrate_procam_stacks([ProcamPose(f"p{i}", render(i), CODEC) for i in range(3)], options)
    np.testing.assert_allclose(np.asarray(lazy.rig.projector.K), np.asarray(eager.rig.projector.K), atol=1e-5)
    np.testing.assert_allclose(np.asarray(lazy.rig.T), np.asarray(eager.rig.T), atol=1e-5)
