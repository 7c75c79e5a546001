"""The codec self-check (metrology.core.codecs.check) on virtual-rig renders of right and wrong descriptions.

Every right description is ``consistent``; every deliberately wrong one (phase origin off by a half
and a quarter period, reversed shift, word twice too wide or too narrow, lsb/msb order swapped, gray
origin off by half a word, inverted bits, swapped axes) is ``inconsistent`` on some axis or refused by
the codec's validation, never ``consistent`` on every axis. Renders are noise-free 16-bit of smooth
maps covering the projector, 144 x 200 camera pixels.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import Codec, CodecError, builtin_codec, codec_from_dict, render_codec
from metrology.core.codecs.check import CONSISTENT, INCONSISTENT, UNDETERMINED, worst_status
from metrology.core.codecs.decode import decode_codec
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack

PROJ_W, PROJ_H = 256, 192
PERIOD = 16.0


def smooth_maps(height: int = 144, width: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """True (u, v): a slightly curved, rotated view of the whole projector."""
    sy, sx = np.mgrid[0:height, 0:width] / np.array([height - 1, width - 1])[:, None, None]
    u = -0.45 + (PROJ_W - 0.1) * (0.97 * sx + 0.03 * sx**2) + 0.6 * np.sin(3 * sy)
    v = -0.45 + (PROJ_H - 0.1) * (0.96 * sy + 0.04 * sy * sx) + 0.4 * np.cos(2 * sx)
    return np.clip(u, -0.45, PROJ_W - 0.55), np.clip(v, -0.45, PROJ_H - 0.55)


U, V = smooth_maps()


def axis_spec(first: int, period: float, word: float, extent: int, phase: bool = True) -> tuple[dict[str, Any], int]:
    """A 4-step phase (origin -0.5) and an msb-first gray code (origin -0.5) from frame ``first``."""
    bits = max(1, int(np.ceil(np.log2((extent + 1) / word))))
    spec: dict[str, Any] = {}
    if phase:
        spec["phase"] = [{"frames": list(range(first, first + 4)), "period": period, "origin": -0.5}]
        first += 4
    spec["gray"] = {"frames": list(range(first, first + bits)), "word": word, "origin": -0.5}
    return spec, first + bits


def make_codec(u: dict[str, Any], v: dict[str, Any] | None, frames: int) -> Codec:
    axes = {"u": u} if v is None else {"u": u, "v": v}
    return codec_from_dict(
        {"codec": "gcps-codec/1", "frames": frames, "projector": {"width": PROJ_W, "height": PROJ_H}, "axes": axes}
    )


def right_codec(word: float) -> Codec:
    u, n = axis_spec(0, PERIOD, word, PROJ_W)
    v, n = axis_spec(n, PERIOD, word, PROJ_H)
    return make_codec(u, v, n)


def shifted_origin(fraction: float) -> Callable[[dict[str, Any]], None]:
    def change(axis: dict[str, Any]) -> None:
        axis["phase"][0]["origin"] += fraction * axis["phase"][0]["period"]

    return change


def gray_key(key: str, value: Callable[[Any], Any]) -> Callable[[dict[str, Any]], None]:
    def change(axis: dict[str, Any]) -> None:
        axis["gray"][key] = value(axis["gray"][key])

    return change


WRONG: dict[str, Callable[[dict[str, Any]], None]] = {
    "phase origin off by half a period": shifted_origin(0.5),
    "phase origin off by a quarter period": shifted_origin(0.25),
    "phase origin off by minus a quarter period": shifted_origin(-0.25),
    "reversed shift": lambda axis: axis["phase"][0].__setitem__("shift", -axis["phase"][0]["shift"]),
    "word twice too wide": gray_key("word", lambda w: 2 * w),
    "word twice too narrow": gray_key("word", lambda w: w / 2),
    "bit order": gray_key("order", lambda o: "lsb_first" if o == "msb_first" else "msb_first"),
    "gray origin off by half a word": lambda axis: axis["gray"].__setitem__(
        "origin", axis["gray"]["origin"] + axis["gray"]["word"] / 2
    ),
    "inverted bits": gray_key("inverted", lambda i: not i),
}


def check_of(codec: Codec, images: np.ndarray) -> dict[str, dict[str, Any]]:
    summary = decode_codec(images, codec).summary()
    return summary["codec_check"]  # type: ignore[no-any-return]


@pytest.fixture(scope="module", params=[1.0, 0.5, 0.25], ids=["word=period", "word=period/2", "word=period/4"])
def rendered(request: pytest.FixtureRequest) -> tuple[Codec, np.ndarray]:
    codec = right_codec(PERIOD * request.param)
    return codec, render_codec(codec, U, V)


def test_right_descriptions_are_consistent(rendered: tuple[Codec, np.ndarray]) -> None:
    codec, images = rendered
    check = check_of(codec, images)
    assert set(check) == {"u", "v"}
    for name, axis in check.items():
        assert axis["status"] == CONSISTENT, (name, axis)
        assert axis["message"] == ""
        assert abs(axis["offset_px"]) <= max(1.0, codec.axes[name].gray.word / 8)  # type: ignore[union-attr]
        assert axis["outside_share"] <= 0.05
        assert axis["outside_projector_share"] == 0


@pytest.mark.parametrize("wrong", list(WRONG))
def test_wrong_descriptions_are_inconsistent_or_refused(rendered: tuple[Codec, np.ndarray], wrong: str) -> None:
    codec, images = rendered
    data = copy.deepcopy(codec.to_dict())
    WRONG[wrong](data["axes"]["u"])
    try:
        described = codec_from_dict(data)
    except CodecError as exc:  # a word wider than the period it unwraps
        assert "wider than the period" in str(exc)
        return
    check = check_of(described, images)
    assert check["u"]["status"] == INCONSISTENT, check["u"]
    assert check["u"]["message"], "an inconsistent axis says why"
    assert check["v"]["status"] == CONSISTENT  # the other axis was described right


def test_swapped_axes_are_inconsistent(rendered: tuple[Codec, np.ndarray]) -> None:
    codec, images = rendered
    data = copy.deepcopy(codec.to_dict())
    data["axes"]["u"], data["axes"]["v"] = data["axes"]["v"], data["axes"]["u"]
    check = check_of(codec_from_dict(data), images)
    # the projector's columns decoded as rows reach beyond its height
    assert check["v"]["status"] == INCONSISTENT
    assert "outside the projector" in check["v"]["message"]
    assert worst_status(check) == INCONSISTENT
    if codec.axes["u"].gray.word >= 8:  # type: ignore[union-attr]
        assert check["v"]["message"].startswith("Axes look swapped")


@pytest.mark.parametrize(
    ("wrong", "word", "says"),
    [
        ("phase origin off by half a period", 8.0, "origin should be -0.5, not 7.5 (axes.u.phase[0].origin)"),
        ("phase origin off by a quarter period", 16.0, "origin should be -0.5, not 3.5 (axes.u.phase[0].origin)"),
        ("phase origin off by minus a quarter period", 4.0, "origin should be -0.5, not -4.5"),
        ("reversed shift", 16.0, "shift looks reversed (axes.u.phase[*].shift should be [1], not [-1])"),
        ("reversed shift", 4.0, "shift looks reversed"),
        ("word twice too wide", 8.0, "word looks twice too wide (axes.u.gray.word should be 8, not 16)"),
        ("word twice too narrow", 16.0, "word looks twice too narrow (axes.u.gray.word should be 16, not 8)"),
        ("bit order", 8.0, "bit order looks wrong (axes.u.gray.order should be msb_first)"),
        ("inverted bits", 16.0, "bits look inverted (axes.u.gray.inverted should be false)"),
    ],
)
def test_the_message_names_the_likely_correction(wrong: str, word: float, says: str) -> None:
    codec = right_codec(word)
    images = render_codec(codec, U, V)
    data = copy.deepcopy(codec.to_dict())
    WRONG[wrong](data["axes"]["u"])
    message = check_of(codec_from_dict(data), images)["u"]["message"]
    assert says in message.lower(), message


def test_too_few_pixels_are_undetermined_and_say_why() -> None:
    codec = right_codec(PERIOD)
    u = U.copy()
    u[4:, :] = np.nan  # the projector lights a strip of 4 rows only
    images = render_codec(codec, u, None if "v" not in codec.axes else np.where(np.isfinite(u), V, np.nan))
    check = check_of(codec, images)
    assert check["u"]["status"] == UNDETERMINED
    assert "only" in check["u"]["message"] and "pixels" in check["u"]["message"]


def test_a_word_wider_than_the_period_it_unwraps_is_refused_naming_both() -> None:
    u, n = axis_spec(0, PERIOD, 2 * PERIOD, PROJ_W)
    with pytest.raises(CodecError, match=r"gray word \(32\) is wider than the period 16 of phase:0"):
        make_codec(u, None, n)
    u, n = axis_spec(0, PERIOD, PERIOD, PROJ_W)
    make_codec(u, None, n)  # equal stays valid (slips are repaired)


def test_axes_without_gray_or_phase_are_not_checked() -> None:
    u, n = axis_spec(0, PERIOD, 1.0, PROJ_W, phase=False)
    codec = codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": n + 2,
            "white": [n],
            "black": [n + 1],
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "axes": {"u": u},
        }
    )
    assert check_of(codec, render_codec(codec, U, None)) == {}


@pytest.mark.slow
@pytest.mark.parametrize("options", [None, SimulationOptions.realistic_8bit()], ids=["noise-free", "realistic"])
def test_gcps_v1_renders_of_the_virtual_rig_are_consistent(options: SimulationOptions | None) -> None:
    rendered = render_stack(PAPER_RIG, make_scene("sphere"), options)
    check = check_of(builtin_codec("gcps-v1"), rendered.images)
    assert check["u"]["status"] == CONSISTENT, check["u"]
