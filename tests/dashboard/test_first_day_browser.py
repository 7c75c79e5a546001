"""What a real rig's first day showed (issue 21, item 5), in headless Chromium: at 1366 px wide
the tables fit their cards (the rigs list, a rig's history of calibrated values, the jobs page),
and on the embedded default a measurement's page shows the job's progress and then its result."""

from __future__ import annotations

import os

import pytest

from tests.browser import CHROMIUM, shot
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
