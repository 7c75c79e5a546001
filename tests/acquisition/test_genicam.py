"""The GenICam backend against a real GenTL producer: the EMVA reference simulator TLSimu.cti.

The ``genicam`` wheel (1.5.0, the dev extra) ships ``TLSimu.cti``, a GenTL producer of four
simulated devices: ``TLSimuMono`` (index 0 and 2, 512x512 Mono8) and ``TLSimuColor`` (index 1 and
3, 768x572 RGB8). Their frames are exact ramps of the frame counter ``k`` (0 at the first frame
after the device is opened, +1 per delivered frame), which the tests use as ground truth:

- Mono: ``I[r, c] = (r + c + k) mod 256``, so ``k = I[0, 0]``;
- Color: ``R = (r + k) mod 256``, ``G = (c + k) mod 256``, ``B = k``, so the grey frame is
  ``round(0.299 R + 0.587 G + 0.114 B)`` and its pixel (0, 0) is ``k``.

The simulator has ``TriggerMode`` (Off, On), ``TriggerSource`` (Software only), ``TriggerSoftware``,
no ``TriggerSelector``, no ``ExposureTime`` and no input lines; its ``PixelFormat`` accepts every
entry but the frames stay Mono8/RGB8. Stopping its acquisition takes 0.5 s (the simulator's own
stream stop), so each test starts as few acquisitions as it can. What a real camera adds (a line
trigger, exposure, 10- to 16-bit frames) is not simulated: docs/acquisition.md lists it.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from metrology.acquisition.agent.cameras import (
    CameraError,
    CameraPair,
    GenICamCamera,
    Shown,
    genicam_grey,
    make_camera,
    make_cameras,
)
from metrology.acquisition.agent.patterns import resolve_codec
from metrology.acquisition.agent.sequencer import InstantProjector, SequenceOptions, run_sequence

# where the genicam wheel exists (pyproject.toml's dev extra has the same marker)
WHEEL_PLATFORMS = {("linux", "x86_64"), ("win32", "AMD64"), ("darwin", "arm64")}
MONO, COLOR, MONO_B = 0, 1, 2
WHITE = Shown("white")


def tlsimu_path() -> str:
    """The simulator's .cti; skips only where no genicam wheel exists (not in CI), else fails."""
    if (sys.platform, platform.machine()) not in WHEEL_PLATFORMS or sys.version_info >= (3, 14):
        reason = (
            f"no genicam wheel (the GenICam simulator TLSimu.cti) for {sys.platform} {platform.machine()} "
            f"Python {sys.version_info.major}.{sys.version_info.minor}: the GenICam backend is not run here"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    try:
        import genicam
        import harvesters  # noqa: F401
    except ImportError as exc:
        pytest.fail(f"{exc}: scripts/setup.sh --dev installs harvesters and genicam 1.5.0 on this platform")
    path = Path(genicam.__file__).with_name("TLSimu.cti")
    if not path.is_file():
        pytest.fail(f"{path} is missing: genicam 1.5.1 and later ship no TLSimu.cti; the dev extra pins genicam==1.5.0")
    return str(path)


@pytest.fixture(scope="module")
def cti() -> str:
    return tlsimu_path()


@pytest.fixture
def opened(cti: str) -> Iterator[list[GenICamCamera | CameraPair]]:
    """Cameras a test appends here are closed after it, even when it fails."""
    cameras: list[GenICamCamera | CameraPair] = []
    yield cameras
    for camera in cameras:
        camera.close()


def mono_ramp(k: int) -> np.ndarray:
    r, c = np.indices((512, 512))
    return ((r + c + k) % 256).astype(np.uint8)


def test_free_running_grab_is_the_simulated_frame_exposed_after_the_call(cti, opened):
    camera = make_camera(f"genicam:{cti}:{MONO}")
    assert isinstance(camera, GenICamCamera)
    opened.append(camera)
    camera.open()
    first = camera.grab(WHITE)
    assert first.dtype == np.uint8 and first.shape == (512, 512)
    k1 = int(first[0, 0])
    np.testing.assert_array_equal(first, mono_ramp(k1))
    time.sleep(0.2)  # the free-running simulator fills its 5 buffers with frames older than the next grab
    second = camera.grab(WHITE)
    k2 = int(second[0, 0])
    np.testing.assert_array_equal(second, mono_ramp(k2))
    # the frames queued meanwhile and the one exposing at the call are discarded (a plain fetch gives k1 + 1)
    assert k2 >= k1 + 3
    with pytest.raises(CameraError, match="has no ExposureTime feature: it cannot take exposure 5 ms"):
        camera.set_exposure(5.0)


def test_software_trigger_gives_one_new_frame_per_grab_and_none_without_a_trigger(cti, opened):
    camera = GenICamCamera(cti, MONO, timeout_s=0.2)
    opened.append(camera)
    camera.open()
    camera.use_trigger("Software")  # no TriggerSelector on the simulator: set where the camera has one
    assert camera.trigger == "Software"
    with pytest.raises(CameraError, match=r"no frame within 0.2 s \(waiting for a trigger on Software\)"):
        camera.fetch()  # armed, nothing fired: nothing delivered
    frames = [camera.grab(WHITE) for _ in range(3)]
    k = int(frames[0][0, 0])
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame, mono_ramp(k + i))  # one trigger, one frame, in order
    with pytest.raises(CameraError, match="refused trigger source Line0: its TriggerSource offers Software"):
        camera.use_trigger("Line0")


