"""The codec model: validation naming every bad field, JSON round trip, natural order, gcps-v1."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import (
    CodecError,
    builtin_codec,
    codec_from_dict,
    codec_from_json,
    codec_patterns,
    gcps_v1_codec,
    natural_key,
    read_codec,
    write_codec,
)
from metrology.core.codecs.stack import select_frames
from metrology.core.io import StackError
from metrology.core.patterns import projector_patterns

ISSUE_EXAMPLE: dict[str, Any] = {
    "codec": "gcps-codec/1",
    "frames": 40,
    "projector": {"width": 1280, "height": 800},
    "white": [38],
    "black": [39],
    "axes": {
        "u": {
            "phase": [
                {
                    "frames": list(range(12)),
                    "period": 16.0,
                    "shift": 1,
                    "origin": 0.0,
                    "waveform": "square",
                }
            ],
            "gray": {
                "frames": list(range(12, 19)),
                "order": "lsb_first",
                "word": 16.0,
                "origin": -0.5,
                "inverse_frames": None,
                "inverted": False,
            },
        },
        "v": {
            "phase": [{"frames": list(range(19, 31)), "period": 16.0}],
            "gray": {"frames": list(range(31, 37)), "word": 16.0, "order": "msb_first"},
        },
    },
}


def test_issue_example_parses_and_round_trips(tmp_path: Path) -> None:
    codec = codec_from_dict(ISSUE_EXAMPLE)
    assert codec.n_frames == 40
    assert codec.axes["u"].phase[0].waveform == "square"
    assert codec.axes["v"].gray is not None and codec.axes["v"].gray.bits == 6
    path = tmp_path / "c.json"
    write_codec(codec, path)
    again = read_codec(path)
    assert again == codec
    assert json.loads(path.read_text())["codec"] == "gcps-codec/1"


def _bad(mutate: Any) -> str:
    data = copy.deepcopy(ISSUE_EXAMPLE)
    mutate(data)
    with pytest.raises(CodecError) as info:
        codec_from_dict(data)
    return str(info.value)


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda d: d.update(colour=1), "unknown key 'colour'"),
        (lambda d: d["axes"]["u"]["phase"][0].update(perod=3), "axes.u.phase[0] has unknown key 'perod'"),
        (lambda d: d["axes"]["u"]["gray"].update(wordd=3), "axes.u.gray has unknown key 'wordd'"),
        (lambda d: d["axes"].update(w={}), "axes has unknown key 'w'"),
        (lambda d: d.update(codec="gcps-codec/2"), "codec must be 'gcps-codec/1'"),
        (lambda d: d["axes"]["u"]["phase"][0].update(frames=[0, 1]), "axes.u.phase[0].frames must hold N >= 3"),
        (lambda d: d["axes"]["u"]["phase"][0].update(period=0), "axes.u.phase[0].period must be > 0"),
        (lambda d: d["axes"]["u"]["phase"][0].update(period=-2.0), "axes.u.phase[0].period must be > 0"),
        (lambda d: d["axes"]["u"]["phase"][0].update(shift=2), "axes.u.phase[0].shift must be 1 or -1"),
        (lambda d: d["axes"]["u"]["phase"][0].update(waveform="tri"), "axes.u.phase[0].waveform"),
        (lambda d: d["axes"]["u"]["gray"].update(word=0), "axes.u.gray.word must be > 0"),
        (lambda d: d["axes"]["u"]["gray"].update(order="msb"), "axes.u.gray.order"),
        (lambda d: d["axes"]["u"]["phase"][0]["frames"].__setitem__(3, 40), "axes.u.phase[0].frames[3] = 40 is out"),
        (lambda d: d["axes"]["u"]["gray"].update(inverse_frames=[37]), "inverse_frames must hold one frame per bit"),
        (lambda d: d["axes"]["v"]["gray"]["frames"].__setitem__(0, 5), "uses frame 5, already used by axes.u.phase"),
        (lambda d: d.update(black=[38]), "uses frame 38, already used by white[0]"),
        (lambda d: d["axes"]["u"].update(unwrap=["phase:0", "gray"]), "'gray' can only be the first stage"),
        (lambda d: d["axes"]["u"].update(unwrap=["gray", "phase:3"]), "axes.u.unwrap[1] = 'phase:3'"),
        (lambda d: d["axes"]["u"].update(unwrap=["gray", "beat:0,0"]), "a beat needs two different periods"),
        (lambda d: d["axes"]["u"].update(unwrap=["gray", "phse:0"]), "is not 'gray', 'phase:I' or 'beat:I,J'"),
        (lambda d: d["axes"]["u"].update(unwrap=["phase:0"]), "shorter than the projector's 1280 px"),
        (lambda d: d["axes"]["u"].update(unwrap=[]), "axes.u.unwrap must not be empty"),
        (lambda d: d["axes"].update(u={}), "axes.u codes nothing"),
        (lambda d: d.update(axes={}), "must code at least one axis"),
        (lambda d: d["projector"].update(width=0), "projector.width must be a positive integer"),
        (lambda d: d.update(frames=[]), "frames must not be an empty list"),
        (lambda d: d.update(frames="x"), "frames must be a number of frames or a list"),
        (lambda d: d.pop("projector"), "missing the required key 'projector'"),
        (lambda d: d["axes"]["u"]["phase"][0].pop("period"), "axes.u.phase[0] is missing the required key 'period'"),
        # bounded values (issue 23 item 6): projector sides, periods and words
        (lambda d: d["projector"].update(width=16385), "projector.width must be at most 16384 pixels, got 16385"),
        (lambda d: d["projector"].update(height=10**9), "projector.height must be at most 16384 pixels"),
        (lambda d: d["axes"]["u"]["phase"][0].update(period=1e308), "axes.u.phase[0].period must be at most 64 times"),
        (lambda d: d["axes"]["u"]["phase"][0].update(period=float("inf")), "axes.u.phase[0].period must be a finite"),
        (lambda d: d["axes"]["u"]["phase"][0].update(period=float("nan")), "axes.u.phase[0].period must be a finite"),
        (lambda d: d["axes"]["u"]["gray"].update(word=64 * 1280 + 1), "axes.u.gray.word must be at most 64 times"),
        (lambda d: d["axes"]["v"]["gray"].update(word=64 * 800 + 1), "(64 x 800 = 51200 px), got 51201"),
        (lambda d: d["axes"]["v"]["phase"][0].update(period=1e300), "axes.v.phase[0].period must be at most 64"),
        (lambda d: d["axes"]["u"]["gray"].update(origin=float("-inf")), "axes.u.gray.origin must be a finite"),
    ],
)
def test_every_bad_field_is_named(mutate: Any, expected: str) -> None:
    assert expected in _bad(mutate)


def test_gray_without_threshold_source_is_refused() -> None:
    def mutate(d: dict[str, Any]) -> None:
        d.pop("white")
        d.pop("black")
        d["axes"]["u"].pop("phase")

    assert "axes.u.gray has no threshold source" in _bad(mutate)


def test_gray_only_with_inverse_frames_is_fine() -> None:
    data = {
        "codec": "gcps-codec/1",
        "frames": 4,
        "projector": {"width": 4, "height": 4},
        "axes": {"u": {"gray": {"frames": [0, 2], "inverse_frames": [1, 3], "word": 1, "origin": -0.5}}},
    }
    codec = codec_from_dict(data)
    assert codec.axes["u"].chain()[0].kind == "gray"


def test_beat_stage_period_and_origin() -> None:
    periods = (200 / 3, 100.0)
    phase = [{"frames": [3 * i, 3 * i + 1, 3 * i + 2], "period": p, "origin": p / 3} for i, p in enumerate(periods)]
    gray = {"frames": [6, 8, 10, 12, 14], "inverse_frames": [7, 9, 11, 13, 15], "word": 100.0}
    axis = {"phase": phase, "gray": gray, "unwrap": ["gray", "beat:0,1", "phase:1", "phase:0"]}
    codec = codec_from_dict(
        {"codec": "gcps-codec/1", "frames": 16, "projector": {"width": 1920, "height": 1080}, "axes": {"u": axis}}
    )
    stages = codec.axes["u"].chain()
    assert [s.label for s in stages] == ["gray", "beat:0,1", "phase:1", "phase:0"]
    beat = stages[1]
    # P_b = P_s P_l / (P_l - P_s) = (200/3) 100 / (100 - 200/3) = 200; o_b = P_b (o_s/P_s - o_l/P_l) = 0
    assert beat.period == pytest.approx(200.0, abs=1e-9)
    assert beat.origin == pytest.approx(0.0, abs=1e-9)


def test_bad_json_text_is_named() -> None:
    with pytest.raises(CodecError, match="codec is not valid JSON"):
        codec_from_json("{")


def test_natural_order() -> None:
    names = ["10.bmp", "2.bmp", "01.bmp", "00.Bmp", "pat1.png", "Pat0.png"]
    assert sorted(names, key=natural_key) == ["00.Bmp", "01.bmp", "2.bmp", "10.bmp", "Pat0.png", "pat1.png"]


def test_frame_selection_by_count_and_glob() -> None:
    codec = codec_from_dict(
        {
            **ISSUE_EXAMPLE,
            "frames": 3,
            "files": "pat*.png",
            "white": [],
            "black": [],
            "axes": {"u": {"phase": [{"frames": [0, 1, 2], "period": 4000.0}]}},
        }
    )
    names = ["pat10.png", "pat2.png", "pat1.png", "color.png", "config.xml"]
    assert select_frames(codec, names) == ["pat1.png", "pat2.png", "pat10.png"]
    with pytest.raises(StackError, match=r"holds 2 image files matching 'pat\*.png' but the codec describes 3"):
        select_frames(codec, ["pat1.png", "pat2.png"])


def test_frame_selection_by_names() -> None:
    codec = gcps_v1_codec()
    names = [f"{n}.png" for n in codec.frames if isinstance(codec.frames, tuple)]
    assert select_frames(codec, [*reversed(names), "notes.txt"]) == names
    with pytest.raises(StackError, match=r"missing frame file\(s\) PS_3"):
        select_frames(codec, names[:-1])


def test_gcps_v1_codec_reproduces_the_eleven_patterns() -> None:
    codec = builtin_codec("gcps-v1:1024x768")
    assert codec.name == "gcps-v1" and codec.n_frames == 11
    np.testing.assert_array_equal(codec_patterns(codec), projector_patterns(1024, 768))
    small = gcps_v1_codec(640, 16, nlp=64)
    np.testing.assert_array_equal(codec_patterns(small), projector_patterns(640, 16, nlp=64))
    with pytest.raises(CodecError, match="WIDTHxHEIGHT"):
        builtin_codec("gcps-v1:big")


def test_a_codec_file_with_out_of_range_numbers_or_deep_nesting_is_refused_naming_it() -> None:
    text = json.dumps(ISSUE_EXAMPLE).replace('"period": 16.0, "shift"', '"period": 1e400, "shift"')
    with pytest.raises(CodecError, match=r"axes\.u\.phase\[0\]\.period must be a finite number, got inf"):
        codec_from_json(text)
    for depth in (17, 100_000):
        nested = json.dumps(ISSUE_EXAMPLE).replace('"white": [38]', '"white": ' + "[" * depth + "]" * depth)
        with pytest.raises(CodecError, match=r"c\.json is nested deeper than 16 levels"):
            codec_from_json(nested, label="c.json")


def test_the_largest_projector_and_longest_period_are_accepted() -> None:
    data = copy.deepcopy(ISSUE_EXAMPLE)
    data["projector"] = {"width": 16384, "height": 16384}
    data["axes"]["u"]["phase"].append({"frames": [37, 38, 39], "period": 64.0 * 16384})
    data.pop("white")
    data.pop("black")
    data["axes"]["u"]["unwrap"] = ["gray", "phase:0"]
    codec = codec_from_dict(data)
    assert codec.projector_width == 16384 and codec.axes["u"].phase[1].period == 64 * 16384
