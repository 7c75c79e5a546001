"""Projector-camera calibration in headless Chromium: upload six pose zips through the form, watch the
job's progress, see the warnings and figures, apply, see the rig page show the pinhole calibration.

Jobs run in the in-process worker thread of tests/dashboard/conftest.py; screenshots (GCPS_SCREENSHOTS=1) go to
artifacts/screenshots/ (procam-*.png).
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.rigs.services import create_rig
from tests.app.procam_stacks import BOARD_SPEC, RIG_320, TRUE_RIG, UNUSABLE_POSE, pose_name, pose_zips
from tests.browser import CHROMIUM, POLL_MS, shot
from tests.conftest import PASSWORD

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not __import__("os").path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


@pytest.fixture
def procam_rig(alice):
    """A crossed-axes rig of the poses' camera size (made before the browser starts its event loop)."""
    return create_rig(owner=alice, data={**RIG_320, "name": "procam bench"})


def test_procam_calibration_in_the_browser(live_server, alice, procam_rig, worker, browser_page, tmp_path):
    page = browser_page
    base = live_server.url
    rig = procam_rig
    files = []
    for index, data in enumerate(pose_zips()):
        path = tmp_path / pose_name(index)
        path.write_bytes(data)
        files.append(str(path))

    page.goto(f"{base}/login/")
    page.fill("#id_username", "alice")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url(f"{base}/")

    page.goto(f"{base}/rigs/{rig.pk}/")
    page.click("text=Projector-camera calibration")
    page.wait_for_url("**/procam-calibrations/new/?rig=*")
    assert "points per row first" in page.locator("form.stack").inner_text()
    page.fill("#id_board", BOARD_SPEC)
    page.set_input_files("#id_pose_files", files)
    assert pose_name(5) in page.locator(".js-file-name").inner_text()
    page.check("#id_fix_k3")
    shot(page, "procam-01-new")
    page.click("text=Start the calibration")
    page.wait_for_url("**/procam-calibrations/*/")
    detail_url = page.url
    if page.locator(".progress[role=progressbar]").count():  # not done yet when the page was served
        page.wait_for_selector(".progress[data-status=running], .progress[data-status=done]")
        shot(page, "procam-02-progress")
    page.wait_for_selector("#h-warnings")  # the page reloaded with the result
    warning = page.locator(".warning").first
    assert "board_not_found" in warning.inner_text() and "What to do" in warning.inner_text()
    assert "5 of 6" in page.locator("dl.values").first.inner_text()
    fx = float(page.locator("table").first.locator("td.num").first.inner_text().split()[0])
    assert abs(fx / np.asarray(TRUE_RIG.camera.K)[0, 0] - 1) < 0.005
    # every figure is drawn: 5 residual plots and 2 coverage maps, all loaded
    images = page.locator("figure.svg-figure img")
    assert images.count() == 7
    for i in range(images.count()):
        images.nth(i).scroll_into_view_if_needed()
        page.wait_for_function(
            "el => el.complete && el.naturalWidth > 0", arg=images.nth(i).element_handle(), polling=POLL_MS
        )
    assert f"/residuals/{UNUSABLE_POSE}.svg" not in page.content()
    # what the poses cannot determine: both devices' focal-distance correlation, and the
    # intrinsics' tables with their spread and correlation columns fitting their cards
    determinacy = page.locator("#h-determinacy").locator("..")
    assert "focal length vs. board distance" in determinacy.inner_text()
    assert determinacy.locator("td.separable").count() == 2
    for card in page.locator("section.card", has=page.locator("th", has_text="left-out spread")).all():
        assert card.evaluate("el => el.scrollWidth <= el.clientWidth + 1"), card.inner_text()[:200]
    assert page.js_errors == []
    shot(page, "procam-03-detail")

    page.click("text=Apply to procam bench")
    page.wait_for_url(f"{base}/rigs/{rig.pk}/")
    current = page.locator("#h-current").locator("..").inner_text()
    assert "pinhole camera and projector" in current
    history = page.locator("#h-hist").locator("..").inner_text()
    assert "projector-camera calibration" in history and f"pinhole: camera fx {fx:.2f} px" in history
    shot(page, "procam-04-rig")
    page.goto(detail_url)
    assert "Applied" in page.locator("#h-apply").locator("..").inner_text()

    # changed one's mind: the history's Restore brings the crossed-axes values back, as a new entry
    page.goto(f"{base}/rigs/{rig.pk}/")
    page.locator("#h-hist").locator("..").get_by_role("button", name="Restore").last.click()
    page.wait_for_url(f"{base}/rigs/{rig.pk}/#h-hist")
    history = page.locator("#h-hist").locator("..").inner_text()
    assert "restored, the values of" in history and "pinhole camera and projector" not in page.content()
    assert "New calibration" in page.content()  # the crossed-axes rig's actions again
    assert f"Crossed optical axes (the paper's model): L {RIG_320['L_mm']:g} mm" in history
    assert page.js_errors == []
    shot(page, "procam-05-restored")
    assert [outcome for _, outcome in worker] == ["done"]
