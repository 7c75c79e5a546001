"""`gcps rig import` (a contract): every source format gives the same rig file; every bad source is named."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.geometry.pinhole import PinholeRig
from tests.datasets import dataset_path, require_dataset

ROOT = Path(__file__).resolve().parents[2]
KAMINO = dataset_path("kamino410-procam-calibration", "calibration_result.rerun.xml")

CAM_K = np.array([[2301.123456789012, 0.0, 1023.4567], [0.0, 2299.87654321, 767.25], [0.0, 0.0, 1.0]])
CAM_D = np.array([-0.112233445566, 0.0987654321, 0.000123456, -0.000654321, -0.0123456789])
PROJ_K = np.array([[1500.5, 0.0, 640.25], [0.0, 1499.75, 400.125], [0.0, 0.0, 1.0]])
PROJ_D = np.array([0.0312, -0.0456, 0.0001, 0.0002])
RVEC = np.array([0.01234, -0.3456, 0.0078])
R = cv2.Rodrigues(RVEC)[0]
T = np.array([210.123456789, -5.5, 18.25])
VALUES = {"camera_K": CAM_K, "camera_dist": CAM_D, "projector_K": PROJ_K, "projector_dist": PROJ_D, "R": R, "T": T}
SIZES = ["--camera-size", "2048", "1536", "--projector-size", "1280", "800"]


def _import(out: Path, *args: str) -> int:
    return main(["--quiet", "rig", "import", "--out", str(out), *SIZES, *args])


def _sets(sources: dict[str, str]) -> list[str]:
    return [arg for key, src in sources.items() for arg in ("--set", f"{key}={src}")]


def _write_filestorage(path: Path, names: dict[str, str], first: dict[str, np.ndarray] | None = None) -> None:
    """The values of ``names`` (key -> node) as a FileStorage file, after the nodes ``first`` (node -> value)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for node, value in (first or {}).items():
        fs.write(node, value)
    for key, node in names.items():
        value = VALUES[key]
        fs.write(node, value if value.ndim == 2 else value.reshape(1, -1))
    fs.release()


def _text(value: np.ndarray, sep: str, newline: str) -> str:
    rows = value.reshape(-1, 3) if value.size % 3 == 0 else value.reshape(1, -1)
    return newline.join(sep.join(repr(float(x)) for x in row) for row in rows) + newline


@pytest.fixture(scope="module")
def reference_file(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    root = tmp_path_factory.mktemp("ref")
    for key, value in VALUES.items():
        np.save(root / f"{key}.npy", value)
    out = root / "rig.json"
    assert _import(out, *_sets({key: str(root / f"{key}.npy") for key in VALUES})) == 0
    return out.read_bytes()


def test_reference_rig_holds_the_values(reference_file: bytes) -> None:
    rig = PinholeRig.from_json(reference_file.decode())
    assert np.array_equal(np.asarray(rig.camera.K), CAM_K)
    assert np.array_equal(np.asarray(rig.projector.dist), PROJ_D)
    assert np.array_equal(np.asarray(rig.R), R)
    assert np.array_equal(np.asarray(rig.T), T)
    sizes = (rig.camera.width_px, rig.camera.height_px, rig.projector.width, rig.projector.height)
    assert sizes == (2048, 1536, 1280, 800)


@pytest.mark.parametrize("fmt", ["yml", "xml", "yml-plain", "text-crlf-commas", "text-tabs", "npz", "json"])
def test_every_format_gives_the_identical_file(tmp_path: Path, reference_file: bytes, fmt: str) -> None:
    sources: dict[str, str] = {}
    if fmt in ("yml", "xml"):
        names = {key: f"node_{key}" for key in VALUES}
        path = tmp_path / f"calib.{fmt}"
        _write_filestorage(path, names)
        sources = {key: f"{path}#{node}" for key, node in names.items()}
    elif fmt == "yml-plain":
        path = tmp_path / "calib.yaml"
        lines = ["%YAML:1.0", "---"]
        for key, value in VALUES.items():
            rows = value.reshape(-1, 3) if value.ndim == 2 else value.reshape(1, -1)
            nested = "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in rows) + "]"
            lines.append(f"{key}: {nested if value.ndim == 2 else nested[1:-1]}")
        path.write_text("\n".join(lines) + "\n")
        sources = {key: f"{path}#{key}" for key in VALUES}
    elif fmt.startswith("text"):
        sep, newline = (", ", "\r\n") if fmt == "text-crlf-commas" else ("\t", "\n")
        for key, value in VALUES.items():
            (tmp_path / f"{key}.txt").write_bytes(_text(value, sep, newline).encode())
            sources[key] = str(tmp_path / f"{key}.txt")
    elif fmt == "npz":
        np.savez(tmp_path / "calib.npz", **{f"a_{key}": value for key, value in VALUES.items()})
        sources = {key: f"{tmp_path / 'calib.npz'}#a_{key}" for key in VALUES}
    else:
        doc = {"calib": {key: value.tolist() for key, value in VALUES.items()}}
        (tmp_path / "calib.json").write_text(json.dumps(doc))
        sources = {key: f"{tmp_path / 'calib.json'}#calib.{key}" for key in VALUES}
    out = tmp_path / "rig.json"
    assert _import(out, *_sets(sources)) == 0
    assert out.read_bytes() == reference_file


