"""The agent side without a server: frame checks, auto-exposure, camera backends, ``gcps capture``."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from metrology.acquisition.agent.cameras import CameraError, FaultyCamera, GenICamCamera, Shown, make_camera
from metrology.acquisition.agent.checks import CheckOptions, FrameChecker, auto_exposure, projector_change
from metrology.acquisition.agent.patterns import resolve_codec
from metrology.acquisition.agent.sequencer import AcquisitionError, InstantProjector, SequenceOptions, run_sequence
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import read_stack
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack
from tests.acquisition.helpers import ROOT
from tests.app.stacks import SMALL_RIG

RNG = np.random.default_rng(7)


def flats(shape=(60, 80), white=200, black=20):
    return np.full(shape, white, np.uint8), np.full(shape, black, np.uint8)


def test_codec_names_and_refusals():
    codec = resolve_codec("gcps-v1:640x480")
    assert (codec.width, codec.height, codec.n_frames) == (640, 480, 11)
    assert codec.images().shape == (11, 480, 640)
    assert resolve_codec(None).spec == "gcps-v1:1024x768"
    for bad in ("gray-9", "gcps-v1:8x8", 42):
        with pytest.raises(ValueError, match="codec"):
            resolve_codec(bad)


def test_projector_change_of_gray_bits_is_one_half():
    images = resolve_codec("gcps-v1:1024x768").images()
    # consecutive reflected gray-code bits differ on half the columns (exactly, at 1024 px)
    assert projector_change(images[2], images[3], 0.25) == pytest.approx(0.5)
    assert projector_change(np.full_like(images[0], 255), images[0], 0.25) == pytest.approx(0.5)


def test_white_check_refuses_a_dark_white_and_disagreeing_blacks():
    checker = FrameChecker()
    white, black = flats()
    assert not checker.check_white(black.copy(), black).ok  # latency: the black frame again
    late = checker.check_white(white, black, black_after=white)  # the second black is late (white)
    assert not late.ok and "disagree" in late.reasons[0]
    ok = checker.check_white(white, black, black_after=black)
    assert ok.ok and ok.lit_fraction == 1.0


def test_frame_checks_catch_latency_saturation_and_range():
    checker = FrameChecker()
    white, black = flats()
    checker.check_white(white, black, black_after=black)
    half = black.copy()
    half[:, 40:] = 200  # the right half lit: a gray bit
    check = checker.check_frame(half, name="GC_0", frame=0, previous_image=white, expected_change=0.5)
    assert check.ok and check.change_fraction == pytest.approx(0.5)
    late = checker.check_frame(white, name="GC_0", frame=0, previous_image=white, expected_change=0.5)
    assert not late.ok and "did not change" in late.reasons[0]
    saturated = np.minimum(half.astype(np.int32) * 4, 255).astype(np.uint8)
    bad = checker.check_frame(saturated, name="GC_0", frame=0, previous_image=white, expected_change=0.5)
    assert not bad.ok and bad.saturated_fraction == pytest.approx(0.5)
    assert any("saturated" in r for r in bad.reasons) and any("outside the black-white range" in r for r in bad.reasons)
    wrong = checker.check_frame(
        half, name="GC_0", frame=0, previous_image=white, expected_change=0.5, expected_image=255 - half
    )
    assert not wrong.ok and wrong.correlation == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="fraction"):
        CheckOptions(min_contrast=2.0)


def test_auto_exposure_reaches_the_target_on_a_linear_sensor():
    """A linear sensor: grey = min(255, 20 e) (e in ms) on 99 % of the pixels: the target 0.8 F is e = 10.2 ms."""
    base = np.full((50, 50), 20.0)

    def grab_white(e: float) -> np.ndarray:
        return np.clip(np.rint(base * e), 0, 255).astype(np.uint8)

    exposure, steps = auto_exposure(grab_white, 100.0)  # starts saturated
    assert steps[0]["saturated_fraction"] == 1.0
    assert abs(20 * exposure / 255 - 0.8) <= 0.1
    with pytest.raises(ValueError, match="did not converge"):
        auto_exposure(lambda e: np.zeros((10, 10), np.uint8), 1.0, max_iterations=3)


def test_sequence_with_faulty_virtual_camera_keeps_only_in_sync_frames():
    rig = Rig.from_dict(SMALL_RIG)
    options = {"bit_depth": 8, "noise_grey": 1.5}
    camera = FaultyCamera(make_camera("virtual", scene={"name": "sphere"}, options=options), 4, 7)
    from metrology.acquisition.agent.cameras import AcquisitionTarget

    codec = resolve_codec("gcps-v1")
    camera.prepare(AcquisitionTarget(role="object", codec=codec, rig_geometry=SMALL_RIG))
    result = run_sequence(
        InstantProjector(), camera, codec, exposure_ms=10.0, options=SequenceOptions(settle_s=0.0, max_grabs=4)
    )
    direct = render_stack(rig, make_scene("sphere", rig=rig), SimulationOptions(**options))
    np.testing.assert_array_equal(result.images, direct.images)
    kinds = {kind for _, kind in camera.injected}
    assert kinds == {"latency", "saturated"}
    assert sum(r["regrabs"] for r in result.frame_reports()) == len(camera.injected)


def test_sequence_gives_up_with_the_reason_after_max_grabs():
    camera = FaultyCamera(make_camera("virtual", scene={"name": "plane"}), latency_every=1)
    from metrology.acquisition.agent.cameras import AcquisitionTarget

    codec = resolve_codec("gcps-v1")
    camera.prepare(AcquisitionTarget(role="object", codec=codec, rig_geometry=SMALL_RIG))
    with pytest.raises(AcquisitionError, match="refused 2 times"):
        run_sequence(InstantProjector(), camera, codec, exposure_ms=10.0, options=SequenceOptions(0.0, 2))


def test_opencv_backend_reads_a_video_file(tmp_path):
    path = tmp_path / "frames.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (64, 48), isColor=True)
    assert writer.isOpened()
    for level in (10, 120, 240):
        writer.write(np.full((48, 64, 3), level, np.uint8))
    writer.release()
    camera = make_camera(f"opencv:{path}")
    camera.open()
    frames = [camera.grab(Shown("frame", k)) for k in range(3)]
    assert [int(f.mean()) for f in frames] == [10, 120, 240] and frames[0].shape == (48, 64)
    with pytest.raises(CameraError, match="no frame"):
        camera.grab(Shown("frame", 3))
    camera.close()
    with pytest.raises(CameraError, match="cannot open"):
        make_camera(f"opencv:{tmp_path / 'missing.avi'}").open()


def test_genicam_without_harvesters_says_what_to_install(monkeypatch):
    # the dev install has harvesters (tests/acquisition/test_genicam.py): hide it as a plain install lacks it
    monkeypatch.setitem(sys.modules, "harvesters", None)
    monkeypatch.setitem(sys.modules, "harvesters.core", None)
    with pytest.raises(CameraError, match="pip install 'gcps-lab\\[genicam\\]'"):
        GenICamCamera("/opt/vendor/producer.cti").open()
    with pytest.raises(ValueError, match="not known"):
        make_camera("firewire:0")


def gcps(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-c", "import sys; from metrology.cli import main; sys.exit(main())", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.slow
def test_gcps_capture_virtual_writes_the_stack_and_its_checks(tmp_path):
    rig_path = tmp_path / "rig.json"
    rig_path.write_text(json.dumps(SMALL_RIG))
    out = tmp_path / "stage.zip"
    done = gcps(
        "capture", "--camera", "virtual", "--projector", "none", "--rig", str(rig_path), "--role", "stage",
        "--z-in", "12", "--sim-options", '{"bit_depth": 8, "noise_grey": 1.0}', "--settle", "0",
        "--inject-faults", "latency=5", "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["regrabs"] > 0 and summary["exposure_ms"] == pytest.approx(10.0, rel=0.3)
    rig = Rig.from_dict(SMALL_RIG)
    direct = render_stack(
        rig, make_scene("stage", rig=rig, z_in_mm=12.0), SimulationOptions(bit_depth=8, noise_grey=1.0)
    )
    if summary["exposure_ms"] == 10.0:
        np.testing.assert_array_equal(read_stack(out, rig=rig).images, direct.images)
    checks = json.loads(out.with_suffix(".checks.json").read_text())
    assert [f["name"] for f in checks["frames"]][-1] == "PS_3"
    bad = gcps("capture", "--camera", "opencv:0", "--projector", "none", "--out", str(tmp_path / "x.zip"))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "virtual camera only" in bad.stderr
    bad = gcps("capture", "--camera", "virtual", "--role", "stage", "--out", str(tmp_path / "x.zip"))
    assert bad.returncode == 2 and "--z-in is required" in bad.stderr
    assert not (tmp_path / "x.zip").exists()


CODEC = {
    "codec": "gcps-codec/1",
    "frames": 12,
    "projector": {"width": 1024, "height": 768},
    "white": [10],
    "black": [11],
    "axes": {
        "u": {
            "phase": [{"frames": [0, 1, 2], "period": 32.0}],
            "gray": {"frames": [3, 4, 5, 6, 7, 8, 9], "word": 8.0, "origin": -0.5},
        }
    },
}


@pytest.mark.slow
def test_gcps_capture_of_a_codec_file_decodes_to_the_true_projector_columns(tmp_path):
    """A 3-step phase (period 32 px) + 7-bit gray codec with its own white/black frames, through the
    virtual camera: the stored stack carries codec.json and decodes (issue 11's decoder) to the true u."""
    from metrology.core.codecs import codec_from_dict
    from metrology.core.codecs.decode import decode_codec
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.simulate import crossed_rig_truth

    rig_path, codec_path, out = tmp_path / "rig.json", tmp_path / "codec.json", tmp_path / "sphere.zip"
    rig_path.write_text(json.dumps(SMALL_RIG))
    codec_path.write_text(json.dumps(CODEC))
    done = gcps(
        "capture", "--camera", "virtual", "--projector", "none", "--rig", str(rig_path), "--codec", str(codec_path),
        "--scene", '{"name": "sphere"}', "--sim-options", '{"bit_depth": 8, "noise_grey": 1.0}', "--settle", "0",
        "--exposure", "10", "--inject-faults", "latency=6", "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["regrabs"] > 0
    stack = read_codec_stack(out)
    assert stack.images.shape == (12, SMALL_RIG["height_px"], SMALL_RIG["width_px"])
    u = decode_codec(stack.images, stack.codec).uv()[..., 0]
    rig = Rig.from_dict(SMALL_RIG)
    truth_u, _ = crossed_rig_truth(render_stack(rig, make_scene("sphere", rig=rig)), rig, 1024, 768)
    both = np.isfinite(u) & np.isfinite(truth_u)
    assert both.mean() > 0.5
    # 3-step phase, B ~ 100 grey levels, noise 1 grey level: sigma_u = P / (2 pi) sqrt(2/3) sigma / B ~ 0.04 px
    assert np.median(np.abs(u[both] - truth_u[both])) < 0.1
    assert codec_from_dict(CODEC).n_frames == 12
