"""Capture stacks of any codec: uploads read and validated before anything is stored, and stored
stacks read back in a worker (docs/codecs.md, docs/file-formats.md).

gcps-v1 stacks (the eleven named patterns) are read by the core's gcps-v1 reader
(:func:`metrology.core.io.read_stack`), every other codec by the codec reader
(:func:`metrology.core.codecs.stack.read_codec_stack`), which checks the frames against the codec;
both within :func:`stack_limits` (pixels per image, expanded bytes of the zip).
"""

from __future__ import annotations

from typing import Any

from django.conf import settings

from metrology.captures.codecs import capture_codec
from metrology.captures.models import Capture
from metrology.core.codecs.model import CodecError, is_gcps_v1
from metrology.errors import BadInput
from metrology.rigs.codecs import MAX_CODEC_FRAMES, capture_default, check_codec_for_rig, codec_of, validate_codec
from metrology.rigs.models import Rig

MIB = 1024 * 1024


def stack_limits(rig: Rig, frames: int | None = None) -> dict[str, int]:
    """Bounds passed to the core's readers: pixels per image, and the expanded bytes of a zip of the
    eleven gcps-v1 images (``frames`` None) or of ``frames`` images of a codec plus its codec.json,
    each of at most 4 channels x 16 bit with generous room for file headers; per camera of the rig
    (its largest camera's pixels)."""
    shapes = rig.to_core().camera_shapes
    pixels = max(h * w for h, w in shapes)
    per_camera = 11 * (pixels * 8 + MIB) if frames is None else (frames + 1) * (pixels * 8 + MIB)
    return {
        "max_pixels": min(pixels, settings.GCPS_MAX_STACK_PIXELS),
        "max_bytes": min(len(shapes) * per_camera, max(settings.GCPS_MAX_UPLOAD_BYTES, 64 * MIB) * 4),
    }


def read_capture_stack(source: Any, rig: Rig, *, expected_bit_depth: int | None = None):
    """Read and validate a stack (path or binary file-like zip) for ``rig`` with the core's reader.

    Raises
    ------
    BadInput
        With the core's one-line message when the stack is refused.
    """
    from metrology.core.io import StackError, read_stack

    try:
        return read_stack(source, rig=rig.to_core(), expected_bit_depth=expected_bit_depth, **stack_limits(rig))
    except StackError as exc:
        raise BadInput(f"capture stack refused: {exc}") from None


def load_capture_stack(capture: Capture):
    """The stored stack of a capture (in a worker). Raises ``ValueError`` if it is not stored.

    A stack validated when it was stored (its sha256 recorded) is read without validating it again,
    after checking that its hash still matches (:func:`metrology.core.io.read_verified_stack`);
    one without a recorded hash is validated like an upload.
    """
    if not capture.file:
        raise ValueError(f"capture {capture.pk} has no stored stack yet (its simulation has not finished)")
    from metrology.core.io import read_stack, read_verified_stack

    with capture.file.open("rb") as handle:
        if capture.checksum_sha256:
            return read_verified_stack(handle.read(), capture.checksum_sha256, shape=capture.rig.to_core().shape)
        return read_stack(handle, rig=capture.rig.to_core(), **stack_limits(capture.rig))


def upload_limits(rig: Rig) -> dict[str, int]:
    """Bounds of a multi-exposure capture's reader: pixels per image, and expanded bytes of the
    whole zip (all exposures: the largest expansion :func:`stack_limits` allows any stack)."""
    return {
        "max_pixels": min(max(h * w for h, w in rig.to_core().camera_shapes), settings.GCPS_MAX_STACK_PIXELS),
        "max_bytes": max(settings.GCPS_MAX_UPLOAD_BYTES, 64 * MIB) * 4,
    }


def frame_shape(stack: Any) -> tuple[int, int]:
    """``(H, W)`` of a read stack: a single stack's ``images``, a multi-exposure one's ``stack``, or
    camera 0's of a capture of several cameras (:class:`~metrology.core.codecs.stack.CameraCodecStacks`)."""
    exposures = getattr(stack, "stack", None)
    if exposures is not None:
        height, width = exposures.frame_shape
        return int(height), int(width)
    if getattr(stack, "stacks", None) is not None:  # a capture of several cameras: camera 0's
        height, width = stack.frame_shapes[0]
        return int(height), int(width)
    height, width = stack.images.shape[1:]
    return int(height), int(width)


