"""Fusion of multi-exposure captures per pixel, for every codec family (issue 26, docs/exposures.md):
each pixel takes the exposure of largest modulation among those where it decoded and none of its
frames saturates; saturation inside one exposure never leaks into the result."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metrology.core.codecs import Codec, read_codec, render_codec
from metrology.core.codecs.decode import REASON_SATURATED, decode_codec
from metrology.core.codecs.exposures import NO_EXPOSURE, decode_exposures
from metrology.core.codecs.model import gcps_v1_codec
from metrology.core.codecs.stack import ExposureStack
from metrology.core.io.exposures import Exposure
from metrology.core.simulate import SimulationOptions
from tests.core.codecs.roundtrips import PROJ_H, axis_spec, bits_for, make_codec, truth_maps

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def _gray_inverse() -> Codec:
    """Phase and gray code with inverse frames on u, a 3-step phase and lsb-first gray on v."""
    u, first = axis_spec(0, 4, 16.0, bits=bits_for(16.0), inverse=True)
    v, end = axis_spec(first, 3, 12.0, bits=bits_for(12.0, PROJ_H), order="lsb_first", shift=-1)
    return make_codec(u, v, end + 2, white=[end], black=[end + 1])


def _codecs() -> dict[str, Codec]:
    return {
        "gcps-v1": gcps_v1_codec(),
        "three-frequency": read_codec(str(EXAMPLES / "three-frequency.codec.json")),
        "gray-inverse": _gray_inverse(),
    }


CODECS = _codecs()
EXPOSURES = (Exposure("short", 1000.0), Exposure("long", 2000.0))


def _render(codec: Codec, relative: float, options: SimulationOptions) -> np.ndarray:
    u, v = truth_maps(proj_w=codec.projector_width, proj_h=codec.projector_height, shadow=False)
    return render_codec(
        codec, u if "u" in codec.axes else None, v if "v" in codec.axes else None, options, albedo=0.45 * relative
    )


def _stack(codec: Codec, options: SimulationOptions) -> ExposureStack:
    return ExposureStack(tuple(_render(codec, e.exposure_us / 1000.0, options) for e in EXPOSURES), EXPOSURES)


@pytest.mark.parametrize("name", sorted(CODECS))
@pytest.mark.parametrize("frame_kind", ["first phase", "last"])
def test_saturation_in_one_frame_of_the_best_exposure_never_leaks(name: str, frame_kind: str) -> None:
    codec = CODECS[name]
    stack = _stack(codec, SimulationOptions.realistic_8bit(seed=5, supersample=1))
    # the long exposure is the best one (twice the modulation, no saturation anywhere)
    assert max(int(images.max()) for images in stack.images) < 255
    axis = next(iter(codec.axes))
    phase_frame = codec.axes[axis].phase[0].frames[0]
    # the first phase frame, or the codec's last frame (black, a gray bit, another phase sequence)
    frame = phase_frame if frame_kind == "first phase" else codec.n_frames - 1
    # two pixels both exposures decode
    both_valid = np.logical_and.reduce(
        [decode_codec(images, codec).axes[a].valid for images in stack.images for a in codec.axes]
    )
    rows, cols = np.nonzero(both_valid[10:-10, 10:-10])
    one, both = (int(rows[0]) + 10, int(cols[0]) + 10), (int(rows[-1]) + 10, int(cols[-1]) + 10)
    long_images = stack.images[1].copy()
    long_images[frame][one] = 255
    long_images[frame][both] = 255
    short_images = stack.images[0].copy()
    short_images[frame][both] = 255
    stack = ExposureStack((short_images, long_images), EXPOSURES)

    fused = decode_exposures(stack, codec)
    short, long_ = decode_codec(short_images, codec), decode_codec(long_images, codec)
    for name_axis, axis_fused in fused.axes.items():
        index = fused.exposure[name_axis]
        # everywhere else the long exposure measured, as decoded alone
        good = long_.axes[name_axis].valid
        good[one] = good[both] = False
        assert (index[good] == 1).all()
        np.testing.assert_array_equal(axis_fused.coordinate[good], long_.axes[name_axis].coordinate[good])
        # the pixel saturated in one frame of the long exposure: the short exposure's decoding, whole
        assert index[one] == 0
        for key in ("coordinate", "modulation", "mean", "noise", "reason"):
            np.testing.assert_array_equal(
                getattr(axis_fused, key)[one], getattr(short.axes[name_axis], key)[one], err_msg=key
            )
        # saturated in every exposure: not measured, saturated
        assert index[both] == NO_EXPOSURE
        assert np.isnan(axis_fused.coordinate[both]) and axis_fused.reason[both] == REASON_SATURATED
    assert fused.saturated_pixels == 1
    quality = fused.quality_arrays()
    assert quality[f"exposure_{axis}"].dtype == np.uint8
    pixels = fused.summary()["exposures"]["pixels"][axis]
    first = fused.exposure[axis]
    assert pixels["none"] == int(np.count_nonzero(first == NO_EXPOSURE)) >= 1
    assert pixels["short"] == int(np.count_nonzero(first == 0)) >= 1
    assert sum(pixels.values()) == first.size


@pytest.mark.parametrize("name", sorted(CODECS))
def test_one_exposure_fuses_to_its_own_decoding(name: str) -> None:
    """A one-exposure capture without saturation decodes exactly as the single stack."""
    codec = CODECS[name]
    images = _render(codec, 1.0, SimulationOptions.realistic_8bit(seed=6, supersample=1))
    fused = decode_exposures(ExposureStack.single(images), codec)
    alone = decode_codec(images, codec)
    for axis in codec.axes:
        for key in ("coordinate", "modulation", "noise", "reason"):
            np.testing.assert_array_equal(getattr(fused.axes[axis], key), getattr(alone.axes[axis], key))
        valid = alone.axes[axis].valid
        assert (fused.exposure[axis][valid] == 0).all() and (fused.exposure[axis][~valid] == NO_EXPOSURE).all()


def test_the_largest_modulation_wins_where_both_decode() -> None:
    codec = CODECS["three-frequency"]
    stack = _stack(codec, SimulationOptions.noise_free_16bit())
    fused = decode_exposures(stack, codec)
    long_ = decode_codec(stack.images[1], codec)
    valid = long_.axes["u"].valid
    assert valid.mean() > 0.9
    assert (fused.exposure["u"][valid] == 1).all()
