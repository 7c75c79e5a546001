"""Inspection in headless Chromium: upload a nominal model through the form (and, with cadquery-ocp, a
STEP file, its tessellation tolerance shown), inspect a finished measurement against it from the
measurement's page, watch the job, see the deviation map (a diverging scale centred at 0 with the
tolerance marked), the histogram, the conformance counts and the features table (a plane typed as
JSON in the form), open the printable report.

The scene and the nominal are tests/app/test_inspections.py's (a block with a 0.1 mm pit, the block
without it). Jobs run in the in-process worker of tests/dashboard/conftest.py; screenshots (GCPS_SCREENSHOTS=1) go to
artifacts/screenshots/ (inspection-*.png).
"""

from __future__ import annotations

import json

import pytest

from metrology.core.io.step import LINEAR_TOLERANCE_MM, ocp_available
from metrology.measurements.services import request_measurement
from tests.app.inspection_parts import (
    PIT_DEPTH_MM,
    TOP_FEATURE,
    block_nominal,
    block_step,
    pitted_block_heights,
    stl_bytes,
)
from tests.browser import CHROMIUM, shot
from tests.conftest import PASSWORD
from tests.dashboard.conftest import upload

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not __import__("os").path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


@pytest.fixture
def pitted_measurement(alice, rig, worker):
    """A measurement of the pitted block (made before the browser starts its event loop)."""
    reference = upload(alice, rig, 0.0, "reference")
    obj = upload(alice, rig, pitted_block_heights(), "object")
    return request_measurement(owner=alice, rig=rig, reference_id=reference.pk, object_id=obj.pk)


def test_inspection_in_the_browser(live_server, alice, pitted_measurement, worker, browser_page, tmp_path):
    page = browser_page
    base = live_server.url
    nominal = tmp_path / "block.stl"
    nominal.write_bytes(stl_bytes(*block_nominal()))

    page.goto(f"{base}/login/")
    page.fill("#id_username", "alice")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url(f"{base}/")

    page.click("nav.main >> text=Inspections")
    page.click("text=Nominal models")
    if ocp_available():  # a STEP file through the same form, tessellated, its tolerance shown
        page.set_input_files("#id_file", str(block_step(tmp_path / "part.step")))
        page.click("button:has-text('Upload')")
        page.wait_for_selector("td:has-text('part')")
        row = page.locator("tr", has_text="part")
        assert "STEP" in row.inner_text() and "12" in row.inner_text()
        assert row.locator("[data-tessellation]").inner_text() == f"{LINEAR_TOLERANCE_MM} mm, 0.1 rad"
    page.set_input_files("#id_file", str(nominal))
    page.fill("#id_name", "block")
    page.click("button:has-text('Upload')")
    page.wait_for_selector("td:has-text('block')")
    assert "12" in page.locator("table").inner_text()  # triangles
    shot(page, "inspection-01-nominals")

    page.goto(f"{base}/measurements/{pitted_measurement.pk}/")
    page.wait_for_selector("#fig-height_map .main-svg")  # the measurement is done
    page.click("text=Inspect against a nominal model")
    assert "block (12 triangles)" in page.locator("#id_nominal option").nth(1).inner_text()  # the STL, the newest
    page.select_option("#id_nominal", label=page.locator("#id_nominal option").nth(1).inner_text())
    page.select_option("#id_init", "identity")
    page.fill("#id_tolerance_mm", "0.05")
    page.fill("#id_features", json.dumps([TOP_FEATURE]))  # the block's top plane, typed as JSON
    page.click("text=Run inspection")
    page.wait_for_url("**/inspections/*/")
    page.wait_for_selector("#fig-deviation_map .main-svg")  # the page reloaded with the result
    page.wait_for_selector("#fig-deviation_histogram .main-svg")
    nonconforming = int(page.locator("[data-nonconforming]").inner_text())
    assert nonconforming >= 100  # the 10 x 10 px pit
    assert int(page.locator("[data-conforming]").inner_text()) > 4 * nonconforming
    # the colour bar is centred at 0 and marks the tolerance
    ticks = page.locator("#fig-deviation_map .colorbar").text_content() or ""
    assert "+T 50" in ticks and "-T -50" in ticks and "0" in ticks
    # the features table: the top plane's flatness is the pit's depth (minimum zone)
    feature = page.locator("table[data-features] tr[data-feature=top]")
    assert feature.locator("th").inner_text() == "top" and "plane" in feature.inner_text()
    flatness = page.locator("table[data-features] tr", has_text="flatness").locator("td.num").nth(0).inner_text()
    value, unit = flatness.split()
    assert unit == "mm" and abs(float(value) - PIT_DEPTH_MM) < 0.010, flatness  # as the API test's bound
    shot(page, "inspection-02-result")

    page.click("text=Report (HTML)")
    page.wait_for_url("**/inspections/*/report/")
    page.wait_for_selector("#fig-deviation_map .main-svg")
    assert "Nominal SHA-256" in page.content()
    shot(page, "inspection-03-report")
    assert page.js_errors == []
