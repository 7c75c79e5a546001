"""Beats of beats: the chain grammar ``beat:X,Y`` with X, Y a phase index or a parenthesised pair.

Three-frequency heterodyne without a gray code (64, 58 and 53 periods across the projector:
beats of 6 and 5 periods, then their beat of 1 period covering the projector) and a depth-3
four-frequency chain round-trip through the virtual rig within 0.01 px noise-free; with the
realistic 8-bit camera the coordinate scatter matches the decoder's own noise estimate
(``stage_coordinate_sigma``) within 20 %, with no pixel off by half a period.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import CodecError, codec_from_dict, render_codec
from metrology.core.codecs.chain import ChainSyntaxError, parse_stage_label
from metrology.core.simulate import SimulationOptions
from metrology.core.uncertainty import stage_coordinate_sigma
from tests.core.codecs.roundtrips import affine_truth, assert_round_trip, decode_inner, truth_maps

WIDTH, HEIGHT = 1024, 768
THREE = ["beat:(0,1),(1,2)", "beat:0,1", "phase:0"]


def heterodyne_axis(first: int, counts: tuple[int, ...], extent: int, steps: int, unwrap: list[str]) -> dict[str, Any]:
    """Phase sequences of ``counts`` periods across ``extent``, ``steps`` frames each, from frame ``first``."""
    phase = [
        {"frames": list(range(first + steps * i, first + steps * (i + 1))), "period": extent / n, "origin": 0.1 * i}
        for i, n in enumerate(counts)
    ]
    return {"phase": phase, "unwrap": unwrap}


def codec_of(axes: dict[str, Any], frames: int) -> Any:
    return codec_from_dict(
        {"codec": "gcps-codec/1", "frames": frames, "projector": {"width": WIDTH, "height": HEIGHT}, "axes": axes}
    )


def test_beat_of_beats_period_origin_and_weights() -> None:
    codec = codec_of({"u": heterodyne_axis(0, (64, 58, 53), WIDTH, 4, THREE)}, 12)
    top, beat, fine = codec.axes["u"].chain()
    assert [s.label for s in (top, beat, fine)] == THREE
    # P_01 = W / 6, P_12 = W / 5; their beat: (W/6)(W/5) / (W/5 - W/6) = W
    assert top.period == pytest.approx(WIDTH, rel=1e-12)
    assert beat.period == pytest.approx(WIDTH / 6, rel=1e-12)
    # origins by the beat rule: o_01 = P_01 (o_0 / P_0 - o_1 / P_1), o_12 likewise, o = P (o_01 / P_01 - o_12 / P_12)
    p = [WIDTH / n for n in (64, 58, 53)]
    o = [0.0, 0.1, 0.2]
    o01 = (WIDTH / 6) * (o[0] / p[0] - o[1] / p[1])
    o12 = (WIDTH / 5) * (o[1] / p[1] - o[2] / p[2])
    assert top.origin == pytest.approx(WIDTH * (o01 / (WIDTH / 6) - o12 / (WIDTH / 5)), abs=1e-9)
    assert top.phase_weights() == {0: 1, 1: -2, 2: 1}
    assert top.indices == (0, 1, 2)


def test_stage_grammar() -> None:
    assert parse_stage_label("beat:((0,1),(1,2)),3").text == "beat:((0,1),(1,2)),3"
    assert parse_stage_label(" beat: (0, 1), (1, 2) ").text == "beat:(0,1),(1,2)"
    assert parse_stage_label("beat:0,1").tree is not None
    for bad in ("beat:(0,1)", "beat:0", "beat:(0,1,2),3", "beat:0,1)", "phase:(0,1)", "beat:a,b", "bet:0,1"):
        with pytest.raises(ChainSyntaxError):
            parse_stage_label(bad)


@pytest.mark.parametrize(
    ("unwrap", "message"),
    [
        (["beat:(0,1),(1,3)", "phase:0"], r"axes.u.unwrap\[0\] = 'beat:\(0,1\),\(1,3\)': the axis has 3 phase"),
        (["beat:(0,1),(0,1)", "phase:0"], r"axes.u.unwrap\[0\] .* a beat needs two different periods"),
        (["beat:(0,1),(1,2", "phase:0"], r"axes.u.unwrap\[0\] = 'beat:\(0,1\),\(1,2' is not 'gray'"),
        (["beat:(0,1),(1,2)", "beat:(0, 1),(1, 2)"], r"axes.u.unwrap repeats a stage"),
        (["beat:0,1", "phase:0"], r"axes.u: the first unwrapping stage beat:0,1 has period 170.667, shorter than"),
    ],
)
def test_bad_chains_name_the_field(unwrap: list[str], message: str) -> None:
    with pytest.raises(CodecError, match=message):
        codec_of({"u": heterodyne_axis(0, (64, 58, 53), WIDTH, 4, unwrap)}, 12)


def test_first_stage_covers_the_projector_up_to_rounding() -> None:
    # W/64, W/58, W/53: the beat of beats is W up to 2e-16 relative (the rule allows 1e-9)
    codec = codec_of({"u": heterodyne_axis(0, (64, 58, 53), WIDTH, 4, THREE)}, 12)
    assert codec.axes["u"].chain()[0].period <= WIDTH
    with pytest.raises(CodecError, match="shorter than the projector's 1024 px"):
        codec_of({"u": heterodyne_axis(0, (64, 58, 53), WIDTH * (1 - 2e-9), 4, THREE)}, 12)


def test_three_frequency_heterodyne_both_axes_noise_free() -> None:
    u, v = truth_maps(proj_w=WIDTH, proj_h=HEIGHT)
    # v: 48, 44, 41 periods across 768: beats of 4 and 3, their beat of 1
    axes = {
        "u": heterodyne_axis(0, (64, 58, 53), WIDTH, 4, THREE),
        "v": heterodyne_axis(12, (48, 44, 41), HEIGHT, 4, THREE),
    }
    assert_round_trip(codec_of(axes, 24), u, v)


def test_depth_three_four_frequency_chain_noise_free() -> None:
    # 64, 58, 53, 50 periods: beats of 6, 5, 3; (6, 5) -> 1, (5, 3) -> 2; their beat -> 1 period
    unwrap = ["beat:((0,1),(1,2)),((1,2),(2,3))", "beat:(1,2),(2,3)", "beat:0,1", "phase:0"]
    codec = codec_of({"u": heterodyne_axis(0, (64, 58, 53, 50), WIDTH, 4, unwrap)}, 16)
    stages = codec.axes["u"].chain()
    assert [round(WIDTH / s.period, 9) for s in stages] == [1, 2, 6, 64]
    u, _ = truth_maps(proj_w=WIDTH, proj_h=HEIGHT)
    assert_round_trip(codec, u, np.full_like(u, np.nan))


def test_three_frequency_heterodyne_realistic_noise_at_the_decoders_estimate() -> None:
    opts = SimulationOptions.realistic_8bit()
    height, width = 24, 480
    # an affine map over ~1010 of the 1024 projector px
    u_fine, u_centre = affine_truth(height, width, opts.supersample, 4.0, 2.1, 0.05)
    codec = codec_of({"u": heterodyne_axis(0, (64, 58, 53), WIDTH, 8, THREE)}, 24)
    final_period = WIDTH / 64
    measured, predicted = [], []
    for seed in range(2):
        images = render_codec(codec, u_fine, None, opts, seed=seed)
        axis, valid = decode_inner(images, codec)
        error = axis.coordinate[valid] - u_centre[valid]
        assert np.abs(error).max() < final_period / 2  # no period slip anywhere
        sigma = stage_coordinate_sigma(codec, "u", axis.noise, axis.modulation)[valid]
        measured.append(float(np.mean(error**2)))
        predicted.append(float(np.mean(sigma.astype(np.float64) ** 2)))
    ratio = math.sqrt(np.mean(measured) / np.mean(predicted))
    print(
        f"three-frequency heterodyne: measured {math.sqrt(np.mean(measured)):.4f} px, decoder estimate "
        f"{math.sqrt(np.mean(predicted)):.4f} px, ratio {ratio:.3f}"
    )
    assert 1 / 1.2 < ratio < 1.2
