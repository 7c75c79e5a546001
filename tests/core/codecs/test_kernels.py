"""The compiled phase-sum kernel (:mod:`metrology.core.codecs.kernels`) gives the OpenCV passes' bits.

The decoder uses the kernel only where its module is loaded (a worker, a benchmark), so a
``gcps decode`` process and a worker must decode the same stack to the same bits: the kernel's
sums are compared bit for bit with the OpenCV passes (``accumulate``, ``accumulateSquare``,
``accumulateWeighted``) on random 8-bit frames, against the exact sums (float64), and whole
decodes of realistic 8-bit renders with and without the kernel are compared output by output.
The kernel's module is unloaded after each test, so that the other tests decode as a
``gcps decode`` process does.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from dataclasses import replace
from types import ModuleType

import numpy as np
import pytest

from metrology.core.codecs import Codec, codec_from_dict, render_codec
from metrology.core.codecs.decode import (
    KERNELS_MODULE,
    _opencv_sums,
    _plan,
    compiled_kernels,
    decode_codec,
    repair_slips,
    slip_candidates,
)
from metrology.core.simulate import SimulationOptions
from metrology.core.tiling import thread_scratch
from tests.core.codecs.roundtrips import axis_spec, make_codec, multilevel_codec, truth_maps


@pytest.fixture
def kernels() -> Iterator[ModuleType]:
    """The kernel's module, loaded for the test and unloaded after it."""
    was_loaded = KERNELS_MODULE in sys.modules
    module = importlib.import_module(KERNELS_MODULE)
    module.warm()
    yield module
    if not was_loaded:
        sys.modules.pop(KERNELS_MODULE, None)


def phase_codec(steps: int, shift: int, frames: int | None = None) -> Codec:
    """u only: one ``steps``-step phase sequence of period 16 px, 4 gray bits of 16-px words."""
    spec, n = axis_spec(0, steps, 16.0, bits=4, shift=shift)
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": frames or n,
            "projector": {"width": 256, "height": 192},
            "axes": {"u": spec},
        }
    )


@pytest.mark.parametrize(("steps", "shift"), [(3, 1), (4, -1), (5, 1), (8, 1), (18, 1)])
def test_the_kernel_sums_are_the_opencv_passes_bits(kernels: ModuleType, steps: int, shift: int) -> None:
    """Random 8-bit frames, an odd frame size (a partial last chunk) and a tile inside it: the
    total and the sum of squares are the exact integers, ``K C`` and ``-K S`` the OpenCV running
    averages to the bit and the exact ``K sum w_k I_k`` within 2e-6 of its scale."""
    codec = phase_codec(steps, shift)
    seq = _plan(codec, with_noise=True)[0].sequences[0]
    seq = replace(seq, need_noise=True)
    rng = np.random.default_rng(steps)
    height, width = 29, 157  # 4553 px: two full chunks of 2048 and a partial one
    stack = rng.integers(0, 256, (codec.n_frames, height, width), dtype=np.uint8)
    stack[:, 3, :7] = 255  # full scale
    rows = slice(2, 27)
    tile = stack[:, rows]
    h = rows.stop - rows.start
    scratch = thread_scratch()
    total = np.empty((h, width), np.float32)
    squares = np.empty((h, width), np.float32)
    sums = np.empty((2, h * width), np.float32)
    scale = _opencv_sums(tile, seq, total, squares, sums, scratch)
    k_total, k_squares, k_sums = np.empty_like(total), np.empty_like(squares), np.empty_like(sums)
    flat = stack.reshape(codec.n_frames, -1)
    start = rows.start * width
    kernels.phase_sums_u8(
        flat, start, start + h * width, seq.frame_index, seq.recursive_f32, k_total.ravel(), k_sums[0], k_sums[1],
        k_squares.ravel(), True, np.empty(0, np.uint8), 0,
    )  # fmt: skip
    np.testing.assert_array_equal(k_total, total)
    np.testing.assert_array_equal(k_squares, squares)
    np.testing.assert_array_equal(k_sums, sums)
    frames = tile[list(seq.frames)].astype(np.float64)
    np.testing.assert_array_equal(k_total, frames.sum(axis=0))
    np.testing.assert_array_equal(k_squares, (frames**2).sum(axis=0))
    exact = scale * np.tensordot(seq.weights[:2].astype(np.float64), frames, 1).reshape(2, -1)
    assert np.abs(k_sums - exact).max() <= 2e-6 * 255 * steps * scale
    without_squares = np.full_like(k_squares, -1.0)
    kernels.phase_sums_u8(
        flat, start, start + h * width, seq.frame_index, seq.recursive_f32, k_total.ravel(), k_sums[0], k_sums[1],
        without_squares.ravel(), False, peak := np.full(h * width, 7, np.uint8), 2,
    )  # fmt: skip
    np.testing.assert_array_equal(peak, np.maximum(tile[list(seq.frames)].max(axis=0).ravel(), 7))
    assert (without_squares == -1.0).all()  # not written


def realistic(codec: Codec, seed: int) -> np.ndarray:
    u, v = truth_maps()
    axes = codec.axes
    return render_codec(
        codec,
        u if "u" in axes else None,
        v if "v" in axes else None,
        SimulationOptions.realistic_8bit(supersample=1),
        seed=seed,
    )


