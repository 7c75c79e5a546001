"""The poses of a calibration: what was observed of each, and which poses and corners are used.

- :class:`PoseObservation`: one board pose as observed (the calibration's input; the calibration
  never changes one, it returns changed copies);
- :class:`PoseSelection`: every pose of a calibration, each left out with its reason or used with
  the mask of its used corners; each step of the calibration returns a new selection
  (:func:`select_usable_poses` the first, :meth:`PoseSelection.leave_out` the others);
- :class:`FitPoints`: the used corners of the used poses, as OpenCV's calibrations take them
  (:func:`fit_points`).

A pose's points ``N`` are the board's, in its order (row by row, points per row first): board
points ``object_mm`` (mm, ``Z = 0``), camera points ``camera_px`` (pixels, centres at integers)
and projector points ``projector_px`` (projector units, NaN where a corner has no fit).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from metrology.core.procam.board import BoardSpec

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
Float32Array = npt.NDArray[np.float32]

MIN_DECODED_FRACTION = 0.25
"""A corner is usable when at least this fraction of its window is decoded (both axes)."""
MIN_USABLE_CORNERS = 0.9
"""A pose is used when at least this fraction of its corners is usable."""
MIN_POSE_CORNERS = 6
"""A pose is used only with at least this many used corners (OpenCV needs 4; 6 leaves a margin)."""
MIN_POSES = 2
"""Fewest usable poses a calibration needs."""


class ProcamCalibrationError(ValueError):
    """The poses cannot give a calibration (the message says why, pose by pose)."""


@dataclass(frozen=True)
class PoseObservation:
    """One board pose as seen by the camera and mapped into the projector.

    Attributes
    ----------
    name : str
    camera_px : (N, 2) float64 or None
        Board points in the camera, pixels; None when the board was not found.
    projector_px : (N, 2) float64 or None
        The same points in the projector, projector units; NaN rows where a corner has no fit.
    object_mm : (N, 3) float64 or None
        Board points, mm (default: the board spec's points; the calibration's returned poses
        have it filled in).
    decoded_fraction : (N,) float64 or None
        Decoded fraction of each corner's window (None: given correspondences, all usable).
    fit_rms : (N,) float64 or None
        RMS of each local homography's inliers, projector units.
    reason : str or None
        Why the pose cannot be used: set before calibration (board not found, ...) or, in the
        calibration's returned poses, by the calibration.
    mismatch_fraction : float or None
        Fraction of the board's decodable pixels refused as outside the projector or
        gray/phase inconsistent (a projector size or fringe period that does not match).
    gamma : float or None
        Response exponent estimated from the sine fringes' mean against white and black.
    cause : str or None
        The warning cause of ``reason`` (``board_not_found``, ``poorly_decoded``,
        ``corner_order_flipped``, ``outlier_corners``).
    outliers : (N,) bool or None
        In the calibration's returned poses: corners left out because they disagreed with their
        device's fit (None when there were none).
    """

    name: str
    camera_px: FloatArray | None
    projector_px: FloatArray | None
    object_mm: FloatArray | None = None
    decoded_fraction: FloatArray | None = None
    fit_rms: FloatArray | None = None
    reason: str | None = None
    mismatch_fraction: float | None = None
    gamma: float | None = None
    cause: str | None = None
    outliers: BoolArray | None = None


@dataclass(frozen=True)
class PoseSelection:
    """Every pose of a calibration, in the order given, and the corners used of each used pose.

    Attributes
    ----------
    poses : tuple of PoseObservation
        All poses, ``object_mm`` filled in; a pose is used when its ``reason`` is None.
    masks : mapping of str to (N,) bool
        The used corners of every pose that passed :func:`select_usable_poses` (kept for poses left
        out later, ignored for them).
    """

    poses: tuple[PoseObservation, ...]
    masks: Mapping[str, BoolArray]

    @property
    def used(self) -> tuple[PoseObservation, ...]:
        """The poses without a reason, in order."""
        return tuple(p for p in self.poses if p.reason is None)

    def leave_out(self, reasons: Mapping[str, str], cause: str) -> PoseSelection:
        """A selection with the poses named in ``reasons`` left out, each with its reason and ``cause``."""
        poses = tuple(replace(p, reason=reasons[p.name], cause=cause) if p.name in reasons else p for p in self.poses)
        return PoseSelection(poses=poses, masks=self.masks)


def _usable_corners(pose: PoseObservation, min_decoded_fraction: float) -> tuple[BoolArray | None, str, str]:
    """The pose's usable corners ``(N,)`` bool, or None with the reason and cause it is left out for.

    A corner is usable when both its points are finite and, when the pose has decoded fractions,
    at least ``min_decoded_fraction`` of its window is decoded; a pose needs
    ``max(MIN_USABLE_CORNERS N, MIN_POSE_CORNERS)`` of them.
    """
    if pose.camera_px is None:
        return None, "board not found in the board image", "board_not_found"
    if pose.projector_px is None:
        return None, "no projector points", "poorly_decoded"
    n = pose.camera_px.shape[0]
    ok = np.isfinite(pose.projector_px).all(axis=1) & np.isfinite(pose.camera_px).all(axis=1)
    if pose.decoded_fraction is not None:
        ok = np.asarray(ok & (pose.decoded_fraction >= min_decoded_fraction), dtype=bool)
    if ok.sum() < max(MIN_USABLE_CORNERS * n, MIN_POSE_CORNERS):
        reason = (
            f"only {int(ok.sum())} of {n} corners have >= {min_decoded_fraction:.0%} of their window decoded "
            "(part of the board shadowed, outside the projector's light, or too dark)"
        )
        return None, reason, "poorly_decoded"
    return np.asarray(ok, dtype=bool), "", ""


def select_usable_poses(
    poses: Sequence[PoseObservation], board: BoardSpec, min_decoded_fraction: float = MIN_DECODED_FRACTION
) -> PoseSelection:
    """The first selection: every pose with its board points, usable or left out with its reason.

    Parameters
    ----------
    poses : sequence of PoseObservation
        Poses whose ``reason`` is already set stay left out; the others are left out when their
        board was not found, they have no projector points, or too few usable corners
        (:func:`_usable_corners`).
    board : BoardSpec
        Gives ``object_mm`` (mm) to poses without it.
    min_decoded_fraction : float
        Decoded fraction (0..1) a corner's window needs.

    Raises
    ------
    ProcamCalibrationError
        No poses, or two poses of one name.
    """
    if not poses:
        raise ProcamCalibrationError("no poses given")
    names = [p.name for p in poses]
    if len(set(names)) != len(names):
        raise ProcamCalibrationError(f"pose names must be unique, got {names}")
    default_obj = board.object_points()
    selected: list[PoseObservation] = []
    masks: dict[str, BoolArray] = {}
    for p in poses:
        pose = p if p.object_mm is not None else replace(p, object_mm=default_obj)
        if pose.reason is None:
            mask, reason, cause = _usable_corners(pose, min_decoded_fraction)
            if mask is None:
                pose = replace(pose, reason=reason, cause=cause)
            else:
                masks[pose.name] = mask
        selected.append(pose)
    return PoseSelection(poses=tuple(selected), masks=masks)


@dataclass(frozen=True)
class FitPoints:
    """The used corners of the used poses, in the shapes and dtype OpenCV's calibrations take.

    Attributes
    ----------
    names : tuple of str
        The used poses, in order; entry ``k`` of every other attribute is pose ``names[k]``'s.
    object_mm : tuple of (n_k, 1, 3) float32
        Board points, mm.
    camera_px : tuple of (n_k, 1, 2) float32
        Camera points, pixels.
    projector_px : tuple of (n_k, 1, 2) float32
        Projector points, projector units.
    """

    names: tuple[str, ...]
    object_mm: tuple[Float32Array, ...]
    camera_px: tuple[Float32Array, ...]
    projector_px: tuple[Float32Array, ...]


def fit_points(selection: PoseSelection) -> FitPoints:
    """The used corners of ``selection``'s used poses (:class:`FitPoints`).

    Raises
    ------
    ProcamCalibrationError
        Fewer than :data:`MIN_POSES` used poses (the message gives every pose's reason).
    """
    used = selection.used
    if len(used) < MIN_POSES:
        lines = "; ".join(f"{p.name}: {p.reason or 'usable'}" for p in selection.poses)
        raise ProcamCalibrationError(f"need at least {MIN_POSES} usable poses, have {len(used)} ({lines})")

    def pick(points: FloatArray | None, mask: BoolArray, dims: int) -> Float32Array:
        assert points is not None
        return points[mask].astype(np.float32).reshape(-1, 1, dims)

    masks = [selection.masks[p.name] for p in used]
    return FitPoints(
        names=tuple(p.name for p in used),
        object_mm=tuple(pick(p.object_mm, m, 3) for p, m in zip(used, masks, strict=True)),
        camera_px=tuple(pick(p.camera_px, m, 2) for p, m in zip(used, masks, strict=True)),
        projector_px=tuple(pick(p.projector_px, m, 2) for p, m in zip(used, masks, strict=True)),
    )
