"""Every action a rig's pages offer, walked in headless Chromium on a crossed-axes and on a pinhole rig.

The pinhole rig is made as a user would make it from an OpenCV calibration: the Rigs page's
"Import a calibration file" with a FileStorage YAML. Then, on each rig: the rig page's buttons
(checked against what the model can do: the paper's calibration and the sensitivity curves only
where the model has L and alpha), the captures page's simulate forms (a reference, an object, a
master block where the model can be calibrated, a stage series), a measurement (titled height or
depth map as its result is), the paper's calibration, a characterization of the stage series, the
default codec form, the inspection plan page, a restore from the history, and a calibration file imported into the rig
itself. Each job runs in the dashboard's in-process worker and must end ``done``; every page must
load without a JavaScript error. A button the walk does not know fails the test, so an action
added to the rig page is added to the walk.
With GCPS_SCREENSHOTS=1, screenshots go to artifacts/screenshots/rig-walk-*.png.
"""

from __future__ import annotations

import os
import re

import pytest

from tests.browser import CHROMIUM, shot
from tests.dashboard.browser_forms import create_rig, log_in, simulate, simulate_stage_series, wait_until_shown_done
from tests.pinhole_stacks import PROJ_H, PROJ_W, write_filestorage_yaml

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]

RIG_PAGE_BUTTONS = {
    "Captures",
    "New measurement",
    "Projector-camera calibration",
    "New calibration",
    "New characterization",
    "Sensitivity (Figs. 4-6)",
    "Inspection plan",
}
"""Every button of a rig page's action bar that this walk knows how to exercise."""
PAPER_ONLY = {"New calibration", "Sensitivity (Figs. 4-6)"}
"""Offered only where the model has the paper's L and alpha."""


def choose(page, select: str, label_part: str) -> None:
    """Select the first option of ``select`` whose label contains ``label_part``."""
    options = page.locator(f"{select} option")
    for i in range(options.count()):
        if label_part in options.nth(i).inner_text():
            page.select_option(select, index=i)
            return
    raise AssertionError(f"{select} has no option with {label_part!r}: {options.all_inner_texts()}")


def walk(page, base: str, rig_url: str, name: str, quantity: str) -> None:
    rig_id = rig_url.rstrip("/").split("/")[-1]
    page.goto(rig_url)
    buttons = {t.strip() for t in page.locator("p.downloads a.button").all_inner_texts()}
    assert buttons <= RIG_PAGE_BUTTONS, f"actions the walk does not know: {buttons - RIG_PAGE_BUTTONS}"
    paper = "New calibration" in buttons
    assert ("Sensitivity (Figs. 4-6)" in buttons) == paper
    assert buttons - PAPER_ONLY == RIG_PAGE_BUTTONS - PAPER_ONLY
    shot(page, f"rig-walk-{name}-01-rig")

    simulate(page, rig_url, "reference", noise="low")
    simulate(page, rig_url, "sphere", noise="low", seed="2")
    if paper:
        simulate(page, rig_url, "block", z="40", noise="low", seed="3")
    simulate_stage_series(page, rig_url, z_to="10", step="5", repeats="1")
    shot(page, f"rig-walk-{name}-02-captures")

    # a measurement: its map is titled as what it holds
    page.goto(rig_url)
    page.click("p.downloads >> text=New measurement")
    page.wait_for_url(f"**/measurements/new/?rig={rig_id}")
    choose(page, "#id_reference", "reference")
    choose(page, "#id_object", "object")
    page.click("text=Run measurement")
    page.wait_for_url(re.compile(r".*/measurements/\d+/$"))
    page.wait_for_selector("#fig-height_map .main-svg")
    assert quantity in page.locator("h2").all_inner_texts()
    shot(page, f"rig-walk-{name}-03-measurement")

    if paper:
        page.goto(rig_url)
        page.click("p.downloads >> text=New calibration")
        choose(page, "#id_reference", "reference")
        choose(page, "#id_master", "master")
        page.fill("#id_master_height_mm", "40")
        page.click("text=Run calibration")
        page.wait_for_url(re.compile(r".*/calibrations/\d+/$"))
        wait_until_shown_done(page)
        shot(page, f"rig-walk-{name}-04-calibration")
        page.goto(rig_url)
        page.click("p.downloads >> text=Sensitivity (Figs. 4-6)")
        page.wait_for_selector(".main-svg")
    else:
        page.goto(f"{base}/calibrations/new/?rig={rig_id}")
        assert "L and alpha" in page.content()  # says why, instead of a form that cannot work

    page.goto(rig_url)
    page.click("p.downloads >> text=New characterization")
    choose(page, "#id_reference", "reference")
    page.select_option("#id_session", index=1)
    page.fill("#id_n_points", "5")
    page.click("text=Run characterization")
    page.wait_for_url(re.compile(r".*/characterizations/\d+/$"))
    wait_until_shown_done(page)
    page.wait_for_selector("#fig-in_out .main-svg")  # its figures drawn
    shot(page, f"rig-walk-{name}-05-characterization")

    page.goto(rig_url)
    page.click("p.downloads >> text=Projector-camera calibration")
    page.wait_for_selector("h1")
    assert page.locator("form").count() >= 1  # the board-pose form (walked by test_procam_browser.py)

    page.goto(rig_url)
    page.click("p.downloads >> text=Inspection plan")
    page.wait_for_url(f"**/rigs/{rig_id}/inspection-plan/")
    assert page.locator("h2#h-plan").inner_text() == "No plan yet"  # the plan form (walked by the inspection tests)
    assert page.locator("form button:has-text('Set the plan')").count() == 1

    # the default codec, then a restore from the history
    page.goto(rig_url)
    with page.expect_navigation():  # posted to the rig page, redirected back to it
        page.click("text=Set the default codec")
    assert page.url == rig_url and page.locator(".errorlist, .alert[role=alert]").count() == 0
    entries = page.locator("#h-hist + div tbody tr").count()
    restore = page.locator("button:has-text('Restore')")
    if restore.count():
        with page.expect_navigation():
            restore.first.click()
        assert page.locator("#restore-error").count() == 0
        assert page.locator("#h-hist + div tbody tr").count() == entries + 1  # a new entry, nothing deleted
    shot(page, f"rig-walk-{name}-06-rig-after")
    assert page.js_errors == [], page.js_errors


