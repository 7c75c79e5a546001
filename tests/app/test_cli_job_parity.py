"""The same stacks through the ``gcps`` command and through a job give the same results, on the
paper's rig and on a pinhole rig.

Realistic 8-bit renders (noise, camera and projector blur), so the mixed-pixel filter and the
camera-blur correction matter: both doors must run the one pipeline (:mod:`metrology.pipeline`).
Jobs run in-process (the embedded mode), through the same handler a Celery worker calls.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import write_rig, write_series, write_stack
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, SimulationOptions, render_capture, render_series, render_stack
from metrology.version import software_version
from tests.app.stacks import SMALL_RIG, png, stack_zip, zip_bytes
from tests.pinhole_stacks import CODEC
from tests.pinhole_stacks import RIG as PINHOLE_RIG

pytestmark = pytest.mark.django_db(transaction=True)
CORE_RIG = Rig.from_dict(SMALL_RIG)
OPTIONS = SimulationOptions.realistic_8bit(seed=11)
START = {"L_mm": 1040.0, "alpha_rad": 0.35}  # the calibrations' rough start


@pytest.fixture(scope="module")
def stacks() -> dict[str, np.ndarray]:
    images = {
        "reference": render_stack(CORE_RIG, make_scene("reference", CORE_RIG), OPTIONS).images,
        "block": render_stack(CORE_RIG, make_scene("block", CORE_RIG, top_mm=40.0), OPTIONS).images,
    }
    for z, repeat, rendered in render_series(CORE_RIG, [0.0, 4.0, 8.0], 2, OPTIONS):
        images[f"stage_{z:g}_{repeat}"] = rendered.images
    return images


def upload(api, rig_id: int, images: np.ndarray, role: str, **fields) -> int:
    handle = io.BytesIO(stack_zip(images))
    handle.name = f"{role}.zip"
    response = api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role, **fields}, format="multipart")
    assert response.status_code == 201, response.content
    return response.json()["id"]


def cli(*args: str) -> None:
    assert main(["--quiet", *args]) == 0


def folder(tmp_path: Path, name: str, images: np.ndarray) -> str:
    write_stack(images, tmp_path / name)
    return str(tmp_path / name)


def test_measure_calibrate_characterize_agree_between_command_and_job(api, rig, stacks, tmp_path):
    rig_file = tmp_path / "rig.json"
    write_rig(CORE_RIG, rig_file)
    ref_dir = folder(tmp_path, "ref", stacks["reference"])
    block_dir = folder(tmp_path, "block", stacks["block"])
    reference = upload(api, rig["id"], stacks["reference"], "reference")

    # measure: bit-identical heights, the same options and software version
    cli("measure", "--rig", str(rig_file), "--reference", ref_dir, "--object", block_dir,
        "--out", str(tmp_path / "z.npy"), "--json", str(tmp_path / "m.json"))  # fmt: skip
    obj = upload(api, rig["id"], stacks["block"], "object")
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    job_z = np.load(io.BytesIO(b"".join(api.get(f"/api/measurements/{body['id']}/height.npy").streaming_content)))
    cli_z = np.load(tmp_path / "z.npy")
    assert np.isfinite(cli_z).mean() > 0.8
    np.testing.assert_array_equal(job_z, cli_z)  # NaN where NaN, every height to the bit
    stats = json.loads((tmp_path / "m.json").read_text())
    assert body["options"] == stats["options"] and body["options"]["decode"]["edge_band_px"] == 2
    assert body["software_version"] == stats["software_version"] == software_version()

    # calibrate (lsq) from the same rough start: identical calibrated values
    start_file = tmp_path / "start.json"
    write_rig(CORE_RIG.with_parameters(**START), start_file)
    cli("calibrate", "--rig", str(start_file), "--reference", ref_dir, "--master", block_dir,
        "--master-height", "40", "--out", str(tmp_path / "cal.json"))  # fmt: skip
    master = upload(api, rig["id"], stacks["block"], "master")
    response = api.post(
        "/api/calibrations/",
        {"rig": rig["id"], "reference": reference, "master": master, "master_height_mm": 40.0, "initial": START},
        format="json",
    )
    body = api.get(f"/api/calibrations/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    calibrated = json.loads((tmp_path / "cal.json").read_text())
    for key in ("L_mm", "alpha_rad", "d_mm"):
        assert body["result"][key] == calibrated[key] == calibrated["calibration"][key], key
    assert abs(calibrated["L_mm"] - 1022.0) < 1.0 and abs(calibrated["alpha_rad"] - 0.332) < 2e-3
    assert body["result"]["residual_rms_mm"] == calibrated["calibration"]["residual_rms_mm"]
    assert body["options"] == calibrated["calibration"]["options"]

    # characterize a stage series: identical report
    session = api.post(f"/api/rigs/{rig['id']}/sessions/", {"name": "stage"}, format="json").json()["id"]
    captures: dict[float, list[str]] = {}
    for z in (0.0, 4.0, 8.0):
        for repeat in range(2):
            name = f"stage_{z:g}_{repeat}"
            captures.setdefault(z, []).append(folder(tmp_path, name, stacks[name]))
            upload(api, rig["id"], stacks[name], "stage", z_in_mm=z, repeat=repeat, session=session)
    write_series(captures, tmp_path / "series.json")
    cli("characterize", "--rig", str(rig_file), "--reference", ref_dir, "--series", str(tmp_path / "series.json"),
        "--points", "5", "--out", str(tmp_path / "c.json"))  # fmt: skip
    response = api.post(
        "/api/characterizations/",
        {"rig": rig["id"], "reference": reference, "session": session, "options": {"n_points": 5}},
        format="json",
    )
    body = api.get(f"/api/characterizations/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    report = json.loads((tmp_path / "c.json").read_text())
    for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples", "test_points", "overall"):
        assert body["results"][key] == report[key], key
    assert body["options"] == report["options"]
    assert abs(report["overall"]["mean_error_mm"]) < 0.05


def test_result_pages_show_the_options_and_the_commit(api, rig, stacks):
    from django.test import Client
    from django.urls import reverse

    reference = upload(api, rig["id"], stacks["reference"], "reference")
    obj = upload(api, rig["id"], stacks["block"], "object")
    options = {"decode": {"edge_band_px": 3, "smoothing_px": 0.5}}
    response = api.post(
        "/api/measurements/",
        {"rig": rig["id"], "reference": reference, "object": obj, "options": options},
        format="json",
    )
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    assert body["options"]["decode"]["edge_band_px"] == 3 and body["options"]["decode"]["smoothing_px"] == 0.5
    page = Client()
    page.force_login(api.user)
    html = page.get(reverse("dashboard:measurement", args=[body["id"]])).content.decode()
    assert "decode: edge_band_px</dt><dd>3</dd>" in html
    assert "decode: smoothing_px</dt><dd>0.5</dd>" in html
    assert software_version() in html and software_version().split()[-1].removesuffix("+dirty") in html
    bad = api.post(
        "/api/measurements/",
        {"rig": rig["id"], "reference": reference, "object": obj, "options": {"decode": {"smoothing_px": -2}}},
        format="json",
    )
    assert bad.status_code == 400 and "smoothing_px" in bad.json()["error"] and "-2" in bad.json()["error"]


def codec_zip(images: np.ndarray) -> bytes:
    """A capture zip of the pinhole test codec's frames, with its codec.json."""
    members = {f"frame_{i:02d}.png": png(image) for i, image in enumerate(images)}
    members["codec.json"] = json.dumps(CODEC).encode()
    return zip_bytes(members)


