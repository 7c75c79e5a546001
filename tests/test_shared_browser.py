"""The module's Chromium (``module_browser`` in tests/conftest.py) leaves no event loop marked running
between tests: a test of the same module that runs while the browser is started (pytest may order
it before or after the page tests) can use the ORM, ``async_to_sync`` and ``asyncio.run``, and a
browser test after ``asyncio.run`` still drives its page.

Playwright's sync API marks its loop as the thread's running loop between its calls; a browser kept
across tests without clearing that mark made Django raise ``SynchronousOnlyOperation`` and
``async_to_sync`` refuse to run in the tests after it."""

from __future__ import annotations

import asyncio
import os

import pytest
from asgiref.sync import async_to_sync

from tests.browser import CHROMIUM

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


def test_a_page_computes(browser_page):
    browser_page.set_content("<p id=sum></p><script>document.getElementById('sum').textContent = 6 * 7;</script>")
    assert browser_page.locator("#sum").inner_text() == "42"


@pytest.mark.django_db
def test_after_a_browser_test_no_loop_is_running_and_async_code_runs(module_browser, alice):
    from django.contrib.auth import get_user_model

    assert module_browser.browser.is_connected()  # the browser of the test before is still started
    with pytest.raises(RuntimeError):
        asyncio.get_running_loop()
    assert get_user_model().objects.get(pk=alice.pk).username == "alice"  # no SynchronousOnlyOperation

    async def double(value: int) -> int:
        await asyncio.sleep(0)
        return 2 * value

    assert async_to_sync(double)(21) == 42
    assert asyncio.run(double(4)) == 8


def test_a_page_computes_after_async_code(browser_page):
    browser_page.set_content("<p id=p></p><script>document.getElementById('p').textContent = 6 * 9;</script>")
    assert browser_page.locator("#p").inner_text() == "54"
