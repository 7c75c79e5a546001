"""End to end with real processes: the live server, the projector page in headless Chromium, ``gcps agent``.

The agent runs as a subprocess with the virtual camera, which renders what the camera would see
under the pattern the page REPORTS showing (the agent only learns it from the page's
confirmation through the server). So a stored stack equal to the directly simulated one shows
that sequencing, confirmation and frame choice are right, and it then measures exactly as well.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import requests
from django.test import Client

from metrology.acquisition.models import Acquisition
from metrology.captures.models import Capture
from metrology.captures.stacks import load_capture_stack
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.core.patterns import projector_patterns
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack
from metrology.pipeline.measure import measure
from tests.acquisition.helpers import CHROMIUM_ARGS, ROOT
from tests.app.stacks import SMALL_RIG
from tests.browser import CHROMIUM

SIM_OPTIONS = {"bit_depth": 8, "noise_grey": 1.5, "projector_defocus_codes": 0.15, "camera_defocus_px": 0.5}
OBJECT_SCENE = {"name": "sphere"}

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


@pytest.fixture
def server(live_server, transactional_db, alice_token, rig):
    user, token = alice_token
    client = Client()
    client.force_login(user)
    api = requests.Session()
    api.headers["Authorization"] = f"Token {token}"
    return {
        "url": live_server.url,
        "token": token,
        "rig": rig,
        "session": client.cookies["sessionid"].value,
        "api": api,
    }


@contextlib.contextmanager
def projector_page(server, monkeypatch, width: int = 1024, height: int = 768):
    """The projector page of ``server["rig"]`` open in headless Chromium (``width`` x ``height`` CSS
    pixels, devicePixelRatio 1)."""
    # Playwright's sync API runs an event loop in this thread; the test's own ORM reads are still synchronous
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": width, "height": height}, device_scale_factor=1)
        context.add_cookies([{"name": "sessionid", "value": server["session"], "url": server["url"]}])
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(f"{server['url']}/rigs/{server['rig'].pk}/projector/")
        yield page
        assert errors == [], errors
        context.close()
        browser.close()


@pytest.fixture
def projector(server, monkeypatch):
    """The rig's projector page open in headless Chromium (1024x768 CSS pixels, devicePixelRatio 1)."""
    with projector_page(server, monkeypatch) as page:
        yield page


