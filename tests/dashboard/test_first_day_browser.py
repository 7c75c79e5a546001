"""What a real rig's first day showed (issue 21, item 5), in headless Chromium: at 1366 px wide
the tables fit their cards (the rigs list, a rig's history of calibrated values, the jobs page),
and on the embedded default a measurement's page shows the job's progress and then its result."""

from __future__ import annotations

import os

import pytest

from tests.browser import CHROMIUM, POLL_MS, shot
from tests.dashboard.browser_forms import log_in

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]

#: For each table in a card, how far (CSS px) it reaches beyond the card's content box (0 when it
#: fits), plus 1000 when its container scrolls sideways to hold it.
OVERFLOW_JS = """() => Array.from(document.querySelectorAll('.card table')).map(table => {
  const card = table.closest('.card');
  const style = getComputedStyle(card);
  const padding = parseFloat(style.paddingRight) + parseFloat(style.borderRightWidth);
  const inner = card.getBoundingClientRect().right - padding;
  const scroller = table.parentElement.scrollWidth > table.parentElement.clientWidth + 1;
  return Math.max(0, Math.round(table.getBoundingClientRect().right - inner)) + (scroller ? 1000 : 0);
})"""


def test_tables_fit_their_cards_at_1366_px(
    live_server, transactional_db, alice, rig, captures, browser_page, monkeypatch
):
    from metrology.calibrations.models import Calibration
    from metrology.jobs.models import Job
    from metrology.jobs.services import create_job
    from metrology.rigs.models import RigParameters
    from metrology.rigs.services import create_rig, set_rig_model
    from tests.pinhole_stacks import RIG

    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")  # ORM calls beside Playwright's event loop
    reference, master = captures
    for method in ("lsq", "paper"):
        Calibration.objects.create(
            owner=alice,
            rig=rig,
            reference=reference,
            master=master,
            master_height_mm=25.0,
            method=method,
            result={"L_mm": 1022.123456789, "alpha_rad": 0.332123456789, "d_mm": 352.0},
            job=create_job(owner=alice, kind=Job.Kind.CALIBRATION, parameters={}),
        )
    pinhole = create_rig(owner=alice, data={**RIG.to_dict(), "name": "structured-light bench, left camera 2448x2048"})
    set_rig_model(rig=pinhole, model=RIG, source=RigParameters.Source.IMPORTED)  # pinhole summaries in its history
    for kind in (Job.Kind.PROCAM_CALIBRATION, Job.Kind.MEASUREMENT, Job.Kind.CHARACTERIZATION):
        job = create_job(owner=alice, kind=kind, parameters={})
    Job.objects.filter(pk=job.pk).update(
        status=Job.Status.FAILED,
        error="the reference and the object were decoded with different codecs: gcps-v1:1024x768 and a "
        "gcps-codec/1 of 24 frames (axes u, v) on a projector of 1920x1080",
    )
    page = browser_page
    page.set_viewport_size({"width": 1366, "height": 900})
    log_in(page, live_server.url)
    for name, url in (
        ("rigs", "/rigs/"),
        ("rig", f"/rigs/{rig.pk}/"),
        ("pinhole-rig-history", f"/rigs/{pinhole.pk}/"),
        ("calibrations", "/calibrations/"),
        ("jobs", "/jobs/"),
    ):
        page.goto(f"{live_server.url}{url}")
        shot(page, f"first-day-1366-{name}")
        overflow = page.evaluate(OVERFLOW_JS)
        assert overflow and all(px == 0 for px in overflow), (name, overflow)
    assert not page.js_errors, page.js_errors


def test_on_the_embedded_default_a_measurement_page_shows_progress_then_its_maps(
    live_server, transactional_db, alice, rig, captures, browser_page, settings
):
    """No worker fixture: the live server's process runs the job in its embedded background thread
    (GCPS_EMBEDDED_JOBS=background, the default outside the tests), after the form's request has
    answered; the page shows the progress bar, then reloads onto the figures, the height map
    coloured between p1 and p99 with the full range on its colour bar."""
    from metrology.jobs.services import EmbeddedWorker

    settings.GCPS_EMBEDDED_JOBS = "background"
    settings.GCPS_JOB_PHASE_PAUSE_SECONDS = 0.5  # slow enough for the bar to be seen
    reference, obj = captures
    page = browser_page
    page.set_viewport_size({"width": 1366, "height": 900})
    log_in(page, live_server.url)
    page.goto(f"{live_server.url}/measurements/new/?rig={rig.pk}")
    page.select_option("#id_reference", str(reference.pk))
    page.select_option("#id_object", str(obj.pk))
    page.click("text=Run measurement")
    page.wait_for_url("**/measurements/*/")
    bar = page.locator(".js-job .progress")
    assert bar.count() == 1 and bar.get_attribute("data-status") in ("queued", "running")
    # the heading's badge follows the job, as the progress card does
    page.wait_for_function(
        "() => document.querySelector('h1 [data-job-badge]').textContent === 'running'", polling=POLL_MS
    )
    shot(page, "first-day-embedded-progress")
    page.wait_for_selector("#fig-height_map .main-svg", timeout=120_000)  # reloaded once the job is done
    colour_bar = page.locator("#fig-height_map .colorbar").text_content() or ""
    assert "full range" in colour_bar and "p1-p99" in colour_bar, colour_bar
    shot(page, "first-day-embedded-done")
    assert EmbeddedWorker.get().wait_idle(60)
    assert not page.js_errors, page.js_errors


def test_an_upload_names_its_capture_and_codec_and_the_capture_page_gives_valid_pixels_in_percent(
    live_server, transactional_db, alice, rig, browser_page, tmp_path
):
    from tests.app.stacks import SMALL_RIG, plane_zip

    path = tmp_path / "plane-r.zip"
    path.write_bytes(plane_zip(SMALL_RIG))
    page = browser_page
    page.set_viewport_size({"width": 1366, "height": 900})
    log_in(page, live_server.url)
    page.goto(f"{live_server.url}/rigs/{rig.pk}/captures/")
    assert "the rig's default codec (gcps-v1)" in page.locator("#h-up + form .helptext").first.inner_text()
    page.set_input_files("#id_upload-file", str(path))
    page.select_option("#id_upload-role", "reference")
    page.click("form:has(input[value=upload]) button[type=submit]")
    page.wait_for_url(f"**/rigs/{rig.pk}/captures/")
    message = page.locator("p.alert.info[role=status]").inner_text()
    assert message.startswith("Stored capture #") and "(reference plane, plane-r.zip)" in message, message
    assert "decoded with gcps-v1, the rig's default codec (used when the zip has no codec.json)" in message
    shot(page, "first-day-upload-message")
    capture_id = message.split("#", 1)[1].split(" ", 1)[0]
    page.goto(f"{live_server.url}/captures/{capture_id}/")
    cell = page.locator("#h-decoding ~ table td.num").first.inner_text()
    assert " % (" in cell and cell.endswith(" px)"), cell
    # the codec self-check of the stored stack (issue 21 item 1): the paper's codec, rightly described
    check_rows = page.locator("#h-codec-check + table tbody tr")
    assert check_rows.count() >= 1
    assert check_rows.first.locator(".badge").inner_text() == "consistent", check_rows.first.inner_text()
    shot(page, "first-day-capture-valid-pixels")
    assert not page.js_errors, page.js_errors
