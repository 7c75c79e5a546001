"""Two-camera calibration from board poses (the ``gcps calibrate-stereo`` command): find the board in
both cameras' images of every pose, calibrate, explain (docs/stereo-calibration.md).

:func:`calibrate_stereo_images` takes each pose's two board images (arrays, or functions returning
them) and typed options (:class:`StereoCalibrationOptions`) and returns the stereo rig, the report
(``gcps-stereo-calibration-report/1``, with the software version and per-phase timings);
``progress(percent, phase)`` is called after each pose, so a job can report it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec
from metrology.core.geometry.stereo import StereoRig
from metrology.core.option_checks import check_bool, check_keys
from metrology.core.procam import parse_board
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.observe import board_image, observe_pose
from metrology.core.procam.poses import PoseObservation
from metrology.core.stereo_calibration import CAMERAS, StereoBoardPose, calibrate_stereo, observe_stereo_pose
from metrology.pipeline.common import PhaseTimer
from metrology.version import software_version

OPTION_KEYS = ("board", "projector_size", "fix_k3", "joint", "projector")
"""The keys of :meth:`StereoCalibrationOptions.from_dict` (those of :meth:`StereoCalibrationOptions.to_dict`)."""


@dataclass(frozen=True)
class StereoCalibrationOptions:
    """Options of :func:`calibrate_stereo_images`.

    Attributes
    ----------
    board : str
        ``chessboard:COLSxROWS:SQUARE_MM``, ``circles:...`` or ``acircles:...`` (mm).
    projector_size : (float, float)
        The projector's ``(width, height)`` in the codec's units, written to the rig file (the
        projector labels the surface; it is not calibrated here).
    fix_k3 : bool
        Hold the radial distortion coefficient k3 at 0 for both cameras.
    joint : bool
        Refine both cameras' intrinsics together with camera 1's pose (default True); False keeps
        each camera's own calibration in the stereo fit.
    projector : bool
        Calibrate the projector too, from camera 0's codec stacks (both axes coded): every pose
        then needs stacks and a codec of the projector's size.
    """

    board: str
    projector_size: tuple[float, float]
    fix_k3: bool = False
    joint: bool = True
    projector: bool = False

    def __post_init__(self) -> None:
        self.board_spec()  # ValueError naming the board spec
        size = self.projector_size
        if (
            not isinstance(size, tuple | list)
            or len(size) != 2
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in size)
            or not all(math.isfinite(x) and x > 0 for x in size)
        ):
            raise ValueError(f"projector_size must be two positive numbers (width, height), got {size!r}")
        object.__setattr__(self, "projector_size", (float(size[0]), float(size[1])))
        check_bool("fix_k3", self.fix_k3)
        check_bool("joint", self.joint)
        check_bool("projector", self.projector)

    def board_spec(self) -> BoardSpec:
        return parse_board(self.board)

    def to_dict(self) -> dict[str, Any]:
        return {
            "board": self.board,
            "projector_size": list(self.projector_size),
            "fix_k3": self.fix_k3,
            "joint": self.joint,
            "projector": self.projector,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StereoCalibrationOptions:
        """Options from a JSON object; ValueError naming an unknown key or a bad value."""
        check_keys("stereo calibration", data, set(OPTION_KEYS))
        for key in ("board", "projector_size"):
            if key not in data:
                raise ValueError(f"{key} is required")
        values = dict(data)
        if isinstance(values["projector_size"], list):
            values["projector_size"] = tuple(values["projector_size"])
        return cls(**values)


Image = npt.ArrayLike | Callable[[], npt.ArrayLike]


@dataclass(frozen=True)
class StereoBoardImages:
    """One board pose: a name and each camera's board image ``(H, W)`` or codec stack
    ``(frames, H, W)`` (any numeric dtype; a stack's board image is
    :func:`~metrology.core.procam.observe.board_image`'s), with the stacks' codec.

    An image may be a function of no arguments returning it, called when the pose's turn comes
    (one pose's images in memory at a time).
    """

    name: str
    camera0: Image
    camera1: Image
    codec: Codec | None = None

    def images(self) -> tuple[np.ndarray, np.ndarray]:
        """Both images, ``(H, W)`` each (calling the functions)."""
        return tuple(np.asarray(im() if callable(im) else im) for im in (self.camera0, self.camera1))  # type: ignore[return-value]


def _board_image(pose: StereoBoardImages, camera: str, image: np.ndarray) -> np.ndarray:
    """The image the board is found in: ``image`` (H, W), or a stack's (:func:`board_image`)."""
    if image.ndim == 2:
        return image
    if image.ndim == 3:
        if pose.codec is None:
            raise ValueError(f"pose {pose.name}: {camera} holds a stack of {image.shape[0]} frames but no codec")
        if image.shape[0] != pose.codec.n_frames:
            raise ValueError(
                f"pose {pose.name}: {camera} holds {image.shape[0]} frames, its codec has {pose.codec.n_frames}"
            )
        return board_image(image, pose.codec)
    raise ValueError(f"pose {pose.name}: {camera}'s board image must be (H, W) or a stack, got shape {image.shape}")


def _projector_observation(
    pose: StereoBoardImages, stack: np.ndarray, board: BoardSpec, options: StereoCalibrationOptions
) -> PoseObservation:
    """Camera 0's board corners mapped into the projector (:func:`observe_pose` of its stack)."""
    codec = pose.codec
    if stack.ndim != 3 or codec is None:
        raise ValueError(f"pose {pose.name}: --projector needs a codec stack in cam0/, not a single image")
    size = (float(codec.projector_width), float(codec.projector_height))
    if size != options.projector_size:
        raise ValueError(
            f"pose {pose.name}: the codec's projector is {size[0]:g}x{size[1]:g}, the projector size given "
            f"{options.projector_size[0]:g}x{options.projector_size[1]:g}"
        )
    return observe_pose(pose.name, stack, codec, board)


@dataclass
class StereoCalibrationResult:
    """The calibrated stereo rig, the report (JSON-ready apart from non-finite floats), the options,
    both cameras' sizes ``(width, height)``, the software version and the timings."""

    rig: StereoRig
    report: dict[str, Any]
    options: StereoCalibrationOptions
    camera_sizes: tuple[tuple[int, int], tuple[int, int]]
    software_version: str = field(default_factory=software_version)
    timings_s: dict[str, float] = field(default_factory=dict)


def calibrate_stereo_images(
    poses: Sequence[StereoBoardImages],
    options: StereoCalibrationOptions,
    progress: Callable[[int, str], None] | None = None,
) -> StereoCalibrationResult:
    """Find the board in both images of every pose, then calibrate both cameras and their pose.

    Raises
    ------
    ValueError
        Fewer than two poses, names repeated, an image that is not ``(H, W)``, a camera whose image
        size differs from its first pose's (naming the pose and the camera); StereoCalibrationError
        (a ValueError) when a camera's image has no board (naming the pose and the camera) or the
        poses cannot be calibrated.
    """
    if len(poses) < 2:
        raise ValueError(f"need at least 2 board poses seen by both cameras, got {len(poses)}")
    names = [p.name for p in poses]
    if len(set(names)) != len(names):
        raise ValueError(f"pose names must be unique, got {names}")
    board = options.board_spec()
    timer = PhaseTimer()
    sizes: list[tuple[int, int] | None] = [None, None]
    observed: list[StereoBoardPose] = []
    projector_poses: list[PoseObservation] = []
    for index, pose in enumerate(poses):
        if progress is not None:
            progress(round(90 * index / len(poses)), f"observe {pose.name}")
        with timer.phase("read"):
            images = pose.images()
        with timer.phase("observe"):
            boards = [_board_image(pose, camera, image) for camera, image in zip(CAMERAS, images, strict=True)]
            for k, (camera, image) in enumerate(zip(CAMERAS, boards, strict=True)):
                size = (int(image.shape[1]), int(image.shape[0]))
                first = sizes[k]
                if first is not None and size != first:
                    raise ValueError(
                        f"pose {pose.name}: {camera}'s image is {size[0]}x{size[1]} px, "
                        f"its first pose's {first[0]}x{first[1]}"
                    )
                sizes[k] = size
            observed.append(observe_stereo_pose(pose.name, boards[0], boards[1], board))
            if options.projector:
                projector_poses.append(_projector_observation(pose, images[0], board, options))
        del images, boards
    size0, size1 = sizes
    assert size0 is not None and size1 is not None
    if progress is not None:
        progress(90, "calibrate")
    with timer.phase("calibrate"):
        result = calibrate_stereo(
            observed,
            board,
            size0,
            size1,
            options.projector_size,
            fix_k3=options.fix_k3,
            joint=options.joint,
            projector_poses=projector_poses if options.projector else None,
        )
    version = software_version()
    report = dict(result.report)
    report["options"] = options.to_dict()
    report["software_version"] = version
    report["timings_s"] = {k: round(v, 3) for k, v in timer.timings_s.items()}
    return StereoCalibrationResult(
        rig=result.rig,
        report=report,
        options=options,
        camera_sizes=(size0, size1),
        software_version=version,
        timings_s=dict(timer.timings_s),
    )
