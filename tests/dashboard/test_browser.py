"""End to end in headless Chromium (Playwright driving Debian's /usr/bin/chromium).

The live server runs in a thread of this process; jobs are picked up by a small in-process
"worker" thread (one job at a time, like a Celery worker with concurrency 1) so that the pages
really show a progress bar moving from queued to done. With GCPS_SCREENSHOTS=1, screenshots go to
artifacts/screenshots/.
"""

from __future__ import annotations

import os

import pytest

from tests.browser import CHROMIUM, shot
from tests.conftest import PASSWORD
from tests.dashboard.browser_forms import create_rig, log_in, simulate, simulate_stage_series

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


def test_measure_and_characterize_in_the_browser(live_server, alice, worker, browser_page, tmp_path, monkeypatch):
    page = browser_page
    base = live_server.url

    # log in
    page.goto(f"{base}/")
    assert "/login/" in page.url
    page.fill("#id_username", "alice")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url(f"{base}/")
    assert page.locator(".empty").first.is_visible()
    shot(page, "01-home-empty")

    # create a rig
    page.click("nav >> text=Rigs")
    rig_url = create_rig(page, "browser rig")
    assert page.locator("h1").inner_text() == "browser rig"
    shot(page, "02-rig")

    # simulate a reference and an object; each shows a progress bar that reaches done
    simulate(page, rig_url, "reference")
    simulate(page, rig_url, "two_spheres", noise="low", seed="2")
    assert page.locator("td .badge.stored").count() == 2
    shot(page, "03-captures")

    # run a measurement and watch the bar reach done
    page.goto(f"{base}/measurements/new/?rig={rig_url.rstrip('/').split('/')[-1]}")
    page.select_option("#id_reference", index=1)
    page.select_option("#id_object", index=1)
    page.click("text=Run measurement")
    page.wait_for_url("**/measurements/*/")
    bar = page.locator(".progress[role=progressbar]")
    if bar.count():  # not yet done when the page was served
        page.wait_for_selector(".progress[data-status=running], .progress[data-status=done]")
        shot(page, "04-measurement-progress")
    page.wait_for_selector("#fig-height_map .main-svg")  # the page reloaded with the figures
    assert page.locator("#fig-height_map .heatmaplayer, #fig-height_map image").count() >= 1
    page.wait_for_selector("#fig-surface canvas")  # the 3D view is drawn with WebGL
    assert page.locator("#fig-surface .gl-container canvas, #fig-surface canvas").count() >= 1
    assert page.locator("#fig-profile .main-svg").count() >= 1
    assert page.locator("#fig-gray_vs_gcps .main-svg").count() >= 1
    # the row profiles are SVG line plots, drawn where WebGL is missing too (they were blank there)
    for figure in ("#fig-profile", "#fig-gray_vs_gcps"):
        assert page.locator(f"{figure} .scatterlayer .trace path.js-line").count() >= 1
    assert "WebGL is not supported" not in page.locator("body").inner_text()
    assert page.locator("#fig-height_map .colorbar").count() == 1
    # the X axis spans the field (d - FW/2 .. d + FW/2 = 102 .. 602 mm), not a range padded to the square aspect
    x_range = page.evaluate("document.getElementById('fig-height_map')._fullLayout.xaxis.range")
    assert 101.0 <= x_range[0] <= 103.0 and 601.0 <= x_range[1] <= 603.0, x_range
    assert "down" in page.locator("#fig-height_map .g-ytitle").text_content()
    shot(page, "05-measurement", settle_ms=500)

    # row chooser
    page.fill("#id_row", "60")
    page.click("text=Show row")
    page.wait_for_selector("#fig-profile .main-svg")
    assert "Profile along row 60" in page.locator("#fig-profile").inner_text()

    # download the PLY and parse it
    with page.expect_download() as info:
        page.click("a[href$='mesh.ply']")
    path = tmp_path / "mesh.ply"
    info.value.save_as(path)
    header = path.read_bytes().split(b"end_header", 1)[0].decode("ascii", "replace")
    assert header.startswith("ply")
    vertices = int(next(line.split()[-1] for line in header.splitlines() if line.startswith("element vertex")))
    faces = int(next(line.split()[-1] for line in header.splitlines() if line.startswith("element face")))
    assert vertices > 1000 and faces > 1000
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    assert len(mesh.vertices) == vertices and len(mesh.triangles) == faces

    # a stage series (0, 4, 8 mm, 2 repeats) then a characterization
    simulate_stage_series(page, rig_url, z_to="8", step="4", repeats="2")
    assert "6 stage captures" in page.locator("#id_session").inner_text()
    page.select_option("#id_reference", index=1)
    page.fill("#id_n_points", "9")
    page.click("text=Run characterization")
    page.wait_for_url("**/characterizations/*/")
    page.wait_for_selector("#fig-in_out .main-svg")
    page.wait_for_selector("#fig-error_vs_z .main-svg")
    assert "Fig. 12" in page.content() and "Fig. 13" in page.content()
    assert page.locator("#fig-in_out .scatterlayer .trace").count() >= 2
    assert "% of full scale" in page.locator("table").first.inner_text()
    shot(page, "06-characterization", settle_ms=500)

    # the sensitivity page
    page.goto(f"{rig_url}sensitivity/")
    page.wait_for_selector("#fig-sensitivity_alpha .main-svg")
    shot(page, "07-sensitivity")

    # a scheduled report: the schedule is stored for beat; here the task beat would send runs once
    from metrology.reports.services import schedule_report
    from metrology.reports.tasks import scheduled_characterization_report
    from metrology.rigs.models import Rig

    # Playwright's sync API keeps an event loop on this thread; the ORM calls below are synchronous
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
    rig = Rig.objects.get(pk=int(rig_url.rstrip("/").split("/")[-1]))
    options = {"z_start_mm": 0.0, "z_stop_mm": 8.0, "z_step_mm": 4.0, "repeats": 2}
    task = schedule_report(rig, every_s=3600, source="virtual_stage", options=options)
    assert task.enabled and task.task == "metrology.reports.tasks.scheduled_characterization_report"
    report_id = scheduled_characterization_report.run(rig.pk, source="virtual_stage", options=options)
    page.goto(f"{base}/reports/")
    page.click(f"a[href='/reports/{report_id}/']")
    page.wait_for_url(f"**/reports/{report_id}/")
    report = page.frame_locator("iframe").locator(".js-plotly-plot .main-svg").first
    report.wait_for()
    shot(page, "08-report")

    statuses = {status for _job, status in worker}
    assert statuses <= {"done", "skipped"}, worker  # a report runs its sub-jobs inline; their queued copies skip
    assert not page.js_errors, page.js_errors


