"""Projector-camera calibration from board poses (the ``gcps calibrate-procam`` command and, next,
the app's procam calibration job): observe every pose's stack, calibrate, explain.

:func:`calibrate_procam_stacks` takes the poses' stacks (arrays with their codecs) and typed
options and returns the pinhole rig, the report (``gcps-procam-report/1``, with the software
version and per-phase timings) and the poses' observations; ``progress(percent, phase)`` is
called after each pose, so a job can report it. See docs/procam-calibration.md.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy.typing as npt

from metrology.core.codecs import Codec
from metrology.core.codecs.decode import CodecDecodeOptions
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.option_checks import check_bool, check_keys
from metrology.core.procam import calibrate_procam, parse_board
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.observe import observe_pose
from metrology.core.procam.poses import MIN_DECODED_FRACTION, PoseObservation
from metrology.pipeline.common import PhaseTimer
from metrology.pipeline.jsonsafe import json_safe
from metrology.version import software_version

OPTION_KEYS = ("board", "window", "min_decoded", "fix_k3", "joint", "min_modulation", "min_inverse_contrast")
"""The keys of :meth:`ProcamOptions.from_dict` (those of :meth:`ProcamOptions.to_dict`)."""


@dataclass(frozen=True)
class ProcamOptions:
    """Options of :func:`calibrate_procam_stacks`.

    Attributes
    ----------
    board : str
        ``chessboard:COLSxROWS:SQUARE_MM``, ``circles:...`` or ``acircles:...`` (mm).
    window : int or None
        Half-size of each corner's homography window, pixels, 1..200 (None: automatic).
    min_decoded : float
        Decoded fraction (0..1) a corner's window needs for the corner to be used.
    fix_k3 : bool
        Hold the radial distortion coefficient k3 at 0 for both devices.
    joint : bool
        Refine both devices' intrinsics together with the stereo pose (default True); False keeps
        each device's own calibration in the stereo fit.
    min_modulation, min_inverse_contrast : float or None
        Decoder thresholds, grey levels (None: the decoder's defaults).
    """

    board: str
    window: int | None = None
    min_decoded: float = MIN_DECODED_FRACTION
    fix_k3: bool = False
    joint: bool = True
    min_modulation: float | None = None
    min_inverse_contrast: float | None = None

    def __post_init__(self) -> None:
        self.board_spec()  # ValueError naming the board spec
        if self.window is not None and (
            isinstance(self.window, bool) or not isinstance(self.window, int) or not 1 <= self.window <= 200
        ):
            raise ValueError(f"window must be 1..200 pixels, got {self.window!r}")
        if isinstance(self.min_decoded, bool) or not isinstance(self.min_decoded, int | float):
            raise ValueError(f"min_decoded must be a number within 0..1, got {self.min_decoded!r}")
        if not 0.0 <= self.min_decoded <= 1.0:
            raise ValueError(f"min_decoded must be within 0..1, got {self.min_decoded}")
        check_bool("fix_k3", self.fix_k3)
        check_bool("joint", self.joint)
        self.decode_options()  # ValueError naming a bad decoder threshold

    def board_spec(self) -> BoardSpec:
        return parse_board(self.board)

    def decode_options(self) -> CodecDecodeOptions:
        return CodecDecodeOptions(min_modulation=self.min_modulation, min_inverse_contrast=self.min_inverse_contrast)

    def to_dict(self) -> dict[str, Any]:
        return {
            "board": self.board,
            "window": self.window,
            "min_decoded": self.min_decoded,
            "fix_k3": self.fix_k3,
            "joint": self.joint,
            "min_modulation": self.min_modulation,
            "min_inverse_contrast": self.min_inverse_contrast,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ProcamOptions:
        """Options from a JSON object; ValueError naming an unknown key or a bad value."""
        check_keys("procam calibration", data, set(OPTION_KEYS))
        if "board" not in data:
            raise ValueError("board is required (e.g. 'chessboard:9x7:25')")
        return cls(**dict(data))


@dataclass(frozen=True)
class ProcamPose:
    """One board pose: a name, its stack ``(frames, H, W)`` (uint8/uint16) and its codec (both axes).

    ``images`` may also be a function of no arguments returning the stack: it is then called when
    the pose's turn comes and the stack is released once the pose is observed, so that only one
    pose's images are in memory at a time (a job of 40 poses of 1280x1024x44 frames would hold
    2.3 GB otherwise).
    """

    name: str
    images: npt.ArrayLike | Callable[[], npt.ArrayLike]
    codec: Codec

    def stack(self) -> npt.ArrayLike:
        """The pose's images (calling ``images`` when it is a function)."""
        return self.images() if callable(self.images) else self.images


