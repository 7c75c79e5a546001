"""Zero-install webcam mode: the projector page grabs frames through getUserMedia and uploads the stack.

Chromium's fake media device plays a y4m video made of rendered camera frames (black, white,
black, then the eleven gcps-v1 frames of a sphere on the small rig), each held for HOLD_S seconds,
longer than the page's settle time. The page shows each pattern, waits for the camera image to
change, settles, grabs, and uploads. The test checks the sequencing and the frame choice (each
stored frame is the video's frame of its own pattern, not a neighbour's), and the upload
(a capture with source rig and the browser camera recorded). The physics is checked by the agent
tests (test_end_to_end.py).
"""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np
import pytest
import requests

from metrology.captures.models import Capture
from metrology.captures.stacks import load_capture_stack
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_flat_frames, render_stack
from tests.acquisition.helpers import CHROMIUM_ARGS
from tests.app.stacks import SMALL_RIG
from tests.browser import CHROMIUM

FPS = 10
HOLD_S = 1.5
SETTLE_MS = 300

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


def rendered_segments() -> np.ndarray:
    """(14, H, W) uint8: black, white, black, GC_0..PS_3 of a sphere (8-bit, no noise)."""
    rig = Rig.from_dict(SMALL_RIG)
    options = SimulationOptions(bit_depth=8)
    scene = make_scene("sphere", rig=rig)
    white, black = render_flat_frames(rig, scene, options)
    flats = [np.clip(np.rint(x), 0, 255).astype(np.uint8) for x in (black, white, black)]
    return np.concatenate([np.stack(flats), render_stack(rig, scene, options).images])


