"""When the database or the broker is briefly unreachable: retry once, then answer 503, never 500.

- :class:`ServiceUnavailableError` is what a service raises when a dependency is down (the broker
  when a job is created): the request answers ``503`` with ``Retry-After`` and a sentence
  (``{"error": ...}`` under ``/api/``).
- :class:`TransientErrorMiddleware` retries a request once when the database connection failed
  inside it (``OperationalError``/``InterfaceError``: a terminated backend, a restarted server),
  after closing the broken connection; a second failure answers 503 as above. A request is retried
  only when the failed attempt wrote nothing to the database and its body can be read again (no
  half-done work is repeated). Connections that died while idle between requests are caught
  before use by ``CONN_HEALTH_CHECKS`` (settings).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from weakref import WeakKeyDictionary

from django.conf import settings
from django.db import InterfaceError, OperationalError, connections
from django.http import HttpRequest, HttpResponse, JsonResponse

logger = logging.getLogger(__name__)

DATABASE_ERRORS = (OperationalError, InterfaceError)
WRITE_STATEMENTS = ("INSERT", "UPDATE", "DELETE")


class ServiceUnavailableError(Exception):
    """A dependency (database, broker) is unreachable; ``str(exc)`` says which, for a person."""

    def __init__(self, message: str, retry_after_s: int = 10) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


def unavailable_response(request: HttpRequest, message: str, retry_after_s: int) -> HttpResponse:
    """503 with ``Retry-After``: JSON ``{"error": message}`` under /api/, a short page elsewhere."""
    response: HttpResponse
    if request.path.startswith("/api/"):
        response = JsonResponse({"error": message}, status=503)
    else:
        response = HttpResponse(
            f"<!doctype html><title>Service unavailable</title><h1>Service unavailable</h1><p>{_escape(message)}</p>",
            status=503,
        )
    response["Retry-After"] = str(int(retry_after_s))
    return response


def _escape(text: str) -> str:
    from django.utils.html import escape

    return escape(text)


class _WriteRecorder:
    """A database execute wrapper noting whether any INSERT/UPDATE/DELETE succeeded."""

    def __init__(self) -> None:
        self.wrote = False

    def __call__(self, execute: Callable[..., Any], sql: str, params: Any, many: bool, context: Any) -> Any:
        result = execute(sql, params, many, context)
        if sql.lstrip()[:6].upper() in WRITE_STATEMENTS:
            self.wrote = True
        return result


def _close_broken_connections() -> None:
    for connection in connections.all(initialized_only=True):
        if connection.in_atomic_block:
            continue
        with contextlib.suppress(*DATABASE_ERRORS):
            connection.close()


def _body_can_be_replayed(request: HttpRequest) -> bool:
    return not getattr(request, "_read_started", False) or hasattr(request, "_body")


def _keep_body(request: HttpRequest) -> None:
    """Read a small non-multipart body into memory now, so that a retry can parse it again."""
    if request.method in ("GET", "HEAD", "OPTIONS") or (request.content_type or "").startswith("multipart/"):
        return
    try:
        length = int(request.META.get("CONTENT_LENGTH") or 0)
    except ValueError:
        return
    limit = settings.DATA_UPLOAD_MAX_MEMORY_SIZE
    if length > 0 and (limit is None or length <= limit):
        with contextlib.suppress(OSError):  # a client gone mid-body: the view meets the same error
            _ = request.body


@dataclass
class _Attempts:
    """A request's attempts so far: the database error the last one met (None: none), and whether it is the retry."""

    database_error: BaseException | None = None
    retry: bool = False


#: The attempts of each request in progress (an entry goes with its request).
_attempts: WeakKeyDictionary[HttpRequest, _Attempts] = WeakKeyDictionary()


class TransientErrorMiddleware:
    """Retry once on a lost database connection; 503 (not 500) when the database or broker stays away."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        _keep_body(request)
        attempts = _attempts.setdefault(request, _Attempts())
        recorder = _WriteRecorder()
        with connections["default"].execute_wrapper(recorder):
            response = self.get_response(request)
        error = attempts.database_error
        if error is None:
            return response
        _close_broken_connections()
        if recorder.wrote or not _body_can_be_replayed(request):
            logger.warning(
                "database error in %s %s; not retried (it wrote, or read its body)", request.method, request.path
            )
            return response
        logger.warning("database error in %s %s (%s); retrying once", request.method, request.path, error)
        attempts.database_error = None
        attempts.retry = True
        response = self.get_response(request)
        if attempts.database_error is not None:
            _close_broken_connections()
        return response

    def process_exception(self, request: HttpRequest, exception: Exception) -> HttpResponse | None:
        if isinstance(exception, ServiceUnavailableError):
            logger.warning("%s %s: %s", request.method, request.path, exception)
            return unavailable_response(request, str(exception), exception.retry_after_s)
        if isinstance(exception, DATABASE_ERRORS):
            attempts = _attempts.setdefault(request, _Attempts())
            attempts.database_error = exception
            if attempts.retry:
                logger.error("database error in %s %s after a retry", request.method, request.path, exc_info=exception)
            return unavailable_response(request, "The database is unreachable; try again in a few seconds.", 5)
        return None
