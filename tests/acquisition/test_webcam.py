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
import io
import json
import os
import time
import zipfile

import numpy as np
import pytest
import requests

from metrology.captures.models import Capture
from metrology.captures.stacks import load_capture_stack, load_exposure_stack
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


EXPOSURES_MS = (2.0, 16.0)  # 8x apart: the short one saturates nowhere, the long one the bright patch


def test_webcam_mode_captures_and_measures_a_multi_exposure_stack(server, monkeypatch):
    """The success path of exposures in webcam mode, end to end: a simulated camera
    (tests/acquisition/simulated_webcam.py: the projector canvas seen through a manual exposureTime,
    on a 1000:1 reflectance, 8-bit clipping) stands in for the webcam; the page brackets, grabs and
    uploads a reference and an object at 2 and 16 ms; the server stores exposures.json + exp0/, exp1/
    and measures the two.

    Ground truth, exactly (the camera's model is known): each stored frame is its own pattern at its
    own exposure (within the one grey level of the canvas's 2:1 reduction); where neither exposure
    clips, the frames' ratio is the times' ratio 8 to within the rounding of both (|g16 - 8 g2| <= 4.5
    grey levels); the object is the reference plane, so it measures 0 mm; the long exposure saturates
    the bright patch, so its points are the short exposure's, the matte ramp's the long one's. A third
    acquisition at 0.3 ms, where the white frame changes but no pixel reaches the page's 48 grey levels
    of contrast, fails saying so."""
    from metrology.acquisition.agent.patterns import resolve_codec
    from tests.acquisition import simulated_webcam as cam

    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    base, rig, api = server["url"], server["rig"], server["api"]
    with webcam_page(server, CHROMIUM_ARGS, "?webcam=1&settle=50", cam.init_script()):
        queued = [
            api.post(
                f"{base}/api/rigs/{rig.pk}/captures/acquire/", json={"role": role, "exposures": list(EXPOSURES_MS)}
            ).json()
            for role in ("reference", "object")
        ]
        # 0.3 ms: the patch's white frame is 35 grey levels, its black 1: it changed, but lights no pixel
        dim = api.post(f"{base}/api/rigs/{rig.pk}/captures/acquire/", json={"role": "object", "exposure": 0.3})
        done = [wait_finished(api, base, item["id"], timeout_s=60.0) for item in queued]
        refused = wait_finished(api, base, dim.json()["id"], timeout_s=30.0)
    assert [b["status"] for b in done] == ["done", "done"], [b["error"] for b in done]
    assert refused["status"] == "failed" and refused["capture"] is None
    assert "the projector lights 0.00 % of the camera's pixels at exposure 0.3 ms" in refused["error"], refused
    reference, obj = (Capture.objects.get(pk=b["capture"]) for b in done)

    # the layout: exposures.json and one folder of the eleven frames per exposure, the times as asked
    with obj.file.open("rb") as handle, zipfile.ZipFile(handle) as archive:
        names = sorted(archive.namelist())
        manifest = json.loads(archive.read("exposures.json"))
    frames = [f"{name}.png" for name in resolve_codec("gcps-v1").frame_names]
    assert names == sorted(["exposures.json"] + [f"exp{e}/{f}" for e in (0, 1) for f in frames])
    assert manifest == {
        "format": "gcps-exposures/1",
        "exposures": [{"name": "exp0", "exposure_us": 2000}, {"name": "exp1", "exposure_us": 16000}],
    }
    assert obj.exposures == [{"name": "exp0", "exposure_us": 2000.0}, {"name": "exp1", "exposure_us": 16000.0}]
    assert [f.get("exposure_ms") for f in done[1]["frames"]] == [2.0] * 14 + [16.0] * 14

    # each frame is its own pattern at its own exposure: the projector's 2 x 2 means lie between two
    # grey levels (the canvas rounds them), so the camera's grey lies between their two renderings
    projector = resolve_codec("gcps-v1").images().astype(np.float64)
    (x0, y0), k = cam.ORIGIN, cam.SCALE
    region = projector[:, y0 : y0 + k * cam.H, x0 : x0 + k * cam.W]
    means = region.reshape(len(frames), cam.H, k, cam.W, k).mean(axis=(2, 4))
    for capture in (reference, obj):
        stack = load_exposure_stack(capture)
        assert [e.exposure_us for e in stack.exposures] == [2000.0, 16000.0]
        short, long = (images.astype(np.float64) for images in stack.images)
        for images, ms in zip((short, long), EXPOSURES_MS, strict=True):
            low, high = (cam.grey(f(means) / 255, ms) for f in (np.floor, np.ceil))
            assert ((images >= low) & (images <= high)).all(), (capture.role, ms)
        # where neither clips: the ratio of the times, to within both roundings (0.5 + 8 * 0.5 grey)
        ratio = EXPOSURES_MS[1] / EXPOSURES_MS[0]
        unclipped = (long < 255) & (short >= 8)
        assert unclipped.sum() > 0.1 * short.size
        assert np.abs(long - ratio * short)[unclipped].max() <= 0.5 + ratio * 0.5
        fitted = (long[unclipped] * short[unclipped]).sum() / (short[unclipped] ** 2).sum()
        assert abs(fitted / ratio - 1) < 0.01, fitted
        assert (long[:, :, cam.PATCH[0] : cam.PATCH[1]].max(axis=0) == 255).all()  # the bright patch clips at 16 ms
        assert short.max() < 255  # and nowhere at 2 ms

    # the measurement: the object is the reference plane (0 mm), both exposures measured points
    response = api.post(f"{base}/api/measurements/", json={"rig": rig.pk, "reference": reference.pk, "object": obj.pk})
    assert response.status_code == 202, response.text
    measured = wait_finished(api, base, response.json()["id"], kind="measurements")
    assert measured["status"] == "done", measured
    counts = measured["statistics"]["points_per_exposure"]
    z = np.load(io.BytesIO(api.get(f"{base}/api/measurements/{measured['id']}/height.npy").content))
    exposure = np.load(io.BytesIO(api.get(f"{base}/api/measurements/{measured['id']}/exposure.npy").content))
    measured_points = np.isfinite(z)
    assert np.abs(z[measured_points]).max() < 1e-3  # mm: the same scene seen by the same camera, twice
    assert counts == {"exp0": int((exposure == 0).sum()), "exp1": int((exposure == 1).sum())}
    assert sum(counts.values()) == measured["statistics"]["valid_pixels"] == measured_points.sum()
    rho = cam.reflectance()
    patch = rho == 1.0  # its white frame reaches 230 * 1.02 at 2 ms and saturates at 16 ms
    matte = (rho >= 0.02) & (rho <= 0.1)  # at most 0.1 * 8 * 230 * 1.02 = 188 grey levels at 16 ms
    for region, index in ((patch, 0), (matte, 1)):
        assert (exposure[region & measured_points] == index).all()
        assert measured_points[region].mean() > 0.95, (index, measured_points[region].mean())
    assert counts["exp0"] > 0.95 * patch.sum() and counts["exp1"] > 0.95 * matte.sum()