def test_opencv_file_found_by_node_names(
    tmp_path: Path, reference_file: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "stereo.yml"
    names = {"camera_K": "cameraMatrix", "camera_dist": "distCoeffs", "projector_K": "proj_int"}
    names.update({"projector_dist": "proj_dist", "R": "R", "T": "T"})
    _write_filestorage(path, names)
    out = tmp_path / "rig.json"
    assert main(["rig", "import", "--out", str(out), *SIZES, "--opencv", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["read"] == {key: f"{path}#{node}" for key, node in names.items()}
    assert out.read_bytes() == reference_file


def test_a_file_that_numbers_its_devices_is_read_by_its_node_names(
    tmp_path: Path, reference_file: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    """``M1 D1`` camera, ``M4 D4`` projector, ``Rlp Tlp`` pose and ``S`` the image size as (width, height):
    the same rig as the reference, and the summary names each node and where the size came from."""
    path = tmp_path / "numbered.yml"
    names = {"camera_K": "M1", "camera_dist": "D1", "projector_K": "M4", "projector_dist": "D4"}
    names.update({"R": "Rlp", "T": "Tlp"})
    _write_filestorage(path, names, first={"S": np.array([[2048.0, 1536.0]])})
    out = tmp_path / "rig.json"
    args = ["rig", "import", "--out", str(out), "--projector-size", "1280", "800", "--opencv", str(path)]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["read"] == {key: f"{path}#{node}" for key, node in names.items()}
    assert summary["camera_size"] == {"value": [2048, 1536], "from": f"{path}#S (width, height)"}
    assert out.read_bytes() == reference_file


def test_rvec_instead_of_r(tmp_path: Path, reference_file: bytes) -> None:
    for key, value in VALUES.items():
        np.save(tmp_path / f"{key}.npy", value)
    np.savetxt(tmp_path / "rvec.txt", RVEC)
    sources = {key: str(tmp_path / f"{key}.npy") for key in VALUES if key != "R"}
    sources["rvec"] = str(tmp_path / "rvec.txt")
    out = tmp_path / "rig.json"
    assert _import(out, *_sets(sources)) == 0
    rig = PinholeRig.from_json(out.read_text())
    assert np.abs(np.asarray(rig.R) - R).max() < 1e-15 * 10


def _bad_sources(tmp: Path) -> list[tuple[str, str, str]]:
    """(key, SRC, expected message fragment) for malformed sources."""
    (tmp / "k6.txt").write_text("1 2 3\n4 5 6\n")
    (tmp / "word.txt").write_text("1 2 3\n4 five 6\n7 8 9\n")
    (tmp / "empty.txt").write_text("\n")
    (tmp / "dist6.txt").write_text("0 0 0 0 0 0\n")
    (tmp / "t.json").write_text('{"a": {"b": [1, 2, 3]}}')
    (tmp / "broken.json").write_text('{"a": ')
    np.savez(tmp / "c.npz", K=CAM_K)
    (tmp / "c.yml").write_text("%YAML:1.0\nK: [1, 2, 3]\n")
    (tmp / "garbage.xml").write_text("<not><closed>")
    return [
        ("camera_K", str(tmp / "k6.txt"), "camera_K from '{src}' has 6 element(s); camera_K needs 9"),
        ("camera_K", str(tmp / "word.txt"), "camera_K from '{src}': 'five' is not a number"),
        ("T", str(tmp / "empty.txt"), "T from '{src}': the text file holds no numbers"),
        ("camera_dist", str(tmp / "dist6.txt"), "camera_dist from '{src}' has 6 element(s)"),
        ("T", str(tmp / "missing.txt"), "T from '{src}': file"),
        ("T", f"{tmp / 't.json'}#a.c", "no key 'c'"),
        ("T", str(tmp / "t.json"), "name the value"),
        ("T", f"{tmp / 'broken.json'}#a", "not valid JSON"),
        ("camera_K", f"{tmp / 'c.npz'}#M", "no array 'M' (the file has K)"),
        ("T", f"{tmp / 'c.yml'}#nope", "no node 'nope'"),
        ("camera_K", f"{tmp / 'c.yml'}#K", "camera_K from '{src}' has 3 element(s); camera_K needs 9"),
        ("T", f"{tmp / 'garbage.xml'}#T", "T from '{src}'"),
    ]


def test_every_malformed_source_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for key, value in VALUES.items():
        np.save(tmp_path / f"{key}.npy", value)
    good = {key: str(tmp_path / f"{key}.npy") for key in VALUES}
    for key, src, message in _bad_sources(tmp_path):
        out = tmp_path / "rig.json"
        assert _import(out, *_sets({**good, key: src})) == 2, src
        err = capsys.readouterr().err
        assert err.startswith("gcps: error: ") and err.count("\n") == 1
        assert message.format(src=src) in err, (src, err)
        assert not out.exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"colour": "x.npy"}, "unknown key 'colour'"),
        ({"R": "diag"}, "R is not a rotation"),
        ({"T": None}, "T is missing"),
        ({"R": None}, "R is missing"),
        ({"camera_K": "neg"}, "camera K must have fx > 0"),
        ({"T": "far"}, "T[2] must be within +-100000 mm, got 1e+308"),
        ({"camera_dist": "wild"}, "camera dist[0] must be within +-10000, got 1e+300"),
    ],
)
def test_bad_values_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str], change: dict, message: str) -> None:
    for key, value in VALUES.items():
        np.save(tmp_path / f"{key}.npy", value)
    np.save(tmp_path / "diag.npy", np.diag([1.0, 1.0, 1.001]))
    np.save(tmp_path / "neg.npy", CAM_K * np.array([[-1.0], [1.0], [1.0]]))
    np.save(tmp_path / "far.npy", np.array([0.0, 0.0, 1e308]))
    np.save(tmp_path / "wild.npy", np.array([1e300, 0.0, 0.0, 0.0, 0.0]))
    sources: dict[str, str] = {key: str(tmp_path / f"{key}.npy") for key in VALUES}
    for key, name in change.items():
        if name is None:
            del sources[key]
        else:
            sources[key] = str(tmp_path / name) if name.endswith(".npy") else str(tmp_path / f"{name}.npy")
    out = tmp_path / "rig.json"
    assert _import(out, *_sets(sources)) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_kamino410_calibration_imports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Real data: the kamino410 procam calibration (OpenCV XML) imports with --opencv."""
    require_dataset(KAMINO, "kamino410 procam calibration result")
    out = tmp_path / "kamino.json"
    args = ["rig", "import", "--out", str(out), "--projector-size", "1024", "768", "--opencv", str(KAMINO)]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["read"]) == {"camera_K", "camera_dist", "projector_K", "projector_dist", "R", "T"}
    assert summary["read"]["camera_K"].endswith("#cam_int")
    assert summary["camera_size"]["value"] == [1280, 1024]
    rig = PinholeRig.from_json(out.read_text())
    assert rig.camera.K[0][0] == pytest.approx(3452.3929070220047, abs=1e-9)
    assert rig.projector.K[1][2] == pytest.approx(648.33381544261283, abs=1e-9)
    assert np.allclose(rig.T, (88.004970130542176, -641.64704381088495, -80.404851098951013), rtol=0, atol=1e-12)
    assert summary["triangulate_auto"] == "v"  # vertical baseline: rows are coded planes crossed steeply
    prep = rig.prepare()
    assert prep.axis == "v"
    rays = prep.camera_rays()
    assert rays.direction.shape == (1024, 1280, 3)