def test_every_rig_page_action_works_on_both_models(live_server, alice, worker, browser_page, tmp_path):
    page = browser_page
    base = live_server.url
    log_in(page, base)

    # a crossed-axes rig typed in, a pinhole rig imported from an OpenCV calibration file
    page.goto(f"{base}/rigs/")
    crossed_url = create_rig(page, "crossed walk")

    calibration = tmp_path / "stereo_calibration.yml"
    write_filestorage_yaml(calibration)
    page.goto(f"{base}/rigs/")
    page.fill("#id_import-name", "pinhole walk")
    page.set_input_files("#id_import-calibration_file", str(calibration))
    page.fill("#id_import-projector_width", str(PROJ_W))
    page.fill("#id_import-projector_height", str(PROJ_H))
    page.click("form:has(input[value=calibration]) button[type=submit]")
    page.wait_for_url("**/rigs/*/")
    pinhole_url = page.url
    message = page.locator(".messages, [role=status]").first.inner_text()
    for node in ("cam_int", "cam_dist", "proj_int", "proj_dist", "rotation", "translation", "img_shape"):
        assert node in message, (node, message)
    assert "Calibrated pinhole camera and projector" in page.content()
    shot(page, "rig-walk-pinhole-00-imported")

    walk(page, base, crossed_url, "crossed", quantity="Height map")
    walk(page, base, pinhole_url, "pinhole", quantity="Height map")  # measured against a reference plane

    # the rig page imports a calibration file into the rig itself (it becomes a pinhole rig), and
    # Restore brings its crossed-axes values back
    page.goto(crossed_url)
    page.set_input_files("#id_import-calibration_file", str(calibration))
    page.fill("#id_import-projector_width", str(PROJ_W))
    page.fill("#id_import-projector_height", str(PROJ_H))
    with page.expect_navigation():  # posted to the rig page, redirected back to it
        page.click("form:has(input[value=calibration]) button[type=submit]")
    assert page.url == crossed_url
    assert "cam_int" in page.locator(".messages, [role=status]").first.inner_text()
    values = page.locator("#h-current + dl").inner_text()
    assert "Calibrated pinhole camera and projector" in values
    with page.expect_navigation():
        page.locator("button:has-text('Restore')").first.click()  # the entry before the import
    assert "Crossed optical axes" in page.locator("#h-current + dl").inner_text()
    shot(page, "rig-walk-crossed-07-imported-and-restored")
    assert page.js_errors == [], page.js_errors