def test_colour_frames_become_grey_in_their_own_channel_order(cti, opened):
    camera = GenICamCamera(cti, COLOR)
    opened.append(camera)
    camera.open()
    grey = camera.grab(WHITE)
    assert grey.dtype == np.uint8 and grey.shape == (572, 768)
    k = int(grey[0, 0])
    r, c = np.indices(grey.shape)
    red, green, blue = (r + k) % 256, (c + k) % 256, k % 256
    truth = 0.299 * red + 0.587 * green + 0.114 * blue
    assert np.abs(grey - truth).max() <= 0.51  # OpenCV's fixed-point weights round to the nearest level
    swapped = 0.299 * blue + 0.587 * green + 0.114 * red  # RGB8 read as OpenCV's BGR
    assert np.abs(grey - swapped).max() > 40


def test_two_simulated_devices_on_one_producer_grab_as_a_pair(cti, opened):
    pair = make_cameras([f"genicam:{cti}:{MONO}", f"genicam:{cti}:{MONO_B}"])
    assert isinstance(pair, CameraPair)
    opened.append(pair)
    pair.open()  # both share the producer's one Harvester (a second one of the same .cti finds no device)
    frames = pair.grab(WHITE)
    assert len(frames) == 2
    for frame in frames:
        np.testing.assert_array_equal(frame, mono_ramp(int(frame[0, 0])))


def test_triggered_pair_refuses_a_line_the_camera_lacks_and_closes_both(cti):
    pair = CameraPair(GenICamCamera(cti, MONO), GenICamCamera(cti, MONO_B), trigger_line="Line0")
    with pytest.raises(CameraError, match=r"TLSimu.cti:2 refused trigger source Line0: its TriggerSource offers"):
        pair.open()
    assert all(camera._acquirer is None for camera in pair.cameras)  # type: ignore[attr-defined]


def test_triggered_pair_fires_camera_0_and_names_camera_1_when_its_trigger_never_comes(cti, opened):
    # the simulator has no input line: camera 1 on a software trigger nobody fires is a trigger
    # wire that was never connected; camera 0's frame is the one its software trigger exposed
    zero, one = GenICamCamera(cti, MONO, timeout_s=0.2), GenICamCamera(cti, MONO_B, timeout_s=0.2)
    pair = CameraPair(zero, one, trigger_line="Software")
    opened.append(pair)
    pair.open()
    assert (zero.trigger, one.trigger) == ("Software", "Software")
    with pytest.raises(CameraError, match=r"TLSimu.cti:2: no frame within 0.2 s \(waiting for a trigger on Software\)"):
        pair.grab(WHITE)
    one.fire()  # what the wire would have done
    frame = one.fetch()
    np.testing.assert_array_equal(frame, mono_ramp(int(frame[0, 0])))


def test_open_names_a_missing_producer_and_an_absent_device(cti, tmp_path):
    with pytest.raises(CameraError, match="no GenTL producer at"):
        GenICamCamera(str(tmp_path / "vendor.cti")).open()
    with pytest.raises(CameraError, match=r"TLSimu.cti:9: 4 GenICam device\(s\) found"):
        make_camera(f"genicam:{cti}:9").open()
    camera = GenICamCamera(cti, MONO)
    camera.open()
    try:
        with pytest.raises(CameraError, match="cannot be opened"):
            GenICamCamera(cti, MONO).open()  # a device is opened once
    finally:
        camera.close()


def test_an_agent_acquisition_on_the_simulator_stops_at_the_exposure_it_cannot_set(cti, opened):
    camera = GenICamCamera(cti, MONO)
    opened.append(camera)
    camera.open()
    codec = resolve_codec("gcps-v1")
    with pytest.raises(CameraError, match="has no ExposureTime feature: it cannot take exposure 10 ms"):
        run_sequence(InstantProjector(), camera, codec, exposure_ms=None, options=SequenceOptions(settle_s=0.0))


@pytest.mark.parametrize(
    ("pixel_format", "raw", "grey"),
    [
        ("Mono8", np.array([0, 17, 255], np.uint8), np.array([0, 17, 255], np.uint8)),
        ("Mono16", np.array([0, 1000, 65535], np.uint16), np.array([0, 1000, 65535], np.uint16)),
        # I * 65535 / (2^b - 1), rounded: full scale of the sensor -> 65535
        ("Mono12", np.array([0, 1, 2048, 4095], np.uint16), np.array([0, 16, 32776, 65535], np.uint16)),
        ("Mono10Packed", np.array([0, 1, 512, 1023], np.uint16), np.array([0, 64, 32800, 65535], np.uint16)),
    ],
)
def test_mono_formats_keep_their_levels_on_the_agents_full_scale(pixel_format, raw, grey):
    frame = genicam_grey(raw, raw.size, 1, pixel_format)
    assert frame.shape == (1, raw.size) and frame.dtype == grey.dtype
    np.testing.assert_array_equal(frame[0], grey)


def test_packed_frames_as_harvesters_unpacks_them_reach_full_scale(cti):
    from harvesters.util.pfnc import Mono10p, Mono12Packed

    # two pixels per 3 bytes (Mono12Packed: 4095 and 1) and four per 5 bytes (Mono10p: all 1023)
    twelve = Mono12Packed().expand(np.array([0xFF, 0x1F, 0x00], np.uint8))
    ten = Mono10p().expand(np.full(5, 0xFF, np.uint8))
    np.testing.assert_array_equal(genicam_grey(twelve, 2, 1, "Mono12Packed")[0], [65535, 16])
    np.testing.assert_array_equal(genicam_grey(ten, 4, 1, "Mono10p")[0], [65535] * 4)


def test_a_format_the_agent_cannot_read_is_refused_naming_it():
    with pytest.raises(CameraError, match="sends BayerRG8 frames; set its PixelFormat to one of Mono8"):
        genicam_grey(np.zeros(4, np.uint8), 2, 2, "BayerRG8")
