"""One board pose from a capture stack: decode, find the board, map its corners into the projector.

The board image is the mean of the codec's white frames and of the frames of every sine phase
sequence of four or more steps: an N-step sine sequence averages to a uniform half-white
illumination (``(1/N) sum_k (1 + cos(theta + 2 pi k / N)) / 2 = 1/2``; a projector gamma ``g``
leaves the harmonics ``N, 2N, ...`` of ``((1 + cos) / 2)^g``: with g = 2.2 a ripple of 0.4 % of
the mean peak to peak for N = 4, 3 % for N = 3, hence the four steps, under 0.01 % for N = 8).
The mean is then the board's albedo under even light with the camera noise of many frames
instead of one (virtual rig, 8-bit, 1.5 grey levels of noise, one white frame and two 8-step
sequences: camera corners 0.0075 px instead of 0.0101 px per axis). Without white frames or
such sequences, the mean of all frames. The decoded ``(u, v)`` of :func:`metrology.core.codecs.decode.decode_codec`
feed the local homographies of :mod:`metrology.core.procam.corners`, each pixel weighted by the
square of its modulation (the inverse variance of its coordinate).

Two diagnostics are measured on the board (inside the hull of its corners):

- the **mismatch fraction**: of the pixels bright enough to decode, the fraction refused as
  outside the projector (reason 3) or gray/phase inconsistent (reason 4), over both axes: a
  projector size or fringe period in the codec that differs from the projected patterns;
- the **gamma estimate**, for an axis whose first phase sequence is a sine: with
  ``r = median((A - black) / (white - black))`` the mean of the fringes relative to white and
  black, a response ``E = s^g`` of the pattern ``s = (1 + cos)/2`` gives ``r = <s^g>`` (the
  mean over a period), solved for ``g`` (``g = 1`` gives ``r = 1/2``, ``g = 2.2`` about 0.31).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.decode import (
    REASON_INCONSISTENT,
    REASON_OUTSIDE,
    REASON_SLIP_REPAIRED,
    REASON_VALID,
    CodecDecodeOptions,
    CodecDecoding,
    decode_codec,
)
from metrology.core.codecs.model import Codec
from metrology.core.procam.board import BoardSpec, detect_board
from metrology.core.procam.corners import auto_window, project_corners
from metrology.core.procam.poses import PoseObservation

FloatArray = npt.NDArray[np.float64]

_THETA = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
_GAMMAS = np.linspace(0.2, 5.0, 961)
_MEANS = np.array([np.mean(((1 + np.cos(_THETA)) / 2) ** g) for g in _GAMMAS])  # decreasing in g


def gamma_from_mean_ratio(r: float) -> float:
    """The exponent ``g`` with ``<((1 + cos)/2)^g> = r`` (NaN outside the tabulated 0.2..5)."""
    if not math.isfinite(r) or r >= _MEANS[0] or r <= _MEANS[-1]:
        return float("nan")
    return float(np.interp(r, _MEANS[::-1], _GAMMAS[::-1]))


MIN_BOARD_PHASE_STEPS = 4
"""Sine phase sequences of at least this many steps join the board image (module docstring)."""


def board_frames(codec: Codec) -> list[int]:
    """The frames averaged into the board image: white frames and the frames of sine phase
    sequences of :data:`MIN_BOARD_PHASE_STEPS` or more steps, sorted; empty when there are none."""
    frames = set(codec.white)
    for axis in codec.axes.values():
        for sequence in axis.phase:
            if sequence.waveform == "sine" and sequence.steps >= MIN_BOARD_PHASE_STEPS:
                frames.update(sequence.frames)
    return sorted(frames)


def board_image(images: npt.ArrayLike, codec: Codec) -> FloatArray:
    """The image the board is found in: the mean of :func:`board_frames`, else of all frames. (H, W) float64."""
    stack = np.asarray(images)
    frames = board_frames(codec) or list(range(stack.shape[0]))
    return np.mean(stack[frames].astype(np.float64), axis=0)


def _board_mask(corners: FloatArray, shape: tuple[int, int]) -> npt.NDArray[np.bool_]:
    mask = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(corners.astype(np.float32)).astype(np.int32)
    cv2.fillConvexPoly(mask, hull, 1)
    return mask.astype(bool)


def _mismatch_fraction(decoded: CodecDecoding, mask: npt.NDArray[np.bool_]) -> float:
    bad = 0
    total = 0
    for axis in decoded.axes.values():
        r = axis.reason[mask]
        b = int(np.count_nonzero((r == REASON_OUTSIDE) | (r == REASON_INCONSISTENT)))
        good = int(np.count_nonzero((r == REASON_VALID) | (r == REASON_SLIP_REPAIRED)))
        bad += b
        total += b + good
    return bad / total if total else 0.0


def _gamma_estimate(
    images: np.ndarray, codec: Codec, decoded: CodecDecoding, mask: npt.NDArray[np.bool_]
) -> float | None:
    if not codec.white or not codec.black:
        return None
    white = np.mean(images[list(codec.white)].astype(np.float64), axis=0)
    black = np.mean(images[list(codec.black)].astype(np.float64), axis=0)
    ratios = []
    for name, axis in codec.axes.items():
        if not axis.phase or axis.phase[0].waveform != "sine":
            continue
        dec = decoded.axes[name]
        span = white - black
        sel = mask & dec.valid & (span > 0.2 * float(np.percentile(span[mask], 95)))
        if np.count_nonzero(sel) < 50:
            continue
        ratios.append(float(np.median((dec.mean[sel] - black[sel]) / span[sel])))
    if not ratios:
        return None
    g = gamma_from_mean_ratio(float(np.median(ratios)))
    return g if math.isfinite(g) else None


def observe_pose(
    name: str,
    images: npt.ArrayLike,
    codec: Codec,
    board: BoardSpec,
    *,
    half_window: int | None = None,
    decode_options: CodecDecodeOptions | None = None,
) -> PoseObservation:
    """Decode one pose's stack and map its board points into the projector.

    Parameters
    ----------
    name : str
    images : (frames, H, W) uint8/uint16/float array, the codec's frame order
    codec : Codec
        Must code both axes.
    board : BoardSpec
    half_window : int, optional
        Half-size of each corner's homography window, pixels (default :func:`auto_window`).

    Returns
    -------
    PoseObservation
        With ``reason`` set when the board is not found.
    """
    if set(codec.axes) != {"u", "v"}:
        raise ValueError(f"--codec: projector calibration needs both axes coded, this codec codes {sorted(codec.axes)}")
    stack = np.asarray(images)
    corners = detect_board(board_image(stack, codec), board)
    if corners is None:
        return PoseObservation(
            name=name,
            camera_px=None,
            projector_px=None,
            reason="board not found in the board image",
            cause="board_not_found",
        )
    decoded = decode_codec(stack, codec, decode_options, with_noise=False)
    w = half_window if half_window is not None else auto_window(corners, board.cols)
    u_axis, v_axis = decoded.axes["u"], decoded.axes["v"]
    projected = project_corners(
        corners,
        u_axis.coordinate,
        v_axis.coordinate,
        w,
        modulation_u=u_axis.modulation,
        modulation_v=v_axis.modulation,
    )
    mask = _board_mask(corners, decoded.shape)
    return PoseObservation(
        name=name,
        camera_px=corners,
        projector_px=np.array([c.projector_px for c in projected]),
        decoded_fraction=np.array([c.decoded_fraction for c in projected]),
        fit_rms=np.array([c.fit_rms for c in projected]),
        mismatch_fraction=_mismatch_fraction(decoded, mask),
        gamma=_gamma_estimate(stack, codec, decoded, mask),
    )