def test_uploaded_captures_appear_on_every_page_that_lists_captures(
    live_server, alice, rig, browser_page, tmp_path, monkeypatch
):
    """Upload two zips through the captures page (uploads carry no scene), then open every capture list."""
    from metrology.captures.models import Capture
    from metrology.captures.services import create_session
    from tests.app.stacks import SMALL_RIG, plane_zip
    from tests.dashboard.conftest import upload
    from tests.dashboard.helpers import capture_listing_pages

    page = browser_page
    base = live_server.url
    log_in(page, base)
    rig_url = f"{base}/rigs/{rig.pk}/captures/"
    for name, role, z_mm in (("plane-r.zip", "reference", 0.0), ("block-o.zip", "object", 10.0)):
        path = tmp_path / name
        path.write_bytes(plane_zip(SMALL_RIG, z_mm))
        page.goto(rig_url)
        page.set_input_files("#id_upload-file", str(path))
        assert name in page.locator(".js-file-name").inner_text()  # the drop zone names the chosen file
        page.select_option("#id_upload-role", role)
        page.click("form:has(input[value=upload]) button[type=submit]")
        page.wait_for_url(rig_url)
        assert page.locator("table", has_text=name).count() == 1, name
    shot(page, "09-uploaded-captures")

    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")  # ORM calls beside Playwright's event loop
    reference = Capture.objects.get(rig=rig, role="reference")
    obj = Capture.objects.get(rig=rig, role="object")
    assert reference.parameters == {} and obj.parameters == {}
    session = create_session(owner=alice, rig=rig, name="stage")  # so that the characterization form shows
    for z in (0.0, 4.0):
        upload(alice, rig, z, "stage", z_in_mm=z, session_id=session.pk)

    for url, expected in capture_listing_pages(rig.pk, reference.pk, obj.pk).items():
        response = page.goto(f"{base}{url}")
        assert response is not None and response.status == 200, url
        html = page.content()
        for marker in expected:
            assert marker in html, (url, marker)
    page.goto(f"{base}/captures/")
    shot(page, "10-all-captures")
    assert not page.js_errors, page.js_errors
