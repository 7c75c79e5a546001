"""The HTML report in headless Chromium: every figure fits its cell (Fig. 12 shows Z_in up to the top
of the range and its legend), and the drift table shows each change's uncertainty."""

from __future__ import annotations

import os

import pytest

from metrology.jobs.models import Job
from metrology.reports import services
from tests.browser import CHROMIUM, shot

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.django_db(transaction=True),
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]

# Six positions over the paper's 0-80 mm range, two repeats: a few seconds on the 160 x 120 rig.
FULL_RANGE = {"z_start_mm": 0.0, "z_stop_mm": 80.0, "z_step_mm": 16.0, "repeats": 2}

FIGURE_FITS = """() => [...document.querySelectorAll('.js-plotly-plot')].map(gd => {
  const box = gd.getBoundingClientRect(), cell = gd.closest('figure').getBoundingClientRect();
  const legend = gd.querySelector('.legend');
  const lb = legend ? legend.getBoundingClientRect() : null;
  return {id: gd.id, width: gd._fullLayout.width, cell: cell.width, right: box.right, cellRight: cell.right,
          xrange: gd._fullLayout.xaxis.range,
          legendInside: lb === null || (lb.right <= cell.right + 1 && lb.left >= cell.left - 1)};
})"""


def test_report_figures_fit_their_cells_and_drift_shows_uncertainty(rig, browser_page, media_root, monkeypatch):
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")  # ORM calls beside Playwright's event loop
    first = services.run_characterization_report(rig, source="virtual_stage", options=FULL_RANGE)
    second = services.run_characterization_report(rig, source="virtual_stage", options=FULL_RANGE)
    assert first.job.status == second.job.status == Job.Status.DONE, (first.job.error, second.job.error)
    page = browser_page
    page.goto(f"file://{media_root / second.html.name}")
    page.wait_for_selector("#figure-in_out .main-svg")
    page.wait_for_timeout(300)
    # measured before any screenshot: a full-page screenshot resizes the window, which redraws the figures
    figures = {item["id"]: item for item in page.evaluate(FIGURE_FITS)}
    assert set(figures) >= {"figure-in_out", "figure-error_vs_z"}
    for item in figures.values():
        assert item["width"] <= item["cell"] + 1 and item["right"] <= item["cellRight"] + 1, item
        assert item["legendInside"], item
    lo, hi = figures["figure-in_out"]["xrange"]
    assert lo <= 0.0 and hi >= 80.0, figures["figure-in_out"]  # the whole Z_in range of Fig. 12 is shown
    drift = page.locator("#drift").inner_text()
    assert "Uncertainty of the change (1σ)" in drift
    rows = page.locator("#drift tbody tr[data-key^='positions.mean_error_mm@']")
    assert rows.count() == 6
    assert "± " in rows.first.inner_text() and "µm" in rows.first.inner_text()
    shot(page, "11-report")
    assert not page.js_errors, page.js_errors