def start_agent(server, *extra: str) -> subprocess.Popen:
    command = [
        sys.executable,
        "-m",
        "metrology.cli",
        "agent",
        "--server",
        server["url"],
        "--token",
        server["token"],
        "--rig",
        str(server["rig"].pk),
        "--camera",
        "virtual",
        "--scene",
        json.dumps(OBJECT_SCENE),
        "--sim-options",
        json.dumps(SIM_OPTIONS),
        "--poll",
        "0.2",
        *extra,
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def acquire(server, **body) -> dict:
    response = server["api"].post(f"{server['url']}/api/rigs/{server['rig'].pk}/captures/acquire/", json=body)
    assert response.status_code == 202, response.text
    return response.json()


def wait_finished(server, acquisition_id: int, timeout_s: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        body = server["api"].get(f"{server['url']}/api/acquisitions/{acquisition_id}/").json()
        if body["status"] in ("done", "failed"):
            return body
        time.sleep(0.2)
    raise AssertionError(f"acquisition {acquisition_id} did not finish in {timeout_s} s: {body}")


def wait_registered(server, timeout_s: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        body = server["api"].get(f"{server['url']}/api/rigs/{server['rig'].pk}/agent/").json()
        if body["connected"]:
            return body
        time.sleep(0.1)
    raise AssertionError("the agent did not register")


def run_one_acquisition(server, agent_args: tuple[str, ...], **body) -> dict:
    """Start an agent with ``agent_args`` for one acquisition, request it with ``body``, and return
    it once finished (the agent must exit cleanly)."""
    agent = start_agent(server, "--settle", "0.03", "--max-acquisitions", "1", *agent_args)
    try:
        wait_registered(server)
        queued = acquire(server, **body)
        done = wait_finished(server, queued["id"])
        _, err = agent.communicate(timeout=60)
    finally:
        if agent.poll() is None:
            agent.kill()
    assert agent.returncode == 0, err
    return done


def error_statistics(z_mm: np.ndarray, truth_mm: np.ndarray) -> dict[str, float]:
    both = np.isfinite(z_mm) & np.isfinite(truth_mm)
    error = z_mm[both] - truth_mm[both]
    return {
        "valid": int(both.sum()),
        "median_abs_mm": float(np.median(np.abs(error))),
        "rms_mm": float(np.sqrt(np.mean(error**2))),
    }


def test_agent_with_faulty_camera_stores_in_sync_stacks_that_measure_like_direct_simulation(server, projector):
    agent = start_agent(
        server, "--settle", "0.03", "--max-acquisitions", "2", "--inject-faults", "latency=4,saturate=7"
    )
    try:
        wait_registered(server)
        reference = acquire(server, role="reference", exposure=10)
        obj = acquire(server, role="object")  # auto-exposure from the white frame
        done = [wait_finished(server, reference["id"]), wait_finished(server, obj["id"])]
        out, err = agent.communicate(timeout=60)
    finally:
        if agent.poll() is None:
            agent.kill()
    assert agent.returncode == 0, err
    if [d["status"] for d in done] != ["done", "done"]:
        for d in done:
            for f in d["frames"]:
                print(f["name"], f["grab"], f["ok"], f["reasons"], f["out_of_range_fraction"], f["mean_grey"])
    assert [d["status"] for d in done] == ["done", "done"], [d["error"] for d in done]
    rig = CoreRig.from_dict(SMALL_RIG)
    options = SimulationOptions(**SIM_OPTIONS)
    direct_ref = render_stack(rig, make_scene("reference", rig=rig), options)
    direct_obj = render_stack(rig, make_scene("sphere", rig=rig), options)
    stored = {}
    for body, direct in ((done[0], direct_ref), (done[1], direct_obj)):
        capture = Capture.objects.get(pk=body["capture"])
        assert capture.source == "rig"
        assert capture.parameters["camera"].startswith("virtual+faults")
        assert capture.parameters["exposure_ms"] == pytest.approx(10.0)
        assert capture.parameters["agent"] == body["agent"]
        images = load_capture_stack(capture).images
        # no out-of-sync or saturated frame reached the stored capture: it is the direct simulation
        np.testing.assert_array_equal(images, direct.images)
        stored[capture.role] = images
        frames = Acquisition.objects.get(pk=body["id"]).frames
        assert [f["name"] for f in frames][-11:] == ["GC_0", "GC_1", "GC_2", "GC_3", "GC_4", "GC_5", "GC_6",
                                                     "PS_0", "PS_1", "PS_2", "PS_3"]  # fmt: skip
        reasons = [r for f in frames for r in f["refused_reasons"]]
        assert any("did not change from the previous frame" in r for r in reasons), reasons
        assert any("saturated" in r for r in reasons), reasons
        assert capture.parameters["regrabs"] == sum(f["regrabs"] for f in frames) > 0
    summary = json.loads(out)
    assert [a["status"] for a in summary["acquisitions"]] == ["done", "done"]
    # measured from the captured stacks, and from the direct simulation: the same error statistics
    captured = error_statistics(measure(rig, stored["reference"], stored["object"]).z_mm, direct_obj.truth_mm)
    simulated = error_statistics(measure(rig, direct_ref.images, direct_obj.images).z_mm, direct_obj.truth_mm)
    assert captured == simulated
    assert captured["valid"] > 0.5 * rig.shape[0] * rig.shape[1]
    assert captured["median_abs_mm"] < 0.25, captured  # realistic 8-bit camera on the small rig
    print("captured vs direct error statistics:", captured, simulated)


def test_agent_acquires_a_phase_gray_codec_stored_with_its_codec_decoding_to_the_truth(server, projector):
    """A 4-step phase + gray code with inverses on both axes (30 frames): the page shows the codec's
    patterns, the agent grabs one frame per codec frame (virtual camera, latency faults injected), the
    capture is stored with its codec and decodes to the true projector coordinates of the virtual rig."""
    from metrology.captures.stacks import load_codec_stack
    from metrology.core.codecs import codec_from_dict
    from metrology.core.codecs.decode import decode_codec
    from metrology.core.simulate import crossed_rig_truth
    from tests.acquisition.helpers import phase_gray_codec

    document = phase_gray_codec(("u", "v"))
    done = run_one_acquisition(server, ("--inject-faults", "latency=9"), role="object", exposure=10, codec=document)
    assert done["status"] == "done", done["error"]
    canonical = codec_from_dict(document).to_dict()
    capture = Capture.objects.get(pk=done["capture"])
    assert capture.codec == canonical and capture.source == "rig"
    assert capture.parameters["regrabs"] > 0  # the latency faults were caught and re-grabbed
    frames = Acquisition.objects.get(pk=done["id"]).frames
    assert [f["name"] for f in frames][-30:] == [f"{k:02d}" for k in range(30)]
    stack = load_codec_stack(capture)
    assert stack.images.shape == (30, SMALL_RIG["height_px"], SMALL_RIG["width_px"])
    uv = decode_codec(stack.images, stack.codec).uv()
    rig = CoreRig.from_dict(SMALL_RIG)
    truth = crossed_rig_truth(
        render_stack(rig, make_scene("sphere", rig=rig), SimulationOptions(**SIM_OPTIONS)), rig, 1024, 768
    )
    for index in (0, 1):
        both = np.isfinite(uv[..., index]) & np.isfinite(truth[index])
        error = np.abs(uv[..., index][both] - truth[index][both])
        assert both.mean() > 0.5
        # 4-step phase, period 32 px, 8-bit, noise 1.5 grey levels: median |error| ~ 0.05 px
        assert np.median(error) < 0.15, (index, float(np.median(error)))
        assert np.mean(error < 1.0) > 0.99, (index, float(np.mean(error < 1.0)))
        print(f"axis {'uv'[index]}: {both.sum()} px decoded, median |error| {np.median(error):.4f} px")


def test_agent_takes_each_requests_exposures_over_its_own(server, projector):
    """``gcps agent --exposures 4,40`` (its default) on the virtual camera's 1000:1 plane: a request
    for exposures [20, 2] ms is captured at 2 and 20 ms, one for "auto" with max_exposures 2 at the
    automatic bracket's two exposures (10.4 and 820 ms on this part, which needs three: an
    incomplete bracket), each stored as a multi-exposure capture with those times."""
    from metrology.captures.stacks import load_capture_images
    from metrology.core.codecs.stack import ExposureStack

    agent = start_agent(
        server, "--settle", "0.03", "--max-acquisitions", "2", "--scene", '{"name": "plane", "hdr": true}',
        "--exposures", "4,40",
    )  # fmt: skip
    try:
        wait_registered(server)
        listed = acquire(server, role="object", exposures=[20, 2])
        auto = acquire(server, role="object", exposures="auto", max_exposures=2)
        done = [wait_finished(server, queued["id"]) for queued in (listed, auto)]
        _, err = agent.communicate(timeout=60)
    finally:
        if agent.poll() is None:
            agent.kill()
    assert agent.returncode == 0, err
    assert [body["status"] for body in done] == ["done", "done"], [body["error"] for body in done]
    listed_capture, auto_capture = (Capture.objects.get(pk=body["capture"]) for body in done)
    assert [e["exposure_us"] for e in listed_capture.exposures] == [2000.0, 20000.0]
    auto_us = [e["exposure_us"] for e in auto_capture.exposures]
    assert len(auto_us) == 2 and auto_us[0] == pytest.approx(10_430, rel=0.05) and auto_us[1] > 20 * auto_us[0]
    stored = load_capture_images(listed_capture)
    assert isinstance(stored, ExposureStack) and len(stored.images) == 2
    # grabbed at those times: the specular patch saturates at 20 ms, not at 2 ms
    patch = stored.images[0].max(axis=0) >= 20
    assert patch.sum() > 100 and not (stored.images[0] == 255).any()
    assert (stored.images[1].max(axis=0)[patch] == 255).mean() > 0.9


def test_agent_drives_both_cameras_of_a_stereo_rig_and_stores_a_stereo_capture(server, monkeypatch):
    """A stereo rig: the agent (virtual camera, its two-camera mode; every fifth grab of camera 1 late)
    grabs both cameras under each pattern the page confirms; the stored capture holds both cameras'
    stacks exactly as the direct simulation of the stereo rig."""
    from metrology.captures.stacks import load_capture_images
    from metrology.core.codecs import codec_from_dict
    from metrology.core.simulate import render_capture
    from metrology.rigs.services import create_rig
    from tests.app.stereo_stacks import WIDE_CODEC, WIDE_RIG

    stereo = create_rig(owner=server["rig"].owner, data={**WIDE_RIG.to_dict(), "name": "stereo", "codec": WIDE_CODEC})
    server = {**server, "rig": stereo}
    with projector_page(server, monkeypatch, WIDE_CODEC["projector"]["width"], WIDE_CODEC["projector"]["height"]):
        done = run_one_acquisition(server, ("--inject-faults", "latency=5,camera=1"), role="object", exposure=10)
    assert done["status"] == "done", done["error"]
    capture = Capture.objects.get(pk=done["capture"])
    assert capture.parameters["camera"].startswith("virtual+faults") and capture.parameters["regrabs"] > 0
    frames = Acquisition.objects.get(pk=done["id"]).frames
    assert {f["camera"] for f in frames} == {0, 1} and {f["camera"] for f in frames if f["regrabs"]} == {1}
    scene = make_scene("sphere", rig=WIDE_RIG)
    options = SimulationOptions(**SIM_OPTIONS)
    simulated = render_capture(WIDE_RIG, scene, codec_from_dict(WIDE_CODEC), options).camera_stacks
    for got, want in zip(load_capture_images(capture), simulated, strict=True):
        np.testing.assert_array_equal(got, want)


def test_agent_killed_mid_capture_fails_the_job_and_stores_nothing(server, projector, settings, media_root):
    settings.GCPS_AGENT_TIMEOUT_SECONDS = 2.0
    agent = start_agent(server, "--settle", "0.4")
    try:
        wait_registered(server)
        second = start_agent(server)
        _, err = second.communicate(timeout=60)
        assert second.returncode == 2 and "already has a connected capture agent" in err, err
        queued = acquire(server, role="reference", exposure=10)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            body = server["api"].get(f"{server['url']}/api/acquisitions/{queued['id']}/").json()
            if body["status"] == "running" and body["progress"] >= 30:
                break
            time.sleep(0.1)
        assert body["status"] == "running", body
        agent.send_signal(signal.SIGKILL)
        agent.wait(timeout=30)
        failed = wait_finished(server, queued["id"], timeout_s=30)
    finally:
        if agent.poll() is None:
            agent.kill()
    assert failed["status"] == "failed"
    assert "stopped responding" in failed["error"] and "no capture was stored" in failed["error"], failed
    assert failed["capture"] is None and Capture.objects.count() == 0
    assert not list((media_root / "captures").rglob("*.zip")) if (media_root / "captures").exists() else True
    status = server["api"].get(f"{server['url']}/api/rigs/{server['rig'].pk}/agent/").json()
    assert status["connected"] is False


def test_projector_page_is_pixel_exact_at_device_pixel_ratio_2(server):
    """At devicePixelRatio 2 a 512x384 CSS viewport is 1024x768 device pixels: the page draws the pattern 1:1."""
    sync_api = pytest.importorskip("playwright.sync_api")
    api, base, rig = server["api"], server["url"], server["rig"]
    session = api.post(f"{base}/api/rigs/{rig.pk}/agent/register/", json={"camera": "test"}).json()["session"]
    queued = acquire(server, role="object", codec="gcps-v1:1024x768")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 512, "height": 384}, device_scale_factor=2)
        context.add_cookies([{"name": "sessionid", "value": server["session"], "url": base}])
        page = context.new_page()
        page.goto(f"{base}/rigs/{rig.pk}/projector/")
        expected = projector_patterns(1024, 768)
        for frame in (3, 8):
            seq = api.post(
                f"{base}/api/rigs/{rig.pk}/projector/",
                json={"session": session, "kind": "frame", "frame": frame, "acquisition": queued["id"]},
            ).json()["seq"]
            state = api.get(f"{base}/api/rigs/{rig.pk}/projector/?shown={seq}&wait=20").json()
            assert state["shown_seq"] == seq and state["shown_frame"] == frame
            screen = state["screen"]
            assert (screen["canvas_width"], screen["canvas_height"], screen["device_pixel_ratio"]) == (1024, 768, 2)
            assert screen["fits"] is True
            png = page.screenshot(scale="device")
            import cv2

            shot = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
            assert shot.shape == (768, 1024)
            np.testing.assert_array_equal(shot, expected[frame])
        # the test pattern: a one-pixel checkerboard at the top left, in device pixels
        page.keyboard.press("t")
        page.wait_for_timeout(200)
        shot = cv2.imdecode(np.frombuffer(page.screenshot(scale="device"), np.uint8), cv2.IMREAD_GRAYSCALE)
        yy, xx = np.mgrid[1:100, 1:100]
        np.testing.assert_array_equal(shot[1:100, 1:100], np.where((xx + yy) % 2 == 1, 255, 0))
        context.close()
        browser.close()


def test_agent_stopped_with_sigterm_fails_the_running_acquisition_with_the_reason(server, projector):
    agent = start_agent(server, "--settle", "0.3")
    try:
        wait_registered(server)
        queued = acquire(server, role="reference", exposure=10)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            body = server["api"].get(f"{server['url']}/api/acquisitions/{queued['id']}/").json()
            if body["status"] == "running" and body["progress"] >= 20:
                break
            time.sleep(0.1)
        agent.send_signal(signal.SIGTERM)
        out, err = agent.communicate(timeout=30)
        failed = wait_finished(server, queued["id"], timeout_s=10)
    finally:
        if agent.poll() is None:
            agent.kill()
    assert agent.returncode == 0, err
    assert json.loads(out)["stopped"] == "agent stopped (SIGTERM)"
    assert failed["status"] == "failed" and failed["error"] == "agent stopped (SIGTERM); no capture was stored"
    assert Capture.objects.count() == 0