@dataclass
class ProcamResult:
    """The calibrated rig, the report (JSON-ready apart from non-finite floats), the observations
    (as the calibration judged them: board points filled in, each left-out pose's reason set)."""

    rig: PinholeRig
    report: dict[str, Any]
    poses: list[PoseObservation]
    options: ProcamOptions
    camera_size: tuple[int, int]
    projector_size: tuple[int, int]
    software_version: str = field(default_factory=software_version)
    timings_s: dict[str, float] = field(default_factory=dict)


def calibrate_procam_stacks(
    poses: Sequence[ProcamPose],
    options: ProcamOptions,
    progress: Callable[[int, str], None] | None = None,
) -> ProcamResult:
    """Observe every pose (decode, board, local homographies) and calibrate.

    Parameters
    ----------
    poses : sequence of ProcamPose
        All stacks of one size (the camera's), all codecs of one projector size.
    options : ProcamOptions
    progress : callable(percent, phase), optional
        Called with 0..90 while poses are read (``"read NAME"``, for poses whose ``images`` is a
        function) and observed (``"observe NAME"``), and with 90 before the calibration.

    Raises
    ------
    ValueError
        No poses, stacks of different sizes or codecs of different projector sizes (naming the
        pose), a codec that does not code both axes; ProcamCalibrationError (a ValueError)
        when fewer than two poses are usable (naming each pose's reason).
    """
    if not poses:
        raise ValueError("no poses given")
    board = options.board_spec()
    decode = options.decode_options()
    timer = PhaseTimer()
    observations: list[PoseObservation] = []
    shape: tuple[int, int] | None = None
    projector: tuple[int, int] | None = None
    precompensated = False
    for index, pose in enumerate(poses):
        percent = round(90 * index / len(poses))
        if callable(pose.images):
            if progress is not None:
                progress(percent, f"read {pose.name}")
            with timer.phase("read"):
                images = pose.stack()
        else:
            images = pose.images
        if progress is not None:
            progress(percent, f"observe {pose.name}")
        with timer.phase("observe"):
            stack_shape = tuple(getattr(images, "shape", ()))
            if len(stack_shape) != 3:
                raise ValueError(f"pose {pose.name}: not a stack of images (shape {stack_shape})")
            size = (int(stack_shape[1]), int(stack_shape[2]))
            if shape is not None and size != shape:
                raise ValueError(f"pose {pose.name}: image size {size} differs from the first pose's {shape}")
            proj = (pose.codec.projector_width, pose.codec.projector_height)
            if projector is not None and proj != projector:
                raise ValueError(
                    f"pose {pose.name}: projector {proj[0]}x{proj[1]} differs from {projector[0]}x{projector[1]}"
                )
            shape, projector = size, proj
            precompensated = precompensated or pose.codec.precompensated_gamma is not None
            observations.append(
                observe_pose(pose.name, images, pose.codec, board, half_window=options.window, decode_options=decode)
            )
        del images  # a loaded pose's stack is released before the next is read
    assert shape is not None and projector is not None
    camera_size = (shape[1], shape[0])
    if progress is not None:
        progress(90, "calibrate")
    with timer.phase("calibrate"):
        result = calibrate_procam(
            observations,
            board,
            camera_size,
            projector,
            min_decoded_fraction=options.min_decoded,
            codec_gamma_precompensated=precompensated,
            fix_k3=options.fix_k3,
            joint=options.joint,
        )
    report = dict(result.report)
    version = software_version()
    report["software_version"] = version
    report["timings_s"] = {k: round(v, 3) for k, v in timer.timings_s.items()}
    return ProcamResult(
        rig=result.rig,
        report=report,
        poses=list(result.poses),
        options=options,
        camera_size=camera_size,
        projector_size=projector,
        software_version=version,
        timings_s=dict(timer.timings_s),
    )


def report_json_text(report: Mapping[str, Any]) -> str:
    """The text of ``REPORT.json`` (``gcps-procam-report/1``): the report, non-finite floats as null,
    indented by 2, one trailing newline; what ``gcps calibrate-procam --report`` writes and the app's
    ``/api/procam-calibrations/{id}/report.json`` serves."""
    return json.dumps(json_safe(dict(report)), indent=2, allow_nan=False) + "\n"
