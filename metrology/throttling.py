"""Rate limits: API calls per user and per anonymous client, failed log-ins and bad API tokens per client.

Rates are ``"N/period"`` strings (period: second, minute, hour, day) in
``settings.GCPS_THROTTLE_RATES``, read when a request arrives, so they can be changed by the
environment (``GCPS_THROTTLE_USER``, ``GCPS_THROTTLE_ANON``, ``GCPS_THROTTLE_LOGIN``,
``GCPS_THROTTLE_BAD_TOKEN``) and by tests. Counts live in Django's default cache: Redis when
``REDIS_URL`` is set, so every web process shares them; process memory otherwise (the embedded
default runs one process). Counts are atomic (:class:`WindowCounter`: ``add`` then ``incr``), so
parallel requests in any number of processes pass no more than the rate. A window starts at the
first event counted and lasts the rate's period. Exceeding a rate answers 429 with
``Retry-After`` (seconds until the window ends).

- ``user``: API requests of an authenticated user (by user id).
- ``anon``: API requests without valid credentials (by client address), counted before the
  401 too, so an anonymous client cannot probe protected endpoints at full speed.
- ``bad_token``: ``Authorization: Token`` headers that match no user, counted per client address
  and per address and token; past the rate unknown tokens from that address answer 429 (the same
  unknown token again, without being looked up) until the window moves on. Valid tokens are never
  refused by it: one bad client behind a shared address does not lock the others out.
- ``login``: failed log-ins on ``/login/`` and ``/admin/login/`` (by client address, through
  Django's ``user_login_failed`` signal); past the rate the log-in form answers 429.
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable

from django.conf import settings
from django.core.cache import cache
from django.http import HttpRequest, HttpResponse
from rest_framework import exceptions, permissions, throttling
from rest_framework.authentication import TokenAuthentication

LOGIN_PATHS = ("/login/", "/admin/login/")
logger = logging.getLogger(__name__)


class WindowCounter:
    """An atomic count of events per key in a window of ``duration`` seconds that starts at the key's first event.

    ``cache.add`` (Redis ``SET NX EX``) creates the count with its expiry, ``cache.incr`` (Redis
    ``INCRBY``) counts: concurrent requests in any number of processes are each counted once, so no
    more than the limit pass (DRF's ``SimpleRateThrottle`` reads, appends and writes back a list of
    times, and parallel requests overwrite each other's counts). The window's start is kept beside
    the count for ``Retry-After``.
    """

    def __init__(self, key: str, duration: int) -> None:
        self.key = key
        self.duration = duration

    def hit(self) -> int:
        """Count one event now; returns the count in the current window, this one included."""
        cache.add(self.key, 0, self.duration)
        try:
            count = int(cache.incr(self.key))
        except ValueError:  # expired between add and incr: a new window
            cache.add(self.key, 0, self.duration)
            count = int(cache.incr(self.key))
        if count == 1:  # a new window (and, should Redis's INCR have made the key afresh, its expiry)
            cache.touch(self.key, self.duration)
            cache.set(self.key + ":start", time.time(), self.duration)
        return count

    def count(self) -> int:
        """Events counted in the current window (0 when none)."""
        return int(cache.get(self.key, 0))

    def wait_seconds(self) -> float:
        """Seconds until the current window ends (at least 1)."""
        start = cache.get(self.key + ":start")
        if start is None:
            return float(self.duration)
        return max(1.0, self.duration - (time.time() - float(start)))


class SettingsRateMixin(throttling.SimpleRateThrottle):
    """A DRF throttle with the rate of ``scope`` from ``settings.GCPS_THROTTLE_RATES`` and an atomic count.

    The rate is read on every request. A cache that cannot be reached lets the request through
    (logged): rate limiting must not take the API down with it. Listed first among the bases of a
    DRF throttle class.
    """

    # set by SimpleRateThrottle.__init__ from parse_rate(rate): both None when no rate is set
    # (the DRF stubs do not declare them)
    num_requests: int | None
    duration: int | None
    _wait: float | None = None

    def get_rate(self) -> str | None:
        rates = getattr(settings, "GCPS_THROTTLE_RATES", {})
        return rates.get(self.scope)

    def allow_request(self, request, view) -> bool:
        if self.num_requests is None or self.duration is None:
            return True
        key = self.get_cache_key(request, view)
        if key is None:
            return True
        try:
            counter = WindowCounter(key, self.duration)
            if counter.hit() <= self.num_requests:
                return True
            self._wait = counter.wait_seconds()
            return False
        except Exception as exc:  # the cache (Redis) is down
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)
            return True

    def wait(self) -> float | None:
        return self._wait


class UserRateThrottle(SettingsRateMixin, throttling.UserRateThrottle):
    """API requests per authenticated user (anonymous requests are the ``anon`` throttle's)."""

    scope = "user"

    def get_cache_key(self, request, view) -> str | None:
        if not (request.user and request.user.is_authenticated):
            return None
        return self.cache_format % {"scope": self.scope, "ident": request.user.pk}


class AnonRateThrottle(SettingsRateMixin, throttling.AnonRateThrottle):
    """API requests per client address without valid credentials."""

    scope = "anon"


class FailureCounter(SettingsRateMixin, throttling.SimpleRateThrottle):
    """Counts failures (not requests) per client address, or per address and ``detail``;
    :meth:`wait_seconds` tells whether it is blocked."""

    def __init__(self, scope: str, detail: str = "") -> None:
        self.scope = scope
        self.detail = detail
        super().__init__()

    def get_cache_key(self, request, view=None) -> str:
        ident = self.get_ident(request) + (f":{self.detail}" if self.detail else "")
        return self.cache_format % {"scope": self.scope, "ident": ident}

    def _counter(self, request) -> WindowCounter | None:
        if self.num_requests is None or self.duration is None:
            return None
        return WindowCounter(self.get_cache_key(request), self.duration)

    def wait_seconds(self, request) -> float | None:
        """Seconds until the next attempt is allowed, or None when not blocked (or no rate is set)."""
        counter = self._counter(request)
        if counter is None or self.num_requests is None:
            return None
        try:
            if counter.count() < self.num_requests:
                return None
            return counter.wait_seconds()
        except Exception as exc:
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)
            return None

    def record(self, request) -> float | None:
        """Count one failure now; returns the seconds to wait when this failure is past the rate, else None."""
        counter = self._counter(request)
        if counter is None or self.num_requests is None:
            return None
        try:
            if counter.hit() <= self.num_requests:
                return None
            return counter.wait_seconds()
        except Exception as exc:
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)
            return None


