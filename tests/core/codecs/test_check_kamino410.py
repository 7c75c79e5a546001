"""The codec self-check on a real capture: kamino410 phase-shifting ``object1`` (3-step phases of
200/3 and 100 px, gray words of 100 px with inverse frames, both axes; MIT licensed, outside the
repository). Its own description is ``consistent`` on both axes; each deliberately wrong one is
``inconsistent`` on some axis or refused, never ``consistent`` on both."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import Codec, CodecError, codec_from_dict, read_codec
from metrology.core.codecs.check import CONSISTENT, INCONSISTENT, worst_status
from metrology.core.codecs.decode import decode_codec
from metrology.core.codecs.stack import read_codec_stack
from tests.datasets import dataset_path, require_dataset

DATASET = dataset_path("kamino410-phase-shifting")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def capture() -> tuple[Codec, np.ndarray]:
    require_dataset(DATASET / "object1", "kamino410 dataset")
    codec = read_codec(DATASET / "object1.codec.json")
    return codec, read_codec_stack(DATASET / "object1", codec).images


def every_phase(change: Callable[[dict[str, Any]], None]) -> Callable[[dict[str, Any]], None]:
    def apply(axis: dict[str, Any]) -> None:
        for sequence in axis["phase"]:
            change(sequence)

    return apply


def one_phase(index: int, fraction: float) -> Callable[[dict[str, Any]], None]:
    def apply(axis: dict[str, Any]) -> None:
        axis["phase"][index]["origin"] += fraction * axis["phase"][index]["period"]

    return apply


WRONG: dict[str, Callable[[dict[str, Any]], None]] = {
    "origins off by half a period": every_phase(lambda p: p.__setitem__("origin", p["origin"] + p["period"] / 2)),
    "origins 0 (the -120, 0, +120 degree shifts read as 0, 120, 240)": every_phase(
        lambda p: p.__setitem__("origin", 0.0)
    ),
    "100 px origin off by half a period": one_phase(1, 0.5),
    "100 px origin off by a quarter period": one_phase(1, 0.25),
    "66.7 px origin off by half a period": one_phase(0, 0.5),
    "reversed shifts": every_phase(lambda p: p.__setitem__("shift", -p["shift"])),
    "word twice too wide": lambda axis: axis["gray"].__setitem__("word", 200.0),
    "word twice too narrow": lambda axis: axis["gray"].__setitem__("word", 50.0),
    "lsb first": lambda axis: axis["gray"].__setitem__("order", "lsb_first"),
    "gray origin off by half a word": lambda axis: axis["gray"].__setitem__("origin", 50.0),
    "inverted bits": lambda axis: axis["gray"].__setitem__("inverted", True),
}


def test_its_own_description_is_consistent(capture: tuple[Codec, np.ndarray]) -> None:
    codec, images = capture
    check = decode_codec(images, codec, with_noise=False).summary()["codec_check"]
    for name in ("u", "v"):
        assert check[name]["status"] == CONSISTENT, check[name]
        assert abs(check[name]["offset_px"]) <= 100 / 8 and check[name]["outside_share"] <= 0.05


@pytest.mark.parametrize("wrong", [*WRONG, "swapped axes"])
def test_wrong_descriptions_are_inconsistent(capture: tuple[Codec, np.ndarray], wrong: str) -> None:
    codec, images = capture
    data = copy.deepcopy(codec.to_dict())
    if wrong == "swapped axes":
        data["axes"]["u"], data["axes"]["v"] = data["axes"]["v"], data["axes"]["u"]
    else:
        for name in ("u", "v"):
            WRONG[wrong](data["axes"][name])
    try:
        described = codec_from_dict(data)
    except CodecError as exc:
        assert "wider than the period" in str(exc)
        return
    check = decode_codec(images, described, with_noise=False).summary()["codec_check"]
    assert worst_status(check) == INCONSISTENT, check
    assert all(axis["message"] for axis in check.values() if axis["status"] != CONSISTENT)


@pytest.mark.parametrize(
    ("wrong", "says"),
    [
        ("100 px origin off by half a period", "origin should be 33.3333, not 83.3333 (axes.u.phase[1].origin)"),
        ("66.7 px origin off by half a period", "origin should be 22.2222, not 55.5556 (axes.u.phase[0].origin)"),
        ("origins off by half a period", "origins should be 22.2222, 33.3333, not 55.5556, 83.3333"),
        ("reversed shifts", "shift looks reversed"),
        ("word twice too wide", "word looks twice too wide (axes.u.gray.word should be 100, not 200)"),
        ("lsb first", "bit order looks wrong (axes.u.gray.order should be msb_first)"),
        ("gray origin off by half a word", "gray origin should be 0, not 50 (axes.u.gray.origin)"),
    ],
)
def test_the_message_names_the_correction(capture: tuple[Codec, np.ndarray], wrong: str, says: str) -> None:
    codec, images = capture
    data = copy.deepcopy(codec.to_dict())
    WRONG[wrong](data["axes"]["u"])
    check = decode_codec(images, codec_from_dict(data), with_noise=False).summary()["codec_check"]
    assert says in check["u"]["message"].lower(), check["u"]["message"]