def upload_zip(api, rig_id: int, data: bytes, role: str, **fields) -> int:
    handle = io.BytesIO(data)
    handle.name = f"{role}.zip"
    response = api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role, **fields}, format="multipart")
    assert response.status_code == 201, response.content
    return response.json()["id"]


def test_a_pinhole_rig_measures_and_characterizes_alike_through_command_and_job(api, tmp_path):
    """The same realistic captures of a codec through a distorted pinhole rig: depths without a
    reference, heights above the reference plane with one, the points, and a stage series'
    characterization, bit-identical between ``gcps`` and the jobs."""
    codec, placement = codec_from_dict(CODEC), ScenePlacement.facing_camera(600.0)
    options = SimulationOptions.realistic_8bit(seed=5, supersample=1)

    def render(scene: str, **params: float) -> bytes:

        return codec_zip(
            render_capture(PINHOLE_RIG, make_scene(scene, **params), codec, options, placement=placement).images
        )

    rig_file = tmp_path / "pinhole.json"
    write_rig(PINHOLE_RIG, rig_file)
    created = api.post("/api/rigs/", {**PINHOLE_RIG.to_dict(), "name": "parity", "codec": CODEC}, format="json")
    assert created.status_code == 201, created.content
    rig_id = created.json()["id"]
    zips = {"reference": render("reference"), "sphere": render("sphere")}
    for name, data in zips.items():
        (tmp_path / f"{name}.zip").write_bytes(data)
    reference = upload_zip(api, rig_id, zips["reference"], "reference")
    obj = upload_zip(api, rig_id, zips["sphere"], "object")

    def download(measurement_id: int, name: str) -> np.ndarray:
        return np.load(io.BytesIO(b"".join(api.get(f"/api/measurements/{measurement_id}/{name}").streaming_content)))

    for with_reference in (False, True):
        args = ["--reference", str(tmp_path / "reference.zip")] if with_reference else []
        outputs = [
            "--out",
            str(tmp_path / "z.npy"),
            "--xyz",
            str(tmp_path / "xyz.npy"),
            "--json",
            str(tmp_path / "m.json"),
        ]
        cli("measure", "--rig", str(rig_file), "--object", str(tmp_path / "sphere.zip"), *args, *outputs)
        body = {"rig": rig_id, "reference": reference if with_reference else None, "object": obj}
        started = api.post("/api/measurements/", body, format="json")
        assert started.status_code == 202, started.content
        done = api.get(f"/api/measurements/{started.json()['id']}/").json()
        assert done["status"] == "done", done
        cli_z = np.load(tmp_path / "z.npy")
        assert np.isfinite(cli_z).mean() > 0.5
        np.testing.assert_array_equal(download(done["id"], "height.npy"), cli_z)
        np.testing.assert_array_equal(download(done["id"], "points.npy"), np.load(tmp_path / "xyz.npy"))
        stats = json.loads((tmp_path / "m.json").read_text())
        assert done["options"] == stats["options"]
        assert (
            done["statistics"]["z"]
            == stats["z"]
            == ("height above the reference plane" if with_reference else "depth (camera Z)")
        )

    session = api.post(f"/api/rigs/{rig_id}/sessions/", {"name": "stage"}, format="json").json()["id"]
    captures: dict[float, list[str]] = {}
    for z in (0.0, 5.0, 10.0):
        path = tmp_path / f"stage_{z:g}.zip"
        path.write_bytes(render("stage", z_in_mm=z))
        captures[z] = [str(path)]
        upload_zip(api, rig_id, path.read_bytes(), "stage", z_in_mm=z, repeat=0, session=session)
    write_series(captures, tmp_path / "series.json")
    cli("characterize", "--rig", str(rig_file), "--reference", str(tmp_path / "reference.zip"),
        "--series", str(tmp_path / "series.json"), "--points", "5", "--out", str(tmp_path / "c.json"))  # fmt: skip
    started = api.post(
        "/api/characterizations/",
        {"rig": rig_id, "reference": reference, "session": session, "options": {"n_points": 5}},
        format="json",
    )
    body = api.get(f"/api/characterizations/{started.json()['id']}/").json()
    assert body["status"] == "done", body
    report = json.loads((tmp_path / "c.json").read_text())
    for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples", "test_points", "overall"):
        assert body["results"][key] == report[key], key
    assert body["options"] == report["options"] and report["model"] == "pinhole"
    assert abs(report["overall"]["mean_error_mm"]) < 0.05
