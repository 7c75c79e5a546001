"""The capture page of a stereo rig's multi-exposure capture (issues 24 and 26, docs/exposures.md
"Stereo rigs"): the exposures, camera 0's pixels per exposure and its map of which exposure each
pixel used, loaded in headless Chromium."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from tests.browser import CHROMIUM, POLL_MS, shot
from tests.conftest import log_page_in


def _upload(owner):
    from metrology.captures.services import upload_capture
    from metrology.core.codecs.stack import write_camera_stacks
    from metrology.core.scenes import make_scene
    from metrology.core.simulate.exposures import render_stereo_exposures
    from metrology.rigs.services import create_rig
    from tests.app.stereo_stacks import RIG
    from tests.core.exposure_scene import EXPOSURES
    from tests.stereo_rig import PLACEMENT, PROJECTOR, codec

    rig = create_rig(owner=owner, data={**RIG.to_dict(), "name": "stereo hdr"})
    rendered = render_stereo_exposures(
        RIG, make_scene("plane", z_mm=0.0), EXPOSURES, codec("u"), placement=PLACEMENT, projector=PROJECTOR
    )
    with tempfile.TemporaryDirectory(prefix="gcps-stereo-hdr-") as tmp:
        data = write_camera_stacks(rendered.stacks, Path(tmp) / "hdr.zip", codec("u")).read_bytes()
    upload = SimpleUploadedFile("hdr.zip", data, "application/zip")
    return upload_capture(owner=owner, rig=rig, upload=upload, role="object")


@pytest.mark.browser
@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed")
@pytest.mark.django_db(transaction=True)
def test_capture_page_of_a_stereo_multi_exposure_capture_in_the_browser(live_server, alice, browser_page, monkeypatch):
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")  # Playwright's loop shares this thread
    capture = _upload(alice)
    page = browser_page
    log_page_in(page, alice, live_server.url)
    response = page.goto(f"{live_server.url}/captures/{capture.pk}/")
    assert response is not None and response.status == 200
    page.wait_for_function("() => document.querySelector('#fig-exposure_u .main-svg') !== null", polling=POLL_MS)
    legend = page.locator("#fig-exposure_u").inner_text()
    assert all(f"{name} (" in legend for name in ("exp0", "exp1", "exp2")), legend
    assert page.locator("#h-exposures").is_visible()
    assert "could not be decoded" not in page.content()
    shot(page, "capture-stereo-exposures")
    assert page.js_errors == [], page.js_errors
