"""One acquisition: show each pattern, wait for the projector's confirmation and the settle time, grab, check, re-grab.

Order: black, white, black again (the checks' references: the two black frames must agree; the
white one is also the auto-exposure's frame), then the codec's frames in order. A frame that
fails its checks (:mod:`.checks`) is grabbed again after another settle time, up to
``max_grabs`` grabs; a frame still failing then stops the acquisition with
:class:`AcquisitionError` naming the frame and the reasons, and nothing is kept.

A rig of several cameras (a stereo rig, :class:`~.cameras.RigCameras`) gives one frame per camera
at each grab, each checked as a one-camera rig's against that camera's own white and black
frames; a pattern is accepted when every camera's frame passes, else all are grabbed again (a
failing frame on any camera fails the pattern), so the accepted frames of a pattern come from
one grab. One exposure serves every camera (the auto-exposure pools their white frames).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from metrology.acquisition.agent.bracketing import Bracket, BracketOptions, bracket_exposures
from metrology.acquisition.agent.cameras import Camera, RigCameras, Shown, as_rig_cameras
from metrology.acquisition.agent.checks import (
    CheckOptions,
    FrameCheck,
    FrameChecker,
    auto_exposure,
    projector_change,
)
from metrology.acquisition.agent.patterns import ProjectedCodec


class AcquisitionError(Exception):
    """The acquisition cannot complete; the message is the reason reported to the job."""


class Projector(Protocol):
    """Shows a pattern and returns what it reports showing, once on screen (blocking)."""

    def show(self, kind: str, frame: int = -1) -> Shown: ...


@dataclass(frozen=True)
class SequenceOptions:
    """``settle_s``: wait after each confirmed pattern before grabbing, s; ``max_grabs`` per pattern."""

    settle_s: float = 0.1
    max_grabs: int = 4

    def __post_init__(self) -> None:
        if not 0 <= self.settle_s <= 60:
            raise ValueError(f"settle time must be in [0, 60] s, got {self.settle_s}")
        if not 1 <= self.max_grabs <= 20:
            raise ValueError(f"max grabs must be in 1..20, got {self.max_grabs}")


@dataclass
class AcquiredFrames:
    """The result: ``images`` ``(n_frames, H, W)`` in codec order and the flats (camera 0's), every
    check made (incl. refused grabs); on a rig of several cameras ``other_cameras``, the
    ``(n_frames, H_c, W_c)`` stacks of cameras 1, 2, ..."""

    images: np.ndarray
    white: np.ndarray
    black: np.ndarray
    exposure_ms: float | None
    checks: list[FrameCheck] = field(default_factory=list)
    exposure_steps: list[dict[str, float]] = field(default_factory=list)
    other_cameras: tuple[np.ndarray, ...] = ()

    @property
    def camera_stacks(self) -> tuple[np.ndarray, ...]:
        """Every camera's stack, camera 0 first."""
        return (self.images, *self.other_cameras)

    def frame_reports(self) -> list[dict[str, Any]]:
        """Per pattern and camera: its accepted check with ``regrabs`` (refused grabs before it) and their reasons."""
        accepted: dict[tuple[int, str], dict[str, Any]] = {}
        refused: dict[tuple[int, str], list[str]] = {}
        for check in self.checks:
            key = (check.camera, check.name)
            if not check.ok:
                refused.setdefault(key, []).extend(check.reasons)
                continue
            data = check.to_dict()
            data["regrabs"] = len([c for c in self.checks if (c.camera, c.name) == key and not c.ok])
            data["refused_reasons"] = refused.get(key, [])
            accepted[key] = data  # the last accepted grab of each pattern is the one kept
        return list(accepted.values())


Progress = Callable[[int, str, list[dict[str, Any]]], None]


def run_sequence(
    projector: Projector,
    camera: Camera | RigCameras,
    codec: ProjectedCodec,
    *,
    exposure_ms: float | None,
    options: SequenceOptions | None = None,
    checker: FrameChecker | None = None,
    progress: Progress | None = None,
    start_exposure_ms: float = 10.0,
) -> AcquiredFrames:
    """Acquire one stack of ``codec`` per camera (module docstring). ``exposure_ms`` None:
    auto-exposure from the white frame (every camera's pixels pooled). ``checker``: camera 0's
    (the others' take its options)."""
    opts = options or SequenceOptions()
    cameras = as_rig_cameras(camera)
    count = cameras.camera_count
    first = checker or FrameChecker()
    checkers = [first, *(FrameChecker(first.options, camera=index) for index in range(1, count))]
    projected = codec.images()
    checks: list[FrameCheck] = []
    total = codec.n_frames + 2

    def report(done: int, phase: str) -> None:
        if progress is not None:
            progress(int(5 + 90 * done / total), phase[:64], [c.to_dict() for c in checks])

    def grab(kind: str, frame: int = -1) -> tuple[Shown, tuple[np.ndarray, ...]]:
        return _grab(projector, cameras, opts, kind, frame)

    steps: list[dict[str, float]] = []
    if exposure_ms is None:

        def grab_white(e: float) -> np.ndarray:
            cameras.set_exposure(e)
            return np.concatenate([image.ravel() for image in grab("white")[1]])

        try:
            exposure_ms, steps = auto_exposure(grab_white, start_exposure_ms)
        except ValueError as exc:
            raise AcquisitionError(str(exc)) from None
    cameras.set_exposure(exposure_ms)

    blacks = whites = None
    for attempt in range(1, opts.max_grabs + 1):
        blacks = grab("black")[1]
        checks.extend(c.check_black(black, grab=attempt) for c, black in zip(checkers, blacks, strict=True))
        whites = grab("white")[1]
        blacks_after = grab("black")[1]
        white_checks = [
            c.check_white(white, black, grab=attempt, black_after=after)
            for c, white, black, after in zip(checkers, whites, blacks, blacks_after, strict=True)
        ]
        checks.extend(white_checks)
        if all(check.ok for check in white_checks):
            break
        report(1, f"white refused ({attempt}/{opts.max_grabs})")
    else:
        raise AcquisitionError(f"white/black frames refused {opts.max_grabs} times: {_refusals(white_checks, count)}")
    assert blacks is not None and whites is not None
    report(2, "black and white frames")

    stacks: list[list[np.ndarray]] = [[] for _ in range(count)]
    previous_images = list(whites)
    previous_pattern = np.full_like(projected[0], 255)
    previous_expected: list[np.ndarray] = list(whites)  # the first frame follows the white one
    for frame, name in enumerate(codec.frame_names):
        projector_expected = projector_change(previous_pattern, projected[frame], first.options.change_level)
        for attempt in range(1, opts.max_grabs + 1):
            shown, images = grab("frame", frame)
            expected_images = cameras.expected(shown)
            frame_checks = []
            for index, (check_camera, image, expected_image) in enumerate(
                zip(checkers, images, expected_images, strict=True)
            ):
                expected_change = projector_expected
                if expected_image is not None:  # the lit pixels' own change
                    expected_change = check_camera.expected_change(previous_expected[index], expected_image)
                frame_checks.append(
                    check_camera.check_frame(
                        image,
                        name=name,
                        frame=frame,
                        previous_image=previous_images[index],
                        expected_change=expected_change,
                        expected_image=expected_image,
                        grab=attempt,
                    )
                )
            checks.extend(frame_checks)
            if all(check.ok for check in frame_checks):
                break
            report(frame + 2, f"re-grab {name}: {_refusals(frame_checks, count)}")
        else:
            raise AcquisitionError(
                f"frame {name} refused after {opts.max_grabs} grabs: {_refusals(frame_checks, count)}"
            )
        for index, (image, expected_image) in enumerate(zip(images, expected_images, strict=True)):
            stacks[index].append(image)
            previous_images[index] = image
            previous_expected[index] = expected_image if expected_image is not None else image
        previous_pattern = projected[frame]
        report(frame + 3, f"grabbed {name}")
    projector.show("black")
    return AcquiredFrames(
        images=np.stack(stacks[0]),
        white=whites[0],
        black=blacks[0],
        exposure_ms=exposure_ms,
        checks=checks,
        exposure_steps=steps,
        other_cameras=tuple(np.stack(stack) for stack in stacks[1:]),
    )


def _refusals(checks: Sequence[FrameCheck], count: int) -> str:
    """The refused checks' reasons, each named by its camera on a rig of several cameras."""
    return "; ".join(
        f"camera {check.camera}: {reason}" if count > 1 else reason
        for check in checks
        if not check.ok
        for reason in check.reasons
    )


def _grab(
    projector: Projector, cameras: RigCameras, opts: SequenceOptions, kind: str, frame: int = -1
) -> tuple[Shown, tuple[np.ndarray, ...]]:
    """Show a pattern, check that the projector reports it, wait the settle time, grab every camera."""
    shown = projector.show(kind, frame)
    if shown.kind != kind or (kind == "frame" and shown.frame != frame):
        raise AcquisitionError(f"the projector reports showing {shown.kind} {shown.frame}, not {kind} {frame}")
    time.sleep(opts.settle_s)
    return shown, cameras.grab(shown)


@dataclass
class BracketedFrames:
    """A multi-exposure acquisition (docs/exposures.md): one :class:`AcquiredFrames` per exposure,
    shortest first, and the automatic bracket they were chosen by (None for a given list)."""

    stacks: list[AcquiredFrames]
    bracket: Bracket | None = None

    @property
    def exposures_ms(self) -> tuple[float, ...]:
        return tuple(float(s.exposure_ms or 0.0) for s in self.stacks)


def run_bracketed_sequence(
    projector: Projector,
    camera: Camera | RigCameras,
    codec: ProjectedCodec,
    *,
    exposures_ms: Sequence[float] | None,
    bracket_options: BracketOptions | None = None,
    options: SequenceOptions | None = None,
    progress: Progress | None = None,
    start_exposure_ms: float = 10.0,
) -> BracketedFrames:
    """Acquire one stack of ``codec`` per exposure (:func:`run_sequence` each), shortest first.

    ``exposures_ms`` None: the automatic bracket (:func:`~.bracketing.bracket_exposures`) from
    white and black frames grabbed at probe exposures from ``start_exposure_ms``. The longer
    exposures saturate the bright part on purpose: their white frame may saturate
    (``max_white_saturated`` 1), the shortest's may not.

    On a rig of several cameras every camera is grabbed at each probe and each exposure (one stack
    per camera per exposure, :attr:`AcquiredFrames.camera_stacks`); the bracket's shortest exposure
    comes from the brightest camera, its longest from the darkest.
    """
    opts = options or SequenceOptions()
    cameras = as_rig_cameras(camera)
    bracket = None
    if exposures_ms is None:

        def grab_flats(e: float) -> tuple[Any, Any]:
            """Camera 0's white and black frames; every camera's (tuples) on a rig of several."""
            cameras.set_exposure(e)
            white, black = _grab(projector, cameras, opts, "white")[1], _grab(projector, cameras, opts, "black")[1]
            return (white, black) if cameras.camera_count > 1 else (white[0], black[0])

        try:
            bracket = bracket_exposures(grab_flats, start_exposure_ms, bracket_options)
        except ValueError as exc:
            raise AcquisitionError(str(exc)) from None
        exposures_ms = bracket.exposures_ms
    ordered = sorted(float(e) for e in exposures_ms)
    if not ordered or any(not (0 < e < float("inf")) for e in ordered):
        raise AcquisitionError(f"exposures must be positive numbers of ms, got {list(exposures_ms)}")
    stacks: list[AcquiredFrames] = []
    for index, exposure in enumerate(ordered):

        def step(percent: int, phase: str, checks: list[dict[str, Any]], index: int = index) -> None:
            if progress is not None:
                progress(
                    int((index * 100 + percent) / len(ordered)),
                    f"exposure {index + 1}/{len(ordered)}: {phase}"[:64],
                    checks,
                )

        checker = FrameChecker(CheckOptions(max_white_saturated=1.0)) if index else FrameChecker()
        stacks.append(
            run_sequence(projector, cameras, codec, exposure_ms=exposure, options=opts, checker=checker, progress=step)
        )
    return BracketedFrames(stacks, bracket)


class InstantProjector:
    """A projector with nothing to display (the virtual rig without a page): reports each pattern as shown at once."""

    def __init__(self) -> None:
        self.seq = 0

    def show(self, kind: str, frame: int = -1) -> Shown:
        self.seq += 1
        return Shown(kind=kind, frame=frame if kind == "frame" else -1, seq=self.seq)
