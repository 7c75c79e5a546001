"""The Content-Security-Policy header is on every page, and the pages still work under it in
headless Chromium: plotly figures (SVG and the WebGL 3D view), the progress script, the API docs.
Any CSP violation the browser reports fails the test."""

from __future__ import annotations

import os

import pytest

from tests.browser import CHROMIUM
from tests.conftest import log_page_in

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]

RECORD_VIOLATIONS = """
window.__csp = [];
document.addEventListener("securitypolicyviolation", function (e) {
  window.__csp.push(e.violatedDirective + " blocked " + (e.blockedURI || "inline"));
});
"""


def test_header_is_sent_on_pages_and_api(client_alice, rig):
    from django.test import Client

    for client, path in [
        (client_alice, "/"),
        (client_alice, f"/rigs/{rig.pk}/"),
        (Client(), "/api/docs/"),
        (Client(), "/login/"),
    ]:
        response = client.get(path)
        assert response.status_code == 200, path
        policy = response["Content-Security-Policy"]
        assert "default-src 'self'" in policy and "object-src 'none'" in policy, path
    assert "frame-ancestors 'self'" in client_alice.get("/api/rigs/")["Content-Security-Policy"]


@pytest.mark.django_db(transaction=True)
def test_pages_work_under_the_policy(live_server, alice, captures, browser_page, monkeypatch):
    # Playwright's sync API keeps an event loop on this thread; the ORM calls here are synchronous
    monkeypatch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")

    from metrology.measurements.services import request_measurement

    reference, obj = captures
    measurement = request_measurement(owner=alice, rig=reference.rig, reference_id=reference.pk, object_id=obj.pk)
    measurement.refresh_from_db()
    assert measurement.job.status == "done", measurement.job.error

    page = browser_page
    page.add_init_script(RECORD_VIOLATIONS)
    console: list[str] = []
    page.on("console", lambda msg: console.append(msg.text) if msg.type == "error" else None)
    log_page_in(page, alice, live_server.url)

    visited = []

    def visit(path: str, selector: str) -> None:
        response = page.goto(f"{live_server.url}{path}")
        assert response is not None and response.status == 200, path
        assert "default-src 'self'" in (response.header_value("content-security-policy") or ""), path
        page.wait_for_selector(selector)
        visited.append(path)

    visit(f"/measurements/{measurement.pk}/", "#fig-height_map .main-svg")
    page.wait_for_selector("#fig-surface canvas")  # the WebGL 3D view
    visit(f"/rigs/{reference.rig_id}/sensitivity/", "#fig-sensitivity_alpha .main-svg")
    visit("/api/docs/", ".swagger-ui .info")
    page.wait_for_timeout(300)
    violations = page.evaluate("window.__csp")
    assert violations == [], violations
    assert not [text for text in console if "Content Security Policy" in text], console
    assert page.js_errors == [], page.js_errors
    assert len(visited) == 3
