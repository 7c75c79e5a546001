"""`gcps rig import` of two-camera calibrations (issue 24, a contract): an OpenCV FileStorage file with
``M1 D1 M2 D2`` and a pose (``R T`` or ``Rlr Tlr``) and no projector node is a stereo rig; the same
rig as YAML, XML and npz (through ``--set``) gives byte-identical rig files; errors name the node."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.geometry import model_from_dict
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.geometry.stereo import StereoRig

M1 = np.array([[1402.123456789, 0.0, 641.25], [0.0, 1401.5, 511.75], [0.0, 0.0, 1.0]])
D1 = np.array([-0.0812345678, 0.1234567, 0.00012, -0.00034, -0.0456789])
M2 = np.array([[1398.987654321, 0.0, 633.5], [0.0, 1399.25, 520.125], [0.0, 0.0, 1.0]])
D2 = np.array([-0.0798765, 0.1111111, -0.00021, 0.00043, -0.0401234])
R = cv2.Rodrigues(np.array([0.0123, -0.2345, 0.0067]))[0]
T = np.array([-182.123456789, 1.5, 12.25])
VALUES = {"M1": M1, "D1": D1, "M2": M2, "D2": D2, "R": R, "T": T}
SIZE = (1280, 1024)
PROJECTOR = ["--projector-size", "1920", "1080"]


def _write_filestorage(path: Path, values: dict[str, np.ndarray]) -> None:
    """``values`` (node -> array) as an OpenCV FileStorage file (YAML or XML by ``path``'s extension),
    after ``S`` (width, height) and the rectification nodes OpenCV's stereo sample also writes."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("S", np.array([SIZE], dtype=np.float64))
    for node, value in values.items():
        fs.write(node, value if value.ndim == 2 else value.reshape(1, -1))
    fs.write("R1", np.eye(3))
    fs.write("P1", np.hstack([M1, np.zeros((3, 1))]))
    fs.release()


def _import(out: Path, *args: str) -> int:
    return main(["--quiet", "rig", "import", "--out", str(out), *PROJECTOR, *args])


@pytest.fixture(scope="module")
def npz_rig(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The rig file written from an npz through ``--set`` (the reference the other formats must equal)."""
    root = tmp_path_factory.mktemp("npz")
    npz = root / "stereo.npz"
    np.savez(npz, **VALUES)
    keys = {"camera0_K": "M1", "camera0_dist": "D1", "camera1_K": "M2", "camera1_dist": "D2", "R": "R", "T": "T"}
    sets = [arg for key, node in keys.items() for arg in ("--set", f"{key}={npz}#{node}")]
    out = root / "rig.json"
    assert _import(out, "--camera-size", *map(str, SIZE), *sets) == 0
    return out.read_bytes()


def test_the_npz_rig_is_a_stereo_rig_with_the_values(npz_rig: bytes) -> None:
    rig = model_from_dict(json.loads(npz_rig))
    assert isinstance(rig, StereoRig)
    data = rig.to_dict()
    assert np.array_equal(data["cameras"][0]["K"], M1) and np.array_equal(data["cameras"][0]["dist"], D1)
    assert np.array_equal(data["cameras"][1]["K"], M2) and np.array_equal(data["cameras"][1]["dist"], D2)
    assert np.array_equal(data["cameras"][1]["R"], R) and np.array_equal(data["cameras"][1]["T"], T)
    assert [data["cameras"][i]["width_px"] for i in (0, 1)] == [1280, 1280]
    assert data["projector"] == {"width": 1920, "height": 1080}


@pytest.mark.parametrize(("ext", "pose_nodes"), [("yml", ("R", "T")), ("xml", ("R", "T")), ("xml", ("Rlr", "Tlr"))])
def test_yaml_and_xml_give_the_npz_rig_byte_for_byte(
    tmp_path: Path, npz_rig: bytes, capsys: pytest.CaptureFixture[str], ext: str, pose_nodes: tuple[str, str]
) -> None:
    values = dict(VALUES)
    values[pose_nodes[0]], values[pose_nodes[1]] = values.pop("R"), values.pop("T")
    path = tmp_path / f"stereo.{ext}"
    _write_filestorage(path, values)
    out = tmp_path / "rig.json"
    assert main(["rig", "import", "--out", str(out), *PROJECTOR, "--opencv", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["model"] == "stereo"
    expected = {"camera0_K": "M1", "camera0_dist": "D1", "camera1_K": "M2", "camera1_dist": "D2"}
    expected.update({"R": pose_nodes[0], "T": pose_nodes[1]})
    assert summary["read"] == {key: f"{path}#{node}" for key, node in expected.items()}
    assert summary["camera_size"] == {"value": list(SIZE), "from": f"{path}#S (width, height)"}
    assert out.read_bytes() == npz_rig


def test_model_overrides_recognition_and_a_projector_node_keeps_the_file_a_pinhole_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--model pinhole`` reads a two-camera file as today (``M2 D2`` the projector); a file with a
    projector node (``M4``) is not a two-camera file."""
    path = tmp_path / "stereo.yml"
    _write_filestorage(path, VALUES)
    out = tmp_path / "rig.json"
    assert _import(out, "--opencv", str(path), "--model", "pinhole") == 0
    rig = PinholeRig.from_json(out.read_text())
    assert np.array_equal(np.asarray(rig.projector.K), M2) and np.array_equal(np.asarray(rig.T), T)
    with_projector = tmp_path / "procam.yml"
    _write_filestorage(with_projector, {**VALUES, "M4": M2, "D4": D2})
    assert _import(out, "--opencv", str(with_projector)) == 0
    assert json.loads(out.read_text())["model"] == "pinhole"
    assert np.array_equal(np.asarray(PinholeRig.from_json(out.read_text()).projector.K), M2)


def test_set_overrides_a_node_and_a_calibrated_projector_comes_in_through_set(tmp_path: Path) -> None:
    path = tmp_path / "stereo.yml"
    _write_filestorage(path, VALUES)
    npz = tmp_path / "more.npz"
    K2 = M2 + np.diag([1.0, 1.0, 0.0])
    Kp = np.array([[2000.0, 0.0, 960.0], [0.0, 2000.0, 540.0], [0.0, 0.0, 1.0]])
    Rp = cv2.Rodrigues(np.array([0.0, -0.1, 0.0]))[0]
    np.savez(npz, K2=K2, Kp=Kp, Rp=Rp, Tp=np.array([-90.0, 0.0, 5.0]))
    sets = ["camera1_K=K2", "projector_K=Kp", "projector_R=Rp", "projector_T=Tp"]
    args = [arg for item in sets for arg in ("--set", item.replace("=", f"={npz}#"))]
    out = tmp_path / "rig.json"
    assert _import(out, "--opencv", str(path), *args) == 0
    data = json.loads(out.read_text())
    assert np.array_equal(data["cameras"][1]["K"], K2)
    assert np.array_equal(data["projector"]["K"], Kp) and data["projector"]["T"] == [-90.0, 0.0, 5.0]
    assert model_from_dict(data).to_dict() == data


@pytest.mark.parametrize(
    ("change", "args", "message"),
    [
        ({"M2": np.ones((2, 3))}, [], "camera1_K from '{path}#M2' has 6 element(s)"),
        ({"D1": np.ones((1, 7))}, [], "camera0_dist from '{path}#D1' has 7 element(s)"),
        ({"R": 2 * np.eye(3)}, [], "cameras[1] R is not a rotation"),
        ({"T": np.zeros(3)}, [], "cameras[1] T"),
        ({}, ["--set", "camera_K=x.npy"], "unknown key 'camera_K' for a stereo rig"),
        ({}, ["--set", "camera0_K={path}#M9"], "no node 'M9'"),
    ],
)
def test_errors_name_the_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: dict, args: list[str], message: str
) -> None:
    path = tmp_path / "stereo.yml"
    _write_filestorage(path, {**VALUES, **change})
    out = tmp_path / "rig.json"
    code = main(
        ["rig", "import", "--out", str(out), *PROJECTOR, "--opencv", str(path), *(a.format(path=path) for a in args)]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message.format(path=path) in err[0], err
    assert not out.exists()


def test_model_stereo_names_the_missing_camera(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "one.yml"
    _write_filestorage(path, {"M1": M1, "D1": D1, "R": R, "T": T})
    out = tmp_path / "rig.json"
    code = main(["rig", "import", "--out", str(out), *PROJECTOR, "--opencv", str(path), "--model", "stereo"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "camera1_K is missing" in err and "--set camera1_K=SRC" in err


def test_the_example_stereo_calibration_imports_to_the_example_stereo_rig(tmp_path: Path) -> None:
    """examples/stereo-calibration.yml (OpenCV's stereo layout with its rectification nodes) is
    examples/stereo-rig.json: the command of docs/stereo-calibration.md."""
    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "rig.json"
    example = root / "examples" / "stereo-calibration.yml"
    assert _import(out, "--opencv", str(example)) == 0
    expected = model_from_dict(json.loads((root / "examples" / "stereo-rig.json").read_text()))
    assert model_from_dict(json.loads(out.read_text())) == expected
