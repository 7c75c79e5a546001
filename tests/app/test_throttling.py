"""Rate limits (issue 9 item 7): 429 with Retry-After past the configured number of API calls per
user and per anonymous client, of failed log-ins and of unknown API tokens; rates from the settings."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from django.core.cache import cache
from django.test import Client
from rest_framework.test import APIClient

from metrology.accounts.services import create_user_with_token
from tests.conftest import PASSWORD, RAISED_RATE

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def empty_cache(settings):
    assert "locmem" in settings.CACHES["default"]["BACKEND"].lower(), "these tests clear the cache"
    cache.clear()
    yield
    if "locmem" in settings.CACHES["default"]["BACKEND"].lower():  # not the unreachable one of a test
        cache.clear()


def rates(settings, **changes: str) -> None:
    settings.GCPS_THROTTLE_RATES = {**settings.GCPS_THROTTLE_RATES, **changes}


def assert_throttled(response) -> int:
    assert response.status_code == 429, response.content
    retry_after = int(response["Retry-After"])
    assert 1 <= retry_after <= 60, retry_after
    return retry_after


def test_production_defaults_are_limits_and_the_suite_raises_them():
    from metrology import settings as module

    assert module.GCPS_THROTTLE_RATES == {
        "user": "1200/minute",
        "anon": "60/minute",
        "login": "10/minute",
        "bad_token": "20/minute",
    }
    from django.conf import settings

    assert set(settings.GCPS_THROTTLE_RATES.values()) == {RAISED_RATE}


def test_user_calls_past_the_rate_get_429_with_retry_after(settings, api, other_api):
    rates(settings, user="5/minute")
    for _ in range(5):
        assert api.get("/api/rigs/").status_code == 200
    response = api.get("/api/rigs/")
    assert_throttled(response)
    assert "throttled" in response.json()["error"].lower()
    assert other_api.get("/api/rigs/").status_code == 200  # per user


def test_anonymous_calls_past_the_rate_get_429(settings, db):
    rates(settings, anon="3/minute")
    client = APIClient(REMOTE_ADDR="10.0.0.7")
    for _ in range(3):
        assert client.get("/api/rigs/").status_code in (401, 403)
    assert_throttled(client.get("/api/rigs/"))
    assert_throttled(client.get("/api/schema/"))
    assert APIClient(REMOTE_ADDR="10.0.0.8").get("/api/rigs/").status_code in (401, 403)  # per address


def test_hundred_guessed_tokens_are_throttled(settings, user_and_token):
    rates(settings, bad_token="20/minute")
    guesser = APIClient(REMOTE_ADDR="10.0.0.9")
    codes = []
    for guess in range(100):
        guesser.credentials(HTTP_AUTHORIZATION=f"Token {guess:040x}")
        codes.append(guesser.get("/api/rigs/").status_code)
    assert codes.count(401) == 20 and codes.count(429) == 80, codes
    # a valid token from that address (someone else behind the same proxy) is not locked out ...
    colleague = APIClient(REMOTE_ADDR="10.0.0.9")
    colleague.credentials(HTTP_AUTHORIZATION=f"Token {user_and_token[1]}")
    assert colleague.get("/api/rigs/").status_code == 200
    # ... nor the owner elsewhere
    owner = APIClient(REMOTE_ADDR="10.0.0.10")
    owner.credentials(HTTP_AUTHORIZATION=f"Token {user_and_token[1]}")
    assert owner.get("/api/rigs/").status_code == 200


def test_one_unknown_token_repeated_is_refused_and_valid_tokens_from_that_address_still_work(settings, user_and_token):
    rates(settings, bad_token="5/minute")
    stale = APIClient(REMOTE_ADDR="10.0.0.15")
    stale.credentials(HTTP_AUTHORIZATION="Token " + "ab" * 20)
    codes = [stale.get("/api/rigs/").status_code for _ in range(8)]
    assert codes == [401] * 5 + [429] * 3, codes
    assert_throttled(stale.get("/api/rigs/"))
    valid = APIClient(REMOTE_ADDR="10.0.0.15")
    valid.credentials(HTTP_AUTHORIZATION=f"Token {user_and_token[1]}")
    assert [valid.get("/api/rigs/").status_code for _ in range(10)] == [200] * 10


def test_forged_forwarded_for_does_not_escape_the_limit(settings, db):
    rates(settings, bad_token="3/minute")
    codes = []
    for guess in range(6):
        client = APIClient(REMOTE_ADDR="10.0.0.20", HTTP_X_FORWARDED_FOR=f"192.0.2.{guess}")
        client.credentials(HTTP_AUTHORIZATION=f"Token {guess:040x}")
        codes.append(client.get("/api/rigs/").status_code)
    assert codes == [401, 401, 401, 429, 429, 429], codes


@pytest.mark.parametrize("path", ["/login/", "/admin/login/"])
def test_failed_logins_past_the_rate_get_429(settings, db, path):
    rates(settings, login="5/minute")
    user, _key = create_user_with_token(username="carol", password=PASSWORD)
    user.is_staff = True
    user.save()
    client = Client(REMOTE_ADDR="10.0.0.11")
    for attempt in range(5):
        response = client.post(path, {"username": "carol", "password": f"wrong-{attempt}"})
        assert response.status_code == 200, response.status_code  # the form again, with its error
    assert_throttled(client.post(path, {"username": "carol", "password": "wrong-again"}))
    assert_throttled(client.post(path, {"username": "carol", "password": PASSWORD}))
    elsewhere = Client(REMOTE_ADDR="10.0.0.12")
    assert elsewhere.post(path, {"username": "carol", "password": PASSWORD}).status_code == 302


def test_successful_logins_are_not_counted(settings, db):
    rates(settings, login="2/minute")
    create_user_with_token(username="dave", password=PASSWORD)
    client = Client(REMOTE_ADDR="10.0.0.13")
    for _ in range(5):
        assert client.post("/login/", {"username": "dave", "password": PASSWORD}).status_code == 302
        client.logout()


def test_bad_rate_in_the_environment_fails_at_start_up(tmp_path):
    env = {key: value for key, value in os.environ.items() if not key.startswith(("GCPS", "REDIS", "DATABASE"))}
    result = subprocess.run(
        [sys.executable, "-c", "import django; django.setup()"],
        cwd=ROOT,
        env={
            **env,
            "DJANGO_SETTINGS_MODULE": "metrology.settings",
            "GCPS_VAR_DIR": str(tmp_path),
            "GCPS_THROTTLE_USER": "lots",
        },
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode != 0
    assert "GCPS_THROTTLE_USER must look like 100/minute" in result.stderr


CROSS_PROCESS = """
import django
django.setup()
from django.test import Client
client = Client(REMOTE_ADDR="10.0.0.99")
print(" ".join(str(client.get("/api/rigs/").status_code) for _ in range({count})))
"""


@pytest.mark.integration
def test_rate_is_shared_by_processes_through_redis(tmp_path):
    """Two web processes on the real stack (Redis cache) share one count: 4 calls each, rate 6."""
    env = {key: value for key, value in os.environ.items() if not key.startswith(("GCPS", "DATABASE"))}
    env.update(
        DJANGO_SETTINGS_MODULE="metrology.settings",
        GCPS_VAR_DIR=str(tmp_path),
        REDIS_URL="redis://127.0.0.1:6379/0",
        GCPS_CACHE_KEY_PREFIX=f"gcps-test-{uuid.uuid4().hex}",
        GCPS_THROTTLE_ANON="6/minute",
        DEBUG="1",
        ALLOWED_HOSTS="testserver",
    )
    codes = []
    for _process in range(2):
        result = subprocess.run(
            [sys.executable, "-c", CROSS_PROCESS.format(count=4)],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 0, result.stderr[-3000:]
        codes += result.stdout.split()
    assert codes[:6] == ["401"] * 6 and codes[6:] == ["429"] * 2, codes


def test_an_unreachable_cache_does_not_take_the_api_down(settings, api, caplog):
    """Rate limiting fails open: with the cache (Redis) down the API answers, and says so in the log."""
    import socket

    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    settings.CACHES = {
        "default": {"BACKEND": "django.core.cache.backends.redis.RedisCache", "LOCATION": f"redis://127.0.0.1:{port}/0"}
    }
    rates(settings, user="5/minute", bad_token="5/minute")
    assert api.get("/api/rigs/").status_code == 200
    guesser = APIClient(REMOTE_ADDR="10.0.0.30")
    guesser.credentials(HTTP_AUTHORIZATION="Token " + "1" * 40)
    assert guesser.get("/api/rigs/").status_code == 401
    assert "cache unavailable" in caplog.text
