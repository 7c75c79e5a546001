"""Settings and fixtures for the whole test suite: rate limits raised so that no test is throttled by
accident, and the headless-Chromium page of the browser tests.

The tests of the rate limits themselves (tests/app/test_throttling.py) lower them again.
"""

from __future__ import annotations

import pytest

from tests.browser import CHROMIUM, CHROMIUM_ARGS, TIMEOUT_MS

#: Far above anything a test does (the suite's fastest loops make a few hundred requests).
RAISED_RATE = "1000000/hour"


@pytest.fixture(autouse=True)
def raised_throttle_rates(settings) -> None:
    settings.GCPS_THROTTLE_RATES = dict.fromkeys(settings.GCPS_THROTTLE_RATES, RAISED_RATE)


@pytest.fixture
def browser_page():
    """A page of headless Chromium (1280 x 900) that collects the page's JavaScript errors in ``js_errors``."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
        page = context.new_page()
        page.set_default_timeout(TIMEOUT_MS)
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.js_errors = errors
        yield page
        context.close()
        browser.close()
