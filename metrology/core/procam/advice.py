"""The report's warnings: what went wrong, in plain words, and what to do; one function per cause.

Each function returns its cause's entries (:class:`CalibrationWarning`), an empty list when all
is well. A cause that concerns several poses gives one entry naming them all: ``poses`` lists them
in pose order (``board_not_found``, ``poorly_decoded``, ``corner_order_flipped``,
``outlier_corners``, ``inconsistent_pose``, ``projector_mismatch``), and the near-identical poses'
entry lists its pairs (``pairs``, each pair in pose order, ``poses`` the poses they hold). Entries
of one pose or pair say it as they always did; of several, their message lists each one's figures.

Two causes may give two entries, for different findings: ``similar_poses`` (near-identical pairs;
boards whose orientations span too little) and ``coverage`` (one per device). The table of
causes is in docs/procam-calibration.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.procam.board import BoardSpec
from metrology.core.procam.diagnostics import COVERAGE_CELLS, SIMILAR_ANGLE_DEG, SIMILAR_SHIFT, Coverage, PoseDiversity
from metrology.core.procam.poses import PoseObservation
from metrology.core.procam.rejection import outlier_reason
from metrology.core.procam.uncertainty import CORRELATION_LIMIT, DeviceUncertainty, Uncertainty

RECOMMENDED_POSES = 5
INCONSISTENT_POSE_RATIO = 3.0
INCONSISTENT_POSE_PX = 1.0
"""A pose is flagged when, left out, its projector corners are predicted worse than this ratio
times the other poses' median and than this many pixels (RMS)."""
MIN_TILT_RANGE_DEG = 15.0
MIN_COVERAGE = 0.3
MAX_EDGE_GAP = 0.2
"""The corners of all poses should come within this fraction of an image's width of its left and
right edges and of its height of its top and bottom edges; beyond, the distortion is extrapolated.
On the virtual rig of tests/core/procam/test_virtual_calibration.py (8 poses, corner noise
0.005 px in the camera and 0.0085 in the projector, 40 draws), poses leaving 20 %, 18 %, 28 % and
5 % of the projector image free at its left, right, top and bottom edges miss the distortion's
displacements over the whole image by 0.19 px (median; 0.34 px one time in ten); poses reaching
within 6 %, 6 %, 15 % and 10 % by 0.046 px (0.069 px)."""
MISMATCH_FRACTION = 0.02
GAMMA_TOLERANCE = 0.15
PLAUSIBLE_DISTANCE_MM = (100.0, 20000.0)
HIGH_RMS_PX = 1.0