def two_axis_beat_codec() -> Codec:
    """The kamino410 layout at 256x192: per axis 3-step phases of 64/3 and 32 px (a 64-px beat),
    a gray code of 32-px words with inverse frames; white, black."""

    def axis(first: int, gray: range) -> dict[str, object]:
        p = 64 / 3
        return {
            "phase": [
                {"frames": [first, first + 1, first + 2], "period": p, "origin": p / 3},
                {"frames": [first + 3, first + 4, first + 5], "period": 32.0, "origin": 32 / 3},
            ],
            "gray": {"frames": list(gray[0::2]), "inverse_frames": list(gray[1::2]), "word": 32.0, "origin": -0.5},
            "unwrap": ["gray", "beat:0,1", "phase:1", "phase:0"],
        }

    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 26,
            "projector": {"width": 256, "height": 192},
            "white": [24],
            "black": [25],
            "axes": {"u": axis(0, range(12, 18)), "v": axis(6, range(18, 24))},
        }
    )


def white_black_codec() -> Codec:
    """u: 8 phase steps of period 16 px, 4 gray bits of 16-px words thresholded at the white/black
    mean (no inverse frames); v: a gray code with inverse frames only; white, black."""
    u, n = axis_spec(0, 8, 16.0, bits=4)
    v, n = axis_spec(n, None, 8.0, bits=5, inverse=True, word=8.0)
    return make_codec(u, v, n + 2, white=[n], black=[n + 1])


CODECS = {
    "18 steps + gray": lambda: phase_codec(18, 1),
    "3 steps, beats, inverse gray, two axes": two_axis_beat_codec,
    "white/black threshold, gray-only inverse axis": white_black_codec,
    "4-level gray + phase": lambda: multilevel_codec(4, 3, 4.0),
}


@pytest.mark.parametrize("name", list(CODECS))
def test_decoding_with_the_kernel_gives_the_same_bits(kernels: ModuleType, name: str) -> None:
    """Realistic 8-bit renders decoded with the kernels loaded and without them (as ``gcps decode``
    runs): every output map (to the bit, NaN included), the slips and the summary are the same;
    with saturated patches (a phase frame and a gray frame) and coordinates made to slip."""
    codec = CODECS[name]()
    stack = realistic(codec, seed=5)
    stack[:, 5:9, 10:16] = np.maximum(stack[:, 5:9, 10:16], 200)
    stack[0, 5:9, 10:13] = 255  # saturated in a phase (or gray) frame: refused or flagged
    stack[-3, 20:23, 40:44] = 255  # a later frame: flagged
    gray = next(iter(codec.axes.values())).gray
    if gray is not None:  # bits misread at a few pixels: slips to repair (or to refuse)
        f = gray.frames[-1]
        stack[f, 30:32, 50:52] = 255 - stack[f, 30:32, 50:52]
    with_kernel = decode_codec(stack, codec)
    assert compiled_kernels() is kernels
    sys.modules.pop(KERNELS_MODULE)
    try:
        assert compiled_kernels() is None
        without = decode_codec(stack, codec)
    finally:
        sys.modules[KERNELS_MODULE] = kernels
    for axis, a in without.axes.items():
        b = with_kernel.axes[axis]
        assert a.valid.mean() > 0.5, axis
        for field in ("coordinate", "modulation", "mean", "noise"):
            bits = np.dtype(f"u{getattr(a, field).itemsize}")
            assert np.array_equal(getattr(b, field).view(bits), getattr(a, field).view(bits)), f"{axis} {field}"
        np.testing.assert_array_equal(b.reason, a.reason, err_msg=f"{axis} reason")
        assert b.slips_repaired == a.slips_repaired
    assert with_kernel.summary() == without.summary()
    assert with_kernel.saturated_pixels == without.saturated_pixels > 0


def test_the_slip_kernels_are_the_numpy_slip_search_and_repair(kernels: ModuleType) -> None:
    """Coordinates with NaN holes, whole-period slips (single pixels, a 2x2 block, pixels at the
    borders) and a depth edge: the compiled jump search gives numpy's candidates, and the compiled
    repair moves the same pixels to the same bits (with and without the gray-word bound)."""
    rng = np.random.default_rng(3)
    h, w, period = 40, 57, 16.0
    x = (np.arange(w, dtype=np.float32)[None, :] * 3.1 + rng.normal(0, 0.2, (h, w))).astype(np.float32)
    x[:, 40:] += 300  # a depth edge
    x[rng.random((h, w)) < 0.1] = np.nan
    centre = (np.floor(x / period) * period + period / 2).astype(np.float32)  # the true words
    x[[3, 17, 0, 39, 25], [5, 30, 0, 56, 41]] += np.float32(period) * np.array([1, -2, 1, 1, 3], np.float32)
    x[10:12, 20:22] -= np.float32(period)
    centre[17, 30] += 5 * period  # this pixel's moved coordinate is out of its word's reach
    reason = np.where(np.isnan(x), 1, 0).astype(np.uint8)
    with_kernel = slip_candidates(x, period / 2)
    sys.modules.pop(KERNELS_MODULE)
    try:
        without = slip_candidates(x, period / 2)
        expected = []
        for bound in (None, centre):
            xn, rn = x.copy(), reason.copy()
            expected.append((repair_slips(xn, rn, period, 4.0, without, bound, 8.0 + 0.25 * period), xn, rn))
    finally:
        sys.modules[KERNELS_MODULE] = kernels
    np.testing.assert_array_equal(with_kernel, without)
    assert without.size > 20
    for bound, (count, xn, rn) in zip((None, centre), expected, strict=True):
        xk, rk = x.copy(), reason.copy()
        assert repair_slips(xk, rk, period, 4.0, with_kernel, bound, 8.0 + 0.25 * period) == count >= 4
        assert np.array_equal(xk.view(np.uint32), xn.view(np.uint32))
        np.testing.assert_array_equal(rk, rn)