class ThrottledTokenAuthentication(TokenAuthentication):
    """Token authentication that refuses (429) unknown tokens from a client past the ``bad_token`` rate.

    Never a valid token: one bad client behind a shared address (a proxy, a NAT) does not lock the
    others out. Two counts, both of failures: per address and token (a client repeating the same
    unknown token past the rate is answered 429 without looking the token up), and per address
    over all unknown tokens (past the rate, unknown tokens answer 429 instead of 401; a valid token
    is looked up and accepted as always).
    """

    def authenticate(self, request):
        header = request.META.get("HTTP_AUTHORIZATION", "")
        parts = header.split()
        if not parts or parts[0].lower() != self.keyword.lower():
            return super().authenticate(request)
        token = FailureCounter("bad_token", hashlib.sha256(header.encode()).hexdigest()[:16])
        address = FailureCounter("bad_token")
        wait = token.wait_seconds(request)
        if wait is not None:
            raise exceptions.Throttled(wait, detail="Too many requests with this invalid API token from this address.")
        try:
            return super().authenticate(request)
        except exceptions.AuthenticationFailed:
            token.record(request)
            wait = address.record(request)
            if wait is not None:
                raise exceptions.Throttled(wait, detail="Too many invalid API tokens from this address.") from None
            raise


class IsAuthenticatedAnonThrottled(permissions.IsAuthenticated):
    """``IsAuthenticated`` that counts a refused anonymous request against the ``anon`` rate first."""

    def has_permission(self, request, view) -> bool:
        if super().has_permission(request, view):
            return True
        throttle = AnonRateThrottle()
        if not throttle.allow_request(request, view):
            raise exceptions.Throttled(throttle.wait())
        return False


def record_login_failure(sender, credentials: dict, request: HttpRequest | None = None, **kwargs) -> None:
    """``user_login_failed`` receiver: count the failure against the client address."""
    if request is not None:
        FailureCounter("login").record(request)


class LoginThrottleMiddleware:
    """429 with ``Retry-After`` for a log-in POST from an address past the ``login`` rate of failures."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        if request.method == "POST" and request.path in LOGIN_PATHS:
            wait = FailureCounter("login").wait_seconds(request)
            if wait is not None:
                seconds = int(wait + 0.999)
                response = HttpResponse(
                    f"Too many failed log-in attempts from this address; try again in {seconds} s.\n",
                    status=429,
                    content_type="text/plain; charset=utf-8",
                )
                response["Retry-After"] = str(seconds)
                return response
        return self.get_response(request)
