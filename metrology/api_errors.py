"""Errors answer as JSON ``{"error": "<what is wrong and what to do>"}`` (plus ``fields`` for forms).

DRF's own errors (validation, authentication, 404, throttling) are reshaped here so that every
error the API returns has the same shape. The services raise the domain errors of
:mod:`metrology.errors` and know nothing of HTTP: :class:`~metrology.errors.BadInput` answers 400
and :class:`~metrology.errors.Conflict` 409, each with its sentence as ``error``.
"""

from __future__ import annotations

from typing import Any

from rest_framework import exceptions, status
from rest_framework.response import Response
from rest_framework.views import exception_handler as drf_exception_handler

from metrology.errors import BadInput, Conflict, DomainError

# BadInput stays importable from here, where it was defined before metrology.errors.
__all__ = ["BadInput", "bad_request", "exception_handler", "not_found", "server_error"]


def _api_exception(exc: DomainError) -> exceptions.APIException:
    """The DRF error answering a domain error: 409 for a :class:`Conflict`, else 400; its sentence."""
    if isinstance(exc, Conflict):
        answer = exceptions.APIException(detail=str(exc), code="conflict")
        answer.status_code = status.HTTP_409_CONFLICT
    else:
        answer = exceptions.APIException(detail=str(exc), code="bad_input")
        answer.status_code = status.HTTP_400_BAD_REQUEST
    return answer


def _flatten(detail: Any, prefix: str = "") -> list[str]:
    if isinstance(detail, dict):
        messages: list[str] = []
        for key, value in detail.items():
            name = key if key != "non_field_errors" else ""
            messages += _flatten(value, f"{prefix}{name}" if not prefix else f"{prefix}.{name}")
        return messages
    if isinstance(detail, list):
        messages = []
        for index, item in enumerate(detail):
            sub = prefix if not isinstance(item, dict | list) else f"{prefix}[{index}]"
            messages += _flatten(item, sub)
        return messages
    text = str(detail)
    return [f"{prefix}: {text}" if prefix else text]


def exception_handler(exc: Exception, context: dict) -> Response | None:
    if isinstance(exc, DomainError):
        exc = _api_exception(exc)
    response = drf_exception_handler(exc, context)
    if response is None:
        return None
    detail = getattr(exc, "detail", None)
    if isinstance(exc, exceptions.ValidationError) and isinstance(detail, dict | list):
        body: dict[str, Any] = {"error": "; ".join(_flatten(detail)) or "Invalid input."}
        if isinstance(detail, dict):
            body["fields"] = response.data
    elif isinstance(response.data, dict) and "detail" in response.data:
        body = {"error": str(response.data["detail"])}
    else:
        body = {"error": "; ".join(_flatten(response.data))}
    response.data = body
    return response


def bad_request(request, exception=None):
    """400 outside any API view (e.g. a body over DATA_UPLOAD_MAX_MEMORY_SIZE): JSON under /api/."""
    from django.http import JsonResponse
    from django.views.defaults import bad_request as default_bad_request

    if request.path.startswith("/api/"):
        return JsonResponse({"error": f"Bad request: {exception or 'the request could not be read'}."}, status=400)
    return default_bad_request(request, exception)


def not_found(request, exception=None):
    """404 outside any API view: JSON under /api/, Django's page elsewhere."""
    from django.http import JsonResponse
    from django.views.defaults import page_not_found

    if request.path.startswith("/api/"):
        return JsonResponse({"error": f"No API endpoint at {request.path}; see /api/docs/."}, status=404)
    return page_not_found(request, exception)


def server_error(request):
    """500: JSON under /api/ (the details are in the server log), Django's page elsewhere."""
    from django.http import JsonResponse
    from django.views.defaults import server_error as default_server_error

    if request.path.startswith("/api/"):
        return JsonResponse({"error": "Internal server error; it has been logged."}, status=500)
    return default_server_error(request)
