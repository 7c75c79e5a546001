"""The capture page of a multi-exposure capture (issue 26, docs/exposures.md): the exposures, the
pixels each measured, and the image of which exposure each pixel used; loaded in headless Chromium."""

from __future__ import annotations

import base64
import os

import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.services import upload_capture
from metrology.core.geometry.crossed_axes import Rig
from tests.app.stacks import SMALL_RIG, hdr_members, zip_bytes
from tests.browser import CHROMIUM, POLL_MS, shot
from tests.conftest import log_page_in
from tests.dashboard.helpers import figure_data

HALF = SMALL_RIG["width_px"] // 2


def _upload(owner, rig):
    data = zip_bytes(hdr_members(Rig.from_dict(SMALL_RIG), 0.0))
    return upload_capture(
        owner=owner, rig=rig, upload=SimpleUploadedFile("hdr.zip", data, "application/zip"), role="reference"
    )


def _array(value) -> np.ndarray:
    """A plotly figure's array: a nested list, or its typed-array form ``{"dtype", "bdata", "shape"}``."""
    if isinstance(value, dict):
        shape = [int(n) for n in str(value["shape"]).split(",")]
        return np.frombuffer(base64.b64decode(value["bdata"]), dtype=value["dtype"]).reshape(shape).astype(float)
    return np.asarray(value, dtype=float)


def _ticks(html: str) -> dict[str, int]:
    """Pixels per exposure name in the legend of the exposure figure."""
    ticks = figure_data(html, "exposure_u")["data"][0]["colorbar"]["ticktext"]
    return {t.split(" (")[0]: int(t.split("(")[1].split(" px")[0]) for t in ticks}


def test_capture_page_shows_the_pixels_per_exposure_and_which_exposure_each_pixel_used(client_alice, rig, alice):
    capture = _upload(alice, rig)
    html = client_alice.get(f"/captures/{capture.pk}/").content.decode()
    assert "short (1000 µs), long (10000 µs)" in html  # the exposures, least exposed first
    assert 'id="h-exposures"' in html
    counts = _ticks(html)
    # the long exposure saturates the bright left half (reflectance 1), which the short one measures;
    # the dark right half (0.05) is measured by the long one, 10x its modulation in the short
    height = SMALL_RIG["height_px"]
    assert 0.9 * HALF * height <= counts["short"] <= HALF * height
    assert 0.9 * HALF * height <= counts["long"] <= HALF * height
    assert sum(counts.values()) == HALF * 2 * height
    sampled = _array(figure_data(html, "exposure_u")["data"][0]["z"])  # exposure ranks, every k-th pixel
    left, right = sampled[:, : sampled.shape[1] // 2 - 2], sampled[:, sampled.shape[1] // 2 + 2 :]
    assert np.mean(left == 0) > 0.9 and np.mean(right == 1) > 0.9
    for count in (counts["short"], counts["long"]):  # the table shows the same counts
        assert f"{count:,} of" in html


@pytest.mark.browser
@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed")
@pytest.mark.django_db(transaction=True)
def test_capture_page_of_a_multi_exposure_capture_in_the_browser(live_server, alice, rig, browser_page, monkeypatch):
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")  # Playwright's loop shares this thread
    capture = _upload(alice, rig)
    page = browser_page
    log_page_in(page, alice, live_server.url)
    response = page.goto(f"{live_server.url}/captures/{capture.pk}/")
    assert response is not None and response.status == 200
    page.wait_for_function("() => document.querySelector('#fig-exposure_u .main-svg') !== null", polling=POLL_MS)
    legend = page.locator("#fig-exposure_u").inner_text()
    assert "short (" in legend and "long (" in legend
    assert page.locator("#h-exposures").is_visible()
    shot(page, "capture-exposures")
    assert page.js_errors == [], page.js_errors