def stored_exposures(stack: Any) -> list[dict[str, Any]] | None:
    """The ``exposures.json`` entries of a read multi-exposure stack (least exposed first; of every
    camera for a capture of several cameras), None for a single one."""
    exposures = getattr(stack, "stack", None)
    if exposures is not None:
        return [e.to_dict() for e in exposures.exposures]
    if getattr(stack, "stacks", None) is not None and stack.exposures is not None:  # cam0/exp0/ ...
        return [e.to_dict() for e in stack.exposures]
    return None


def read_upload_stack(
    upload: Any, rig: Any, *, expected_bit_depth: int | None = None, codec: Any = None
) -> tuple[Any, Any]:
    """Validate an uploaded zip for ``rig`` with its codec: returns ``(stored codec value, stack)``.

    The codec is the zip's own ``codec.json``, else the rig's default; or, when ``codec`` is given
    (the codec an acquisition projected), that one, and a ``codec.json`` in the zip must then be
    the same codec. gcps-v1 stacks are read by the gcps-v1 reader (the eleven named patterns); any
    other codec by the codec reader, which checks the frames against the codec. The frames must be
    the rig's camera size, and the rig's model must measure with the codec
    (:func:`check_codec_for_rig`). ``stack`` has ``images`` ``(frames, H, W)`` and ``bit_depth``.

    Raises
    ------
    BadInput
        Naming the problem (bad codec.json, a stack that does not match its codec, ...).
    """
    from metrology.core.codecs.stack import (
        is_exposure_capture,
        read_capture_codec,
        read_codec_stack,
        read_exposure_stack,
    )
    from metrology.core.io import StackError

    try:
        own = read_capture_codec(upload, max_bytes=stack_limits(rig, MAX_CODEC_FRAMES)["max_bytes"])
    except CodecError as exc:
        raise BadInput(f"capture codec refused: {exc}") from None
    except StackError as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    if codec is not None:
        value = validate_codec(codec)
        if own is not None and own.to_dict() != codec_of(value).to_dict():
            raise BadInput("capture codec refused: the zip's codec.json is not the codec that was projected")
    else:
        value = validate_codec(own.to_dict()) if own is not None else capture_default(rig)
    codec = codec_of(value)
    check_codec_for_rig(codec, rig)
    upload.seek(0)
    if rig.to_core().cameras > 1:
        return value, read_cameras_upload(upload, rig, codec, expected_bit_depth=expected_bit_depth)
    try:
        multi = is_exposure_capture(upload, max_bytes=upload_limits(rig)["max_bytes"])
    except StackError as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    if is_gcps_v1(codec) and not multi:
        return value, read_capture_stack(upload, rig, expected_bit_depth=expected_bit_depth)
    upload.seek(0)
    limits = upload_limits(rig) if multi else stack_limits(rig, codec.n_frames)
    stack: Any
    try:
        if multi:  # exposures.json and one stack per exposure (docs/exposures.md)
            stack = read_exposure_stack(upload, codec, max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"])
        else:
            stack = read_codec_stack(upload, codec, max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"])
    except (StackError, CodecError) as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    height, width = frame_shape(stack)
    if (height, width) != (rig.height_px, rig.width_px):
        raise BadInput(
            f"capture stack refused: the frames are {width}x{height} px "
            f"but the rig is {rig.width_px}x{rig.height_px} px"
        )
    _check_bit_depth(stack.bit_depth, expected_bit_depth)
    return value, stack


def _check_bit_depth(bit_depth: int, expected: int | None) -> None:
    if expected is not None and bit_depth != expected:
        raise BadInput(f"capture stack refused: the images are {bit_depth}-bit but bit_depth {expected} was declared")


def read_cameras_upload(upload: Any, rig: Any, codec: Any, *, expected_bit_depth: int | None = None) -> Any:
    """Validate the capture of a rig of several cameras (docs/stereo.md): ``cam0/``, ``cam1/`` ...
    each a complete stack of ``codec``'s frames, of its camera's size; a
    :class:`~metrology.core.codecs.stack.CameraCodecStacks` (``stacks``, one ``(frames, H_c, W_c)``
    array per camera, camera 0 first). A multi-exposure capture (``exposures.json`` at the top,
    ``cam0/exp0/`` ..., docs/exposures.md "Stereo rigs") gives one
    :class:`~metrology.core.codecs.stack.ExposureStack` per camera.

    Raises
    ------
    BadInput
        Naming the camera and the file (a camera's folder missing, a frame missing or unreadable, a
        camera's frames of another size than the rig's camera).
    """
    from metrology.core.codecs.stack import is_exposure_capture, read_camera_stacks
    from metrology.core.io import StackError

    model = rig.to_core()
    try:
        multi = is_exposure_capture(upload, max_bytes=upload_limits(rig)["max_bytes"])
        limits = upload_limits(rig) if multi else stack_limits(rig, codec.n_frames)
        upload.seek(0)
        read = read_camera_stacks(upload, codec, model.cameras, **limits)
    except (StackError, CodecError) as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    for index, ((got_h, got_w), (height, width)) in enumerate(zip(read.frame_shapes, model.camera_shapes, strict=True)):
        if (got_h, got_w) != (height, width):
            raise BadInput(
                f"capture stack refused: camera {index}'s frames (cam{index}/) are {got_w}x{got_h} px "
                f"but the rig's camera {index} is {width}x{height} px"
            )
    _check_bit_depth(read.bit_depth, expected_bit_depth)
    return read


def load_capture_images(capture: Any) -> Any:
    """The ``(frames, H, W)`` images of a stored capture in its codec's order: the eleven named
    patterns of gcps-v1, or a codec's frames; for a multi-exposure capture an
    :class:`~metrology.core.codecs.stack.ExposureStack`; for a rig of several cameras a tuple of
    one such stack per camera, camera 0 first (in a worker). Raises ``ValueError`` when not stored."""
    if capture.rig.to_core().cameras > 1:  # an ExposureStack per camera for a multi-exposure one
        return load_camera_stacks(capture).stacks
    if capture.exposures:
        return load_exposure_stack(capture)
    if is_gcps_v1(capture_codec(capture)):
        return load_capture_stack(capture).images
    return load_codec_stack(capture).images


def load_codec_stack(capture: Any) -> Any:
    """The stored stack of a capture of any codec, in codec order (a :class:`CodecStack`); in a worker.

    For a rig of several cameras, camera 0's stack (what the capture's page decodes and checks).
    Raises ``ValueError`` if it is not stored or does not match its codec.
    """
    from metrology.core.codecs.stack import CodecStack, ExposureStack, read_codec_stack

    if capture.rig.to_core().cameras > 1:
        cameras = load_camera_stacks(capture)
        first = cameras.stacks[0]
        if isinstance(first, ExposureStack):  # load_exposure_stack reads it
            raise ValueError(f"capture {capture.pk} is a multi-exposure capture (exposures.json)")
        return CodecStack(first, cameras.codec, (), cameras.codec_source)
    if not capture.file:
        raise ValueError(f"capture {capture.pk} has no stored stack yet (its simulation has not finished)")
    codec = capture_codec(capture)
    limits = stack_limits(capture.rig, codec.n_frames)
    with capture.file.open("rb") as handle:
        return read_codec_stack(handle, codec, max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"])


def load_camera_stacks(capture: Any) -> Any:
    """The stored capture of a rig of several cameras as a
    :class:`~metrology.core.codecs.stack.CameraCodecStacks` (``stacks``: camera 0 first), in a
    worker. Raises ``ValueError`` if it is not stored or does not match its codec."""
    from metrology.core.codecs.stack import read_camera_stacks

    if not capture.file:
        raise ValueError(f"capture {capture.pk} has no stored stack yet (its simulation has not finished)")
    codec = capture_codec(capture)
    limits = upload_limits(capture.rig) if capture.exposures else stack_limits(capture.rig, codec.n_frames)
    with capture.file.open("rb") as handle:
        return read_camera_stacks(handle, codec, capture.rig.to_core().cameras, **limits)


def load_exposure_stack(capture: Any) -> Any:
    """The stored multi-exposure capture's :class:`~metrology.core.codecs.stack.ExposureStack`
    (docs/exposures.md), in a worker; camera 0's for a rig of several cameras (what the capture's
    page decodes). Raises ``ValueError`` if it is not stored or does not match its codec."""
    from metrology.core.codecs.stack import read_exposure_stack

    if not capture.file:
        raise ValueError(f"capture {capture.pk} has no stored stack yet")
    if capture.rig.to_core().cameras > 1:
        return load_camera_stacks(capture).stacks[0]
    limits = upload_limits(capture.rig)
    with capture.file.open("rb") as handle:
        return read_exposure_stack(
            handle, capture_codec(capture), max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"]
        ).stack