def write_y4m(path, segments: np.ndarray) -> None:
    """A y4m (I420, full-range luma = the grey frame, neutral chroma), each segment held HOLD_S s."""
    _, h, w = segments.shape
    chroma = np.full((h // 2) * (w // 2), 128, np.uint8).tobytes()
    with open(path, "wb") as out:
        out.write(f"YUV4MPEG2 W{w} H{h} F{FPS}:1 Ip A1:1 C420jpeg\n".encode())
        for frame in segments:
            for _ in range(int(HOLD_S * FPS)):
                out.write(b"FRAME\n" + frame.tobytes() + chroma + chroma)
        for _ in range(10 * FPS):  # then black, so a late grab cannot find the sequence again
            out.write(b"FRAME\n" + segments[0].tobytes() + chroma + chroma)


def test_webcam_mode_sequences_chooses_and_uploads_frames(server, tmp_path, monkeypatch):
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    segments = rendered_segments()
    video = tmp_path / "camera.y4m"
    write_y4m(video, segments)
    base, rig, api = server["url"], server["rig"], server["api"]
    args = [
        *CHROMIUM_ARGS,
        "--use-fake-ui-for-media-stream",
        "--use-fake-device-for-media-stream",
        f"--use-file-for-fake-video-capture={video}",
    ]
    with webcam_page(server, args, f"?webcam=1&settle={SETTLE_MS}"):
        agent = api.get(f"{base}/api/rigs/{rig.pk}/agent/").json()
        assert agent["connected"] and agent["camera"] == "browser-webcam"
        queued = api.post(f"{base}/api/rigs/{rig.pk}/captures/acquire/", json={"role": "object"}).json()
        body = wait_finished(api, base, queued["id"], timeout_s=120.0)
    assert body["status"] == "done", body["error"]
    capture = Capture.objects.get(pk=body["capture"])
    assert capture.source == "rig" and capture.parameters["camera"].startswith("browser:")
    stored = load_capture_stack(capture).images.astype(np.float64)
    # frame choice: each stored frame is its own pattern's video frame (best match among all 14 segments)
    candidates = segments.astype(np.float64)
    for k in range(11):
        correlations = [np.corrcoef(stored[k].ravel(), c.ravel())[0, 1] if c.std() > 0 else -1 for c in candidates]
        assert int(np.argmax(correlations)) == 3 + k, (k, np.round(correlations, 3))
        assert correlations[3 + k] > 0.98
    names = [f["name"] for f in body["frames"]]
    assert names == ["black", "white", "black", "GC_0", "GC_1", "GC_2", "GC_3", "GC_4", "GC_5", "GC_6",
                     "PS_0", "PS_1", "PS_2", "PS_3"]  # fmt: skip
    assert all(f["change_fraction"] is None or f["change_fraction"] >= 0.08 for f in body["frames"])


def test_webcam_mode_refuses_exposures_its_camera_cannot_set(server, monkeypatch):
    """Exposures in webcam mode are applied through the track's manual exposureTime or refused with
    the reason, never captured as one exposure. Chromium's fake camera offers a manual exposureTime
    of 1 to 10 ms (10..100 in units of 100 us) but its image does not change with it: exposures
    [20, 2] ms are refused as outside its range, [2, 8] ms are applied and refused because the
    white frame did not brighten, "auto" because the page does not bracket. Then the track's
    capabilities lose exposureTime (as a webcam without the control): [2, 8] ms and one exposure
    of 8 ms are refused because the camera cannot set its exposure. Nothing is stored."""
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    base, rig, api = server["url"], server["rig"], server["api"]
    args = [*CHROMIUM_ARGS, "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream"]

    def failed(*bodies: dict) -> list[dict]:
        queued = [
            api.post(f"{base}/api/rigs/{rig.pk}/captures/acquire/", json={"role": "object", **body}).json()
            for body in bodies
        ]
        return [wait_finished(api, base, item["id"]) for item in queued]

    with webcam_page(server, args, "?webcam=1&settle=50") as page:
        capabilities = page.evaluate(
            """async () => {
                const stream = await navigator.mediaDevices.getUserMedia({video: true});
                const caps = stream.getVideoTracks()[0].getCapabilities();
                stream.getTracks().forEach((t) => t.stop());
                return {time: caps.exposureTime, modes: caps.exposureMode};
            }"""
        )
        offered = failed({"exposures": [20, 2]}, {"exposures": [2, 8]}, {"exposures": "auto"})
        page.evaluate(
            """() => {
                const own = MediaStreamTrack.prototype.getCapabilities;
                MediaStreamTrack.prototype.getCapabilities = function () {
                    const caps = own.call(this);
                    delete caps.exposureTime;
                    return caps;
                };
            }"""
        )
        missing = failed({"exposures": [2, 8]}, {"exposure": 8})
    assert capabilities == {"time": {"min": 10, "max": 100, "step": 5}, "modes": ["manual", "continuous"]}
    assert [b["status"] for b in offered + missing] == ["failed"] * 5
    outside, alike, auto = (b["error"] for b in offered)
    assert "the camera's exposure time ranges over 1 to 10 ms; exposure 20 ms is outside it" in outside
    assert "the camera's image did not brighten from exposure 2 ms to 8 ms" in alike
    assert "it does not apply the exposure time it offers" in alike
    assert 'exposures "auto": the webcam page does not bracket automatically' in auto
    for body, times in zip(missing, ("2, 8 ms", "8 ms"), strict=True):
        assert "webcam page: the camera cannot set its exposure" in body["error"], body["error"]
        assert f"cannot capture the requested exposure(s) {times}" in body["error"], body["error"]
    assert all(b["frames"] == [] for b in offered + missing)  # refused before any pattern's frame was kept
    assert Capture.objects.count() == 0


@contextlib.contextmanager
def webcam_page(server, args: list[str], query: str):
    """The rig's projector page (``query``: its webcam mode) in headless Chromium launched with
    ``args``, once it registered as the rig's agent; its JavaScript errors are asserted absent after."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=args)
        context = browser.new_context(viewport={"width": 1024, "height": 768})
        context.add_cookies([{"name": "sessionid", "value": server["session"], "url": server["url"]}])
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(f"{server['url']}/rigs/{server['rig'].pk}/projector/{query}")
        page.wait_for_selector("#projector[data-agent-session]", state="attached", timeout=30_000)
        yield page
        context.close()
        browser.close()
    assert errors == [], errors


def wait_finished(api: requests.Session, base: str, acquisition_id: int, timeout_s: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        body = api.get(f"{base}/api/acquisitions/{acquisition_id}/").json()
        if body["status"] in ("done", "failed"):
            return body
        time.sleep(0.2)
    raise AssertionError(f"acquisition {acquisition_id} did not finish in {timeout_s} s: {body}")


@pytest.fixture
def server(live_server, transactional_db, alice_token, rig):
    from django.test import Client

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
