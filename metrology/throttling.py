"""Rate limits: API calls per user and per anonymous client, failed log-ins and bad API tokens per client.

Rates are ``"N/period"`` strings (period: second, minute, hour, day) in
``settings.GCPS_THROTTLE_RATES``, read when a request arrives, so they can be changed by the
environment (``GCPS_THROTTLE_USER``, ``GCPS_THROTTLE_ANON``, ``GCPS_THROTTLE_LOGIN``,
``GCPS_THROTTLE_BAD_TOKEN``) and by tests. Counts live in Django's default cache: Redis when
``REDIS_URL`` is set, so every web process shares them; process memory otherwise (the embedded
default runs one process). Exceeding a rate answers 429 with ``Retry-After`` (seconds).

- ``user``: API requests of an authenticated user (by user id).
- ``anon``: API requests without valid credentials (by client address), counted before the
  401 too, so an anonymous client cannot probe protected endpoints at full speed.
- ``bad_token``: ``Authorization: Token`` headers that match no user (by client address); past the
  rate every token from that client is refused with 429 until the window moves on.
- ``login``: failed log-ins on ``/login/`` and ``/admin/login/`` (by client address, through
  Django's ``user_login_failed`` signal); past the rate the log-in form answers 429.
"""

from __future__ import annotations

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


class SettingsRateMixin(throttling.SimpleRateThrottle):
    """Reads the rate of ``scope`` from ``settings.GCPS_THROTTLE_RATES`` on every request.

    A cache that cannot be reached lets the request through (logged): rate limiting must not
    take the API down with it. Listed first among the bases of a DRF throttle class.
    """

    def get_rate(self) -> str | None:
        rates = getattr(settings, "GCPS_THROTTLE_RATES", {})
        return rates.get(self.scope)

    def allow_request(self, request, view) -> bool:
        try:
            return super().allow_request(request, view)
        except Exception as exc:  # the cache (Redis) is down
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)
            return True


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
    """Counts failures (not requests) per client address; :meth:`wait_seconds` tells whether it is blocked.

    ``history`` in the cache is the list of failure times (newest first) within the rate's window.
    """

    # set by SimpleRateThrottle.__init__ from parse_rate(rate): both None when no rate is set
    # (the DRF stubs do not declare them)
    num_requests: int | None
    duration: int | None

    def __init__(self, scope: str) -> None:
        self.scope = scope
        super().__init__()

    def get_cache_key(self, request, view=None) -> str:
        return self.cache_format % {"scope": self.scope, "ident": self.get_ident(request)}

    def _history(self, request, duration: int) -> tuple[str, list[float], float]:
        key = self.get_cache_key(request)
        now = time.time()
        history = [moment for moment in cache.get(key, []) if moment > now - duration]
        return key, history, now

    def wait_seconds(self, request) -> float | None:
        """Seconds until the next attempt is allowed, or None when not blocked (or no rate is set)."""
        if self.num_requests is None or self.duration is None:
            return None
        try:
            _key, history, now = self._history(request, self.duration)
        except Exception as exc:
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)
            return None
        if len(history) < self.num_requests:
            return None
        return max(1.0, self.duration - (now - history[-1]))

    def record(self, request) -> None:
        """Count one failure now."""
        if self.num_requests is None or self.duration is None:
            return
        try:
            key, history, now = self._history(request, self.duration)
            cache.set(key, [now, *history][: self.num_requests + 1], self.duration)
        except Exception as exc:
            logger.warning("rate limit %s not applied: cache unavailable (%s)", self.scope, exc)


class ThrottledTokenAuthentication(TokenAuthentication):
    """Token authentication that counts unknown tokens per client and refuses (429) past the ``bad_token`` rate."""

    def authenticate(self, request):
        counter = FailureCounter("bad_token")
        has_token = request.META.get("HTTP_AUTHORIZATION", "").split(" ", 1)[0].lower() == self.keyword.lower()
        if has_token:
            wait = counter.wait_seconds(request)
            if wait is not None:
                raise exceptions.Throttled(wait, detail="Too many invalid API tokens from this address.")
        try:
            return super().authenticate(request)
        except exceptions.AuthenticationFailed:
            if has_token:
                counter.record(request)
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
