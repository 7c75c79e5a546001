"""Settings for the whole test suite: rate limits raised so that no test is throttled by accident.

The tests of the rate limits themselves (tests/app/test_throttling.py) lower them again.
"""

from __future__ import annotations

import pytest

#: Far above anything a test does (the suite's fastest loops make a few hundred requests).
RAISED_RATE = "1000000/hour"


@pytest.fixture(autouse=True)
def raised_throttle_rates(settings) -> None:
    settings.GCPS_THROTTLE_RATES = dict.fromkeys(settings.GCPS_THROTTLE_RATES, RAISED_RATE)
