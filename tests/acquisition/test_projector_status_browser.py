"""The projector page says "connected" as soon as the server answers, also while idle (no pattern
asked for: the long-poll's first question is answered at once), and draws it on its test pattern."""

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


def test_an_idle_projector_page_says_connected(live_server, transactional_db, alice, rig, browser_page):
    page = browser_page
    log_in(page, live_server.url)
    page.goto(f"{live_server.url}/rigs/{rig.pk}/projector/")
    # well before the long-poll's 20 s: the first question is answered at once
    page.wait_for_function(
        "() => document.getElementById('projector').dataset.status === 'connected'", timeout=8000, polling=POLL_MS
    )
    page.wait_for_timeout(300)  # the test pattern redrawn with the new status
    shot(page, "projector-idle-connected")
    assert page.js_errors == []