@dataclass(frozen=True)
class CalibrationWarning:
    """One entry of the report's ``warnings``.

    Attributes
    ----------
    cause : str
        What kind of problem (the docs' table of causes).
    message : str
        What went wrong, naming the poses (or pairs) and the figures.
    action : str
        What to do.
    poses : tuple of str
        The poses it concerns, in pose order (empty: the whole calibration).
    pairs : tuple of (str, str)
        For ``similar_poses``: the near-identical pairs.
    """

    cause: str
    message: str
    action: str
    poses: tuple[str, ...] = ()
    pairs: tuple[tuple[str, str], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """``{cause, message, action}``, with ``poses`` and ``pairs`` (lists) when not empty."""
        entry: dict[str, Any] = {"cause": self.cause, "message": self.message, "action": self.action}
        if self.poses:
            entry["poses"] = list(self.poses)
        if self.pairs:
            entry["pairs"] = [list(pair) for pair in self.pairs]
        return entry


def _listing(items: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _left_out(poses: Sequence[PoseObservation], cause: str) -> list[PoseObservation]:
    return [p for p in poses if p.reason is not None and p.cause == cause]


def _left_out_message(found: Sequence[PoseObservation], one: str, many: str) -> str:
    """``pose a: ONE; the pose is left out.`` (``{reason}`` in ONE standing for the pose's reason), or
    for several ``poses a, b and c: MANY (a and c: their reason; b: its reason); these poses are
    left out.`` (each reason once, for its poses)."""
    if len(found) == 1:
        return f"pose {found[0].name}: {one.format(reason=found[0].reason)}; the pose is left out."
    by_reason: dict[str, list[str]] = {}
    for p in found:
        by_reason.setdefault(str(p.reason), []).append(p.name)
    reasons = "; ".join(f"{_listing(names)}: {reason}" for reason, names in by_reason.items())
    return f"poses {_listing([p.name for p in found])}: {many} ({reasons}); these poses are left out."


def _left_out_warnings(
    poses: Sequence[PoseObservation], cause: str, action: str, many: str, one: str = "{reason}"
) -> list[CalibrationWarning]:
    """One entry for the poses left out with ``cause`` (:func:`_left_out_message`), none without."""
    found = _left_out(poses, cause)
    if not found:
        return []
    return [CalibrationWarning(cause, _left_out_message(found, one, many), action, tuple(p.name for p in found))]


def board_not_found_warnings(poses: Sequence[PoseObservation]) -> list[CalibrationWarning]:
    """Poses left out because their board was not found (cause ``board_not_found``)."""
    names = [p.name for p in _left_out(poses, "board_not_found")]
    if not names:
        return []
    message = (
        f"pose {names[0]}: the board was not found in its board image; the pose is left out."
        if len(names) == 1
        else f"poses {_listing(names)}: the board was not found in their board images; these poses are left out."
    )
    action = (
        "Check the board spec (COLSxROWS counts inner corners, points per row first), that the whole "
        "board is in the camera's view, sharp and evenly lit in the white frame."
    )
    return [CalibrationWarning("board_not_found", message, action, tuple(names))]


def poorly_decoded_warnings(poses: Sequence[PoseObservation]) -> list[CalibrationWarning]:
    """Poses left out because too few of their corners' windows decoded (cause ``poorly_decoded``)."""
    action = (
        "Keep the whole board inside the projector's light, avoid shadows and glare, and raise the exposure "
        "or the projector brightness so the black squares are still decoded."
    )
    summary = "too little of the board decoded"
    return _left_out_warnings(poses, "poorly_decoded", action, summary, f"{summary} ({{reason}})")


def outlier_corners_warnings(poses: Sequence[PoseObservation]) -> list[CalibrationWarning]:
    """Poses left out for too many outlier corners (cause ``outlier_corners``); for several, the
    message gives each one's count of outlier corners in one sentence."""
    action = (
        "Look at the pose's board image: keep the whole board, with a margin, inside the camera's view and "
        "the projector's light, without glare, and keep it still during the sequence."
    )
    entries = _left_out_warnings(poses, "outlier_corners", action, "too many corners disagree with the calibration")
    found = _left_out(poses, "outlier_corners")
    outliers = [p.outliers for p in found if p.outliers is not None]
    if len(found) < 2 or len(outliers) < len(found):
        return entries
    counts = _listing([f"{int(o.sum())} of {o.size}" for o in outliers])
    message = f"poses {_listing([p.name for p in found])}: {outlier_reason(counts)}; these poses are left out."
    return [replace(entry, message=message) for entry in entries]


def corner_order_flipped_warnings(poses: Sequence[PoseObservation]) -> list[CalibrationWarning]:
    """Poses left out because their corner order is mirrored or flipped (cause ``corner_order_flipped``)."""
    action = (
        "Give the board's points in the same order for the camera and the projector (row by row, points "
        "per row first); in a correspondence file check that no pose has its projector list reversed."
    )
    return _left_out_warnings(poses, "corner_order_flipped", action, "corner order mirrored or flipped")


def left_out_warnings(poses: Sequence[PoseObservation]) -> list[CalibrationWarning]:
    """The warnings of the poses left out (the four causes above), in the order of each one's
    first pose. A pose left out with another cause, or none, gives no warning."""
    entries = [
        *board_not_found_warnings(poses),
        *poorly_decoded_warnings(poses),
        *outlier_corners_warnings(poses),
        *corner_order_flipped_warnings(poses),
    ]
    order = {p.name: index for index, p in enumerate(poses)}
    return sorted(entries, key=lambda w: order[w.poses[0]])


def too_few_poses_warnings(n_used: int) -> list[CalibrationWarning]:
    """Fewer than :data:`RECOMMENDED_POSES` poses used (cause ``too_few_poses``)."""
    if n_used >= RECOMMENDED_POSES:
        return []
    return [
        CalibrationWarning(
            "too_few_poses",
            f"only {n_used} poses were used; the intrinsics, above all the projector's, are poorly constrained.",
            f"Capture at least {RECOMMENDED_POSES} (better 8 to 12) poses, tilting the board in different directions.",
        )
    ]


def similar_poses_warnings(diversity: PoseDiversity, n_used: int) -> list[CalibrationWarning]:
    """Near-identical pairs of boards (one entry listing the pairs), and boards whose orientations
    span less than :data:`MIN_TILT_RANGE_DEG` (a second entry); cause ``similar_poses``."""
    entries = []
    pairs = diversity.similar_pairs
    if pairs:
        within = f"board orientations within {SIMILAR_ANGLE_DEG} degrees and positions within {SIMILAR_SHIFT:.0%}"
        if len(pairs) == 1:
            ((a, b),) = pairs
            message = f"poses {a} and {b} are near-identical ({within}); the second adds almost nothing."
            action = "Replace one of them by a pose tilted by 20 to 40 degrees in another direction."
        else:
            listed = ", ".join(f"({a}, {b})" for a, b in pairs)
            message = (
                f"{len(pairs)} pairs of poses are near-identical ({within}): {listed}; "
                "the second of each pair adds almost nothing."
            )
            action = "Replace one pose of each pair by a pose tilted by 20 to 40 degrees in another direction."
        in_pairs = {name for pair in pairs for name in pair}
        poses = tuple(name for name in diversity.names if name in in_pairs)
        entries.append(CalibrationWarning("similar_poses", message, action, poses, pairs))
    if n_used >= 2 and diversity.max_angle_deg < MIN_TILT_RANGE_DEG:
        entries.append(
            CalibrationWarning(
                "similar_poses",
                f"the board's orientations span only {diversity.max_angle_deg:.1f} degrees; "
                "focal length and distance cannot be told apart.",
                "Tilt the board by 20 to 40 degrees about both its axes across the poses.",
            )
        )
    return entries


def _coupled_figures(device: DeviceUncertainty) -> str:
    """``the camera's fx 1000.0 +- 25.3 px and the boards' mean distance from it 480.0 +- 12.1 mm are
    correlated 0.9993`` (``not determined at all`` for a singular covariance)."""
    focal = device.focal()
    if math.isnan(focal.distance_correlation):
        return f"the {device.device}'s focal length and the boards' distances are not determined at all (singular fit)"
    return (
        f"the {device.device}'s {focal.name} {focal.value:.1f} +- {focal.std:.3g} px and the boards' mean distance "
        f"from it {device.mean_distance_mm:.1f} +- {device.mean_distance_std_mm:.3g} mm are correlated "
        f"{focal.distance_correlation:.5f}"
    )


def focal_distance_coupled_warnings(uncertainty: Uncertainty) -> list[CalibrationWarning]:
    """Focal length and board distance not separable from the poses given (cause
    ``focal_distance_coupled``): a device's fx or fy correlated with the boards' mean distance
    beyond :data:`~metrology.core.procam.uncertainty.CORRELATION_LIMIT` in magnitude, or its
    covariance singular. One entry naming the devices, each with its figures."""
    coupled = uncertainty.coupled()
    if not coupled:
        return []
    figures = "; ".join(_coupled_figures(device) for device in coupled)
    message = (
        f"{figures} (beyond {CORRELATION_LIMIT} in magnitude): these poses do not tell a longer focal length from a "
        "farther board, so the focal length is known only as well as the boards' distance."
    )
    action = (
        "Tilt the board by 20 to 40 degrees about both of its axes across the poses (top towards and away from the "
        "camera, left and right side towards it) and vary its distance by 20 % or more; boards facing the camera "
        "do not separate the two at any distance."
    )
    return [CalibrationWarning("focal_distance_coupled", message, action)]


def inconsistent_pose_warnings(leave_one_out_px: Mapping[str, float | None]) -> list[CalibrationWarning]:
    """Poses the others do not predict (cause ``inconsistent_pose``): left out, a pose's projector
    corners are predicted worse (RMS, pixels) than :data:`INCONSISTENT_POSE_RATIO` times the median
    of the other poses' and than :data:`INCONSISTENT_POSE_PX`."""
    finite = {name: v for name, v in leave_one_out_px.items() if v is not None and math.isfinite(v)}
    found: list[tuple[str, float, float]] = []
    for name, value in finite.items():
        others = [v for n, v in finite.items() if n != name]
        typical = float(np.median(others)) if others else math.nan
        if others and value > max(INCONSISTENT_POSE_RATIO * typical, INCONSISTENT_POSE_PX):
            found.append((name, value, typical))
    if not found:
        return []
    if len(found) == 1:
        name, value, typical = found[0]
        message = (
            f"pose {name} is not predicted by the other poses: calibrated without it, the rig puts its projector "
            f"corners {value:.2f} px (RMS) from where they were decoded, against {typical:.2f} px for the "
            "other poses left out in turn."
        )
        action = (
            "Retake this pose or leave it out: the board or the rig may have moved during its sequence, or "
            "its corners are wrong (blur, reflections)."
        )
    else:
        figures = ", ".join(f"{name} {value:.2f} px against {typical:.2f} px" for name, value, typical in found)
        message = (
            f"poses {_listing([name for name, _, _ in found])} are not predicted by the other poses: calibrated "
            "without one of them, the rig puts its projector corners this far (RMS) from where they were decoded, "
            f"against the median of the other poses left out in turn: {figures}."
        )
        action = (
            "Retake these poses or leave them out: the board or the rig may have moved during their sequences, or "
            "their corners are wrong (blur, reflections)."
        )
    return [CalibrationWarning("inconsistent_pose", message, action, tuple(name for name, _, _ in found))]


def coverage_warnings(coverage: Coverage) -> list[CalibrationWarning]:
    """Per device, corners covering less than :data:`MIN_COVERAGE` of its image or stopping more
    than :data:`MAX_EDGE_GAP` short of one of its edges (cause ``coverage``; the camera's entry first)."""
    entries = []
    for cov, what in ((coverage.camera, "camera"), (coverage.projector, "projector")):
        far = {edge: g for edge, g in coverage.edge_gaps[what].items() if g > MAX_EDGE_GAP}
        if cov >= MIN_COVERAGE and not far:
            continue
        reasons = []
        if cov < MIN_COVERAGE:
            reasons.append(f"cover only {cov:.0%} of it (cells of an {COVERAGE_CELLS}x{COVERAGE_CELLS} grid)")
        if far:
            sides = [
                f"{g:.0%} of its {'width' if edge in ('left', 'right') else 'height'} to its {edge} edge"
                for edge, g in far.items()
            ]
            reasons.append(f"come no nearer than {_listing(sides)}")
        entries.append(
            CalibrationWarning(
                "coverage",
                f"in the {what} image the corners {' and '.join(reasons)}; the {what}'s distortion is extrapolated "
                "there.",
                f"Add poses that bring the board's corners within {MAX_EDGE_GAP:.0%} of every edge of the {what} "
                "image (as far as the camera sees and the projector lights), the board tilted by 20 to 40 degrees "
                "and turned 15 to 30 degrees in its plane.",
            )
        )
    return entries


def board_unit_warnings(median_distance_mm: float, baseline_mm: float, board: BoardSpec) -> list[CalibrationWarning]:
    """The boards' median distance outside :data:`PLAUSIBLE_DISTANCE_MM`: the square size is
    probably not in mm (cause ``board_unit``)."""
    lo, hi = PLAUSIBLE_DISTANCE_MM
    if lo <= median_distance_mm <= hi:
        return []
    return [
        CalibrationWarning(
            "board_unit",
            f"the board comes out {median_distance_mm:.4g} mm from the camera and the baseline {baseline_mm:.4g} mm: "
            "implausible for a bench rig, so the board's square size is probably in the wrong unit.",
            f"Give the square size in millimetres (now {board.size_mm:g}; a square of 2.5 cm is 25, of 1 inch 25.4).",
        )
    ]


def projector_mismatch_warnings(
    poses: Sequence[PoseObservation], projector_K: npt.NDArray[np.float64], projector_size: tuple[int, int]
) -> list[CalibrationWarning]:
    """Poses (used or not) with more than :data:`MISMATCH_FRACTION` of their decoded board pixels
    refused, or the projector's principal point (of ``projector_K``, (3, 3)) far outside its image
    (cause ``projector_mismatch``): the codec's projector size or periods are not the projected ones."""
    proj_w, proj_h = projector_size
    mismatched = [p.name for p in poses if p.mismatch_fraction is not None and p.mismatch_fraction > MISMATCH_FRACTION]
    pp = projector_K[:2, 2]
    pp_outside = not (-0.25 * proj_w <= pp[0] <= 1.25 * proj_w and -0.75 * proj_h <= pp[1] <= 1.75 * proj_h)
    if not mismatched and not pp_outside:
        return []
    fractions = ", ".join(
        f"{p.name} {p.mismatch_fraction:.0%}" for p in poses if p.name in mismatched and p.mismatch_fraction
    )
    refused = "decoded pixels refused as outside the projector or gray/phase inconsistent"
    detail = f"{refused}: {fractions}; " if fractions else ""
    return [
        CalibrationWarning(
            "projector_mismatch",
            f"{detail}projector principal point ({pp[0]:.0f}, {pp[1]:.0f}) for a declared {proj_w}x{proj_h} "
            "projector. The codec's projector size or fringe period does not match the patterns that were projected.",
            "Write the projector's real resolution and the periods and words of the projected patterns in the codec "
            "(regenerate the patterns from the codec to be sure), and project them at the native resolution.",
            tuple(mismatched),
        )
    ]


def gamma_warnings(gamma_estimate: float | None, precompensated: bool) -> list[CalibrationWarning]:
    """A response gamma off 1 by more than :data:`GAMMA_TOLERANCE`, unless the patterns were
    pre-compensated (cause ``gamma``)."""
    if gamma_estimate is None or precompensated or not abs(gamma_estimate - 1.0) > GAMMA_TOLERANCE:
        return []
    return [
        CalibrationWarning(
            "gamma",
            f"the projector-camera response is not linear (gamma about {gamma_estimate:.2f} from the fringes' mean "
            "against the white and black frames): sine fringes are distorted and phases carry a periodic error.",
            "Set the projector to a linear (gamma 1) mode, or pre-compensate the patterns for this gamma, or use "
            "gray codes with inverse images or more phase steps.",
        )
    ]


def high_rms_warnings(
    camera_rms_px: float, projector_rms_px: float, others: Sequence[CalibrationWarning]
) -> list[CalibrationWarning]:
    """A device's own RMS above :data:`HIGH_RMS_PX` (cause ``high_rms``), pointing at the causes of
    the ``others`` warnings."""
    if not (projector_rms_px > HIGH_RMS_PX or camera_rms_px > HIGH_RMS_PX):
        return []
    causes = sorted({w.cause for w in others})
    return [
        CalibrationWarning(
            "high_rms",
            f"reprojection error is high (camera {camera_rms_px:.2f} px, projector {projector_rms_px:.2f} px)"
            + (f"; see the other warnings ({', '.join(causes)})" if causes else ""),
            "Look at the per-pose RMS and leave out the worst poses; check the board size, the codec and focus.",
        )
    ]
