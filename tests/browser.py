"""Headless Chromium for the browser tests (Playwright driving Debian's /usr/bin/chromium): how it is
started, and where screenshots go (artifacts/screenshots/, only when ``GCPS_SCREENSHOTS`` is set:
no assertion reads them, and a full-page screenshot costs Chromium a re-layout and a PNG encode of
the whole page). The page fixture is ``browser_page`` in tests/conftest.py."""

from __future__ import annotations

import os
from pathlib import Path

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


def shot(page, name: str) -> None:
    """A full-page screenshot of ``page`` to artifacts/screenshots/<name>.png when screenshots are
    wanted (``GCPS_SCREENSHOTS``); otherwise nothing."""
    if not screenshots_wanted():
        return
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / f"{name}.png"), full_page=True)