@contextlib.contextmanager
def webcam_page(server, args: list[str], query: str, init_script: str | None = None):
    """The rig's projector page (``query``: its webcam mode) in headless Chromium launched with
    ``args`` (``init_script``: JavaScript run before the page's own), once it registered as the rig's
    agent; its JavaScript errors are asserted absent after."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=args)
        context = browser.new_context(viewport={"width": 1024, "height": 768})
        context.add_cookies([{"name": "sessionid", "value": server["session"], "url": server["url"]}])
        page = context.new_page()
        if init_script is not None:
            page.add_init_script(init_script)
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(f"{server['url']}/rigs/{server['rig'].pk}/projector/{query}")
        page.wait_for_selector("#projector[data-agent-session]", state="attached", timeout=30_000)
        yield page
        context.close()
        browser.close()
    assert errors == [], errors


def wait_finished(
    api: requests.Session, base: str, pk: int, timeout_s: float = 60.0, kind: str = "acquisitions"
) -> dict:
    """The API's body of ``/api/<kind>/<id>/`` (an acquisition, or a measurement) once done or failed."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        body = api.get(f"{base}/api/{kind}/{pk}/").json()
        if body["status"] in ("done", "failed"):
            return body
        time.sleep(0.2)
    raise AssertionError(f"{kind} {pk} did not finish in {timeout_s} s: {body}")


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
