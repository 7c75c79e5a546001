"""What the API accepts as a request body: bounded size, bounded JSON nesting, numbers that are numbers.

- :class:`RequestBodyLimitMiddleware` answers 413 JSON under ``/api/`` before a body larger than
  its limit is read: ``DATA_UPLOAD_MAX_MEMORY_SIZE`` for JSON and forms, ``GCPS_MAX_UPLOAD_BYTES``
  (plus room for the form's other fields) for multipart uploads.
- :class:`BoundedJSONParser` reads at most ``DATA_UPLOAD_MAX_MEMORY_SIZE`` bytes (bodies sent
  without a length too) and refuses JSON nested deeper than :data:`MAX_JSON_DEPTH` levels, or so
  deep that Python's parser gives up, with a 400 instead of a ``RecursionError``; NUL
  characters in strings (PostgreSQL refuses them: a 500 at the first write otherwise); and
  numbers that are not finite (``1e400`` and ``-1e400``, which Python's parser reads as
  infinities, and the non-standard ``NaN``/``Infinity``/``-Infinity``), naming the key by its
  JSON path (``extra.a.b``, ``codec.axes.u.phase[0].period``); the checks themselves are
  :mod:`metrology.json_input`'s, which the pages' JSON fields use too.
- :class:`RealNumberField` is DRF's ``FloatField`` without ``true``/``false`` (``float(True)`` is 1.0).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

from django.conf import settings
from django.http import HttpRequest, HttpResponse, JsonResponse
from rest_framework import exceptions, serializers, status
from rest_framework.parsers import JSONParser

from metrology.json_input import MAX_JSON_DEPTH, json_problem, load_json_text

# json_problem, load_json_text and MAX_JSON_DEPTH (metrology/json_input.py, free of DRF so that the
# forms use them too) stay importable from here.
__all__ = [
    "MAX_JSON_DEPTH",
    "MULTIPART_OVERHEAD_BYTES",
    "BoundedJSONParser",
    "PayloadTooLarge",
    "RealNumberField",
    "RequestBodyLimitMiddleware",
    "body_limit",
    "json_problem",
    "load_json_text",
    "too_large_message",
]

if TYPE_CHECKING:
    from django_stubs_ext import StrOrPromise

#: Room for a multipart upload's other fields and boundaries, bytes.
MULTIPART_OVERHEAD_BYTES = 64 * 1024


class PayloadTooLarge(exceptions.APIException):
    """413: the request body is larger than the limit."""

    status_code = status.HTTP_413_REQUEST_ENTITY_TOO_LARGE
    default_detail = "The request body is too large."
    default_code = "payload_too_large"


def body_limit(content_type: str) -> tuple[int, str]:
    """Largest accepted body for ``content_type``, bytes, and the setting that sets it."""
    if content_type.lower().startswith("multipart/"):
        return settings.GCPS_MAX_UPLOAD_BYTES + MULTIPART_OVERHEAD_BYTES, "GCPS_MAX_UPLOAD_BYTES"
    return settings.DATA_UPLOAD_MAX_MEMORY_SIZE, "DATA_UPLOAD_MAX_MEMORY_SIZE"


def too_large_message(size: int | str, limit: int, setting: str) -> str:
    return f"request body of {size} bytes is larger than the limit of {limit} bytes ({setting})"


class RequestBodyLimitMiddleware:
    """413 JSON under ``/api/`` for a declared ``Content-Length`` above :func:`body_limit`."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        if request.path.startswith("/api/"):
            try:
                length = int(request.META.get("CONTENT_LENGTH") or 0)
            except ValueError:
                return JsonResponse({"error": "Content-Length is not a number of bytes."}, status=400)
            limit, setting = body_limit(request.META.get("CONTENT_TYPE", ""))
            if length > limit:
                return JsonResponse({"error": too_large_message(length, limit, setting)}, status=413)
        return self.get_response(request)


class BoundedJSONParser(JSONParser):
    """DRF's JSON parser with a size bound and a nesting bound (400, never a RecursionError), no NUL
    characters and only finite numbers (400 naming the key's JSON path)."""

    def parse(self, stream, media_type=None, parser_context=None):
        parser_context = parser_context or {}
        encoding = parser_context.get("encoding", settings.DEFAULT_CHARSET)
        limit, setting = body_limit("application/json")
        data = stream.read(limit + 1) if stream is not None else b""
        if len(data) > limit:
            raise PayloadTooLarge(too_large_message(f"more than {limit}", limit, setting))
        try:
            text = data.decode(encoding)
            # NaN/Infinity are read as floats so that the check below names their key (as 1e400's).
            value = json.loads(text, parse_constant=float)
        except RecursionError:
            raise exceptions.ParseError(f"JSON parse error - nested deeper than {MAX_JSON_DEPTH} levels") from None
        except ValueError as exc:
            raise exceptions.ParseError(f"JSON parse error - {exc}") from None
        problem = json_problem(value, MAX_JSON_DEPTH)
        if problem:
            raise exceptions.ParseError(f"JSON refused - {problem}")
        return value


class RealNumberField(serializers.FloatField):
    """A finite real number; ``true``/``false`` are refused (they are not numbers)."""

    default_error_messages: ClassVar[dict[str, StrOrPromise]] = {"boolean": "A number is required, not true or false."}

    def to_internal_value(self, data: Any) -> float:
        if isinstance(data, bool):
            self.fail("boolean")
        return super().to_internal_value(data)
