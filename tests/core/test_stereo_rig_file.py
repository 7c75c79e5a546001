"""The stereo rig file (issue 24's contract): read, validated, written back, registered."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from metrology.core.geometry import MODELS, GeometryError, GeometryOptions, model_from_dict, model_from_parameters
from metrology.core.geometry.stereo import StereoRig

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "stereo-rig.json"


@pytest.fixture()
def rig_file() -> dict:
    return json.loads(EXAMPLE.read_text())


def test_the_example_round_trips(rig_file):
    rig = model_from_dict(rig_file)
    assert isinstance(rig, StereoRig) and MODELS["stereo"] is StereoRig
    assert rig.to_dict() == rig_file
    assert model_from_parameters("stereo", rig.parameters()) == rig
    assert rig.shape == (1024, 1280) and rig.camera_shapes == ((1024, 1280), (1024, 1280))
    assert rig.cameras == 2 and not rig.requires_reference and rig.unreferenced_result == "depth"
    assert not rig.projector.calibrated
    assert 150.0 < rig.baseline_mm < 150.2


def test_a_calibrated_projector_round_trips(rig_file):
    rig_file["projector"].update(
        K=[[2000.0, 0, 960], [0, 2000.0, 540], [0, 0, 1]],
        dist=[0.01, 0, 0, 0],
        R=[[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        T=[-75, 0, 0],
    )
    rig = model_from_dict(rig_file)
    assert rig.projector.calibrated and rig.to_dict() == rig_file


def _edit(data: dict, path: tuple, value: object) -> dict:
    data = copy.deepcopy(data)
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("cameras",), [], "exactly 2 cameras, got 0"),
        (("cameras", 0, "R"), [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "cameras[0] has unknown key 'R'"),
        (("cameras", 1, "R"), KeyError, "cameras[1] is missing key 'R'"),
        (("cameras", 1, "R"), [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "cameras[1] R is not a rotation"),
        (("cameras", 1, "T"), [0, 0, 0], "cameras[1] T must not be zero"),
        (("cameras", 1, "T"), [1, 2], "cameras[1] T must be a list of three numbers"),
        (("cameras", 0, "K"), [[-5, 0, 1], [0, 5, 1], [0, 0, 1]], "cameras[0] K must have fx > 0"),
        (("cameras", 1, "width_px"), 0, "cameras[1] width_px must be a positive integer"),
        (("cameras", 0, "dist"), [1, 2, 3], "cameras[0] dist must hold 4, 5, 8, 12 or 14"),
        (("cameras", 1, "focus"), 3, "cameras[1] has unknown key 'focus'"),
        (("projector", "width"), KeyError, "projector is missing key 'width'"),
        (("projector", "K"), [[2000, 0, 960], [0, 2000, 540], [0, 0, 1]], "projector is missing key 'R'"),
        (("projector", "gamma"), 2.2, "projector has unknown key 'gamma'"),
        (("baseline",), 1, "stereo rig has unknown key 'baseline'"),
    ],
)
def test_bad_values_are_refused_naming_the_key(rig_file, path, value, message):
    with pytest.raises(GeometryError) as err:
        model_from_dict(_edit(rig_file, path, value))
    assert message in str(err.value)


def test_the_codec_must_fit(rig_file):
    rig = model_from_dict(rig_file)
    rig.check_codec((1920, 1080), ("u",))
    with pytest.raises(GeometryError, match="codec's projector is 1024x768 but the rig's projector is 1920x1080"):
        rig.check_codec((1024, 768), ("u",))
    with pytest.raises(GeometryError, match="does not code the projector's u axis"):
        rig.check_codec((1920, 1080), ("v",))
    with pytest.raises(GeometryError, match="method 'midpoint'"):
        rig.check_codec((1920, 1080), ("u",), GeometryOptions(method="midpoint"))
