"""The joint stereo refinement of both devices' intrinsics, and the standard deviations it reports.

Correspondences are the true board points of a known distorted pinhole rig (exact projections,
:func:`metrology.core.procam.virtual.true_corners`) plus Gaussian noise of known sigma, so the
spread of the calibrated values over repeated draws is the truth the reported standard
deviations must match. Rendering is not involved (tests/core/procam/test_virtual_calibration.py
covers the images).
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.procam.calibrate import PoseObservation
from metrology.core.procam.virtual import BoardPose, true_corners

from .noisy_corners import POSES, SIGMA_PX, calibrate, observations
from .virtual_rig import BOARD, CAMERA, PROJECTOR, RIG  # the distorted rig


def test_noise_free_round_trip_is_exact_with_and_without_joint_refinement() -> None:
    """OpenCV takes the points as float32 (a rounding of 3e-5 px at 1000 px, i.e. an RMS of
    1.7e-5 px): the fit returns the truth to 1e-3 px in K, 2e-5 in distortion and 1e-3 mm in T
    (measured 1.0e-4 px camera, 4.7e-4 px projector, 7.8e-5 mm)."""
    for joint in (True, False):
        result = calibrate(observations(None), joint)
        got = result.rig
        for dev, truth in ((got.camera, CAMERA), (got.projector, PROJECTOR)):
            np.testing.assert_allclose(np.asarray(dev.K), np.asarray(truth.K), atol=1e-3)  # pixels
            np.testing.assert_allclose(dev.dist[:4], truth.dist[:4], atol=2e-5)
        np.testing.assert_allclose(np.asarray(got.T), np.asarray(RIG.T), atol=1e-3)  # mm
        assert result.report["stereo_rms_px"] < 5e-5
        assert result.report["intrinsics_refined_jointly"] is joint


@pytest.mark.slow
def test_reported_standard_deviations_match_the_spread_over_noise_draws() -> None:
    """40 draws of 0.1 px noise: the reported sigma of fx, fy, cx, cy (both devices) agree with the
    draws' spread within 35 % (the spread of 40 draws is itself uncertain by about 11 %), and the
    joint refinement's projector focal length scatters less than the per-device fit's."""
    rng = np.random.default_rng(7)
    keys = ("fx", "fy", "cx", "cy")
    values: dict[bool, dict[str, list[float]]] = {True: {}, False: {}}
    reported: dict[str, list[float]] = {}
    for _ in range(40):
        obs = observations(rng)
        for joint in (True, False):
            result = calibrate([PoseObservation(p.name, p.camera_px, p.projector_px) for p in obs], joint)
            for device, model in (("camera", result.rig.camera), ("projector", result.rig.projector)):
                K = np.asarray(model.K)
                for key, value in zip(keys, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), strict=True):
                    values[joint].setdefault(f"{device}.{key}", []).append(float(value))
                    if joint:
                        reported.setdefault(f"{device}.{key}", []).append(result.report[device]["std"][key])
    for name, draws in values[True].items():
        spread = float(np.std(draws, ddof=1))
        claimed = float(np.median(reported[name]))
        assert 0.65 < claimed / spread < 1.35, (name, claimed, spread)
        truth = {"camera": CAMERA, "projector": PROJECTOR}[name.split(".")[0]]
        K = np.asarray(truth.K)
        true_value = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}[name.split(".")[1]]
        assert abs(np.mean(draws) - true_value) < 4 * spread / np.sqrt(len(draws)) + 0.05, name  # unbiased
    assert np.std(values[True]["projector.fx"]) < np.std(values[False]["projector.fx"])


def test_leave_one_out_predicts_clean_poses_to_the_noise_and_flags_a_pose_that_moved() -> None:
    """Clean draws: every pose left out is predicted within 3 sigma-ish of the corner noise (RMS
    below 0.35 px for 0.1 px per coordinate) and no pose is flagged. Then pose 3's board moves by
    3 mm between its white frame (camera corners) and its fringes (projector corners): it alone is
    flagged ``inconsistent_pose``."""
    rng = np.random.default_rng(3)
    clean = calibrate(observations(rng), joint=True).report
    values = clean["leave_one_out"]["projector_rms_px"]
    assert len(values) == len(POSES) and max(values.values()) < 0.35, values
    assert "inconsistent_pose" not in {w["cause"] for w in clean["warnings"]}

    obs = observations(rng)
    angles, shift = POSES[3]
    moved = BoardPose.from_angles(*angles, np.add(shift, (3.0, 0.0, 0.0))).centred(BOARD)
    _, prj = true_corners(RIG, BOARD, moved)
    obs[3] = PoseObservation("pose3", obs[3].camera_px, prj + rng.normal(0.0, SIGMA_PX, prj.shape))
    report = calibrate(obs, joint=True).report
    flagged = [w["poses"] for w in report["warnings"] if w["cause"] == "inconsistent_pose"]
    assert flagged == [["pose3"]], report["leave_one_out"]
