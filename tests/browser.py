"""Headless Chromium for the browser tests (Playwright driving Debian's /usr/bin/chromium): how it is
started, and where screenshots go (artifacts/screenshots/, only when ``GCPS_SCREENSHOTS`` is set:
no assertion reads them, and a full-page screenshot costs Chromium a re-layout and a PNG encode of
the whole page). The page fixture is ``browser_page`` in tests/conftest.py."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENSHOTS = Path(__file__).resolve().parents[1] / "artifacts" / "screenshots"
TIMEOUT_MS = 120_000
POLL_MS = 100
"""How often ``page.wait_for_function`` evaluates its predicate: Playwright's default evaluates it on
every animation frame, which keeps Chromium drawing frames for as long as the wait lasts."""


def screenshots_wanted() -> bool:
    """Whether ``shot`` writes its screenshots: set ``GCPS_SCREENSHOTS=1`` to look at the pages."""
    return os.environ.get("GCPS_SCREENSHOTS", "") not in ("", "0")


def shot(page, name: str, settle_ms: int = 0) -> None:
    """A full-page screenshot of ``page`` to artifacts/screenshots/<name>.png, ``settle_ms`` after the
    call (for figures still drawing), when screenshots are wanted (``GCPS_SCREENSHOTS``); otherwise
    nothing."""
    if not screenshots_wanted():
        return
    if settle_ms:
        page.wait_for_timeout(settle_ms)
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / f"{name}.png"), full_page=True)


class SharedBrowser:
    """One headless Chromium that several tests use in turn (each in a browser context of its own).

    Playwright's sync API runs its asyncio loop in a greenlet of this thread and, between its calls,
    leaves that loop marked as the thread's running loop (``asyncio._set_running_loop``; the loop's
    suspended tasks expect the mark when they resume). While the mark is set, Django refuses
    synchronous ORM calls (``SynchronousOnlyOperation``), ``async_to_sync`` refuses to run and
    ``asyncio.run`` raises: a browser kept for the whole session broke later tests of the same
    worker. ``idle`` clears the mark between tests, ``resume`` sets it again before the next
    Playwright call."""

    def __init__(self, browser: Any, loop: asyncio.AbstractEventLoop) -> None:
        self.browser = browser
        self.loop = loop

    def resume(self) -> None:
        asyncio.events._set_running_loop(self.loop)

    def idle(self) -> None:
        asyncio.events._set_running_loop(None)


@contextmanager
def shared_browser(sync_api: ModuleType) -> Iterator[SharedBrowser]:
    """Start Playwright and Chromium (about 1.4 s of CPU), yield them idle (no running loop marked
    in this thread), then close and stop them."""
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        shared = SharedBrowser(browser, asyncio.get_running_loop())
        shared.idle()
        try:
            yield shared
        finally:
            shared.resume()
            browser.close()
    asyncio.events._set_running_loop(None)
