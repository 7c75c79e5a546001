"""Errors answer as JSON ``{"error": "<what is wrong and what to do>"}`` (plus ``fields`` for forms).

DRF's own errors (validation, authentication, 404, throttling) are reshaped here so that every
error the API returns has the same shape; services raise :class:`ApiError` subclasses or plain
DRF ``ValidationError``.
"""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from rest_framework import exceptions, status
from rest_framework.response import Response
from rest_framework.views import exception_handler as drf_exception_handler


class BadInput(exceptions.APIException):
    """400: the request is understood but its content is refused; ``detail`` says why."""

    status_code = status.HTTP_400_BAD_REQUEST
    default_detail = "The request was refused."
    default_code = "bad_input"


#: What services raise for refused input: DRF errors (``BadInput``, ``ValidationError``), Django's
#: model ``ValidationError`` and ``ValueError`` from the measurement core.
SERVICE_ERRORS = (exceptions.APIException, ValueError, DjangoValidationError)


def error_sentence(exc: Exception) -> str:
    """One of :data:`SERVICE_ERRORS` as one sentence for a page or an enclosing error."""
    if isinstance(exc, exceptions.APIException):
        detail = exc.detail
        if isinstance(detail, dict):
            return "; ".join(f"{key}: {' '.join(map(str, value))}" for key, value in detail.items())
        if isinstance(detail, list):
            return " ".join(map(str, detail))
        return str(detail)
    if isinstance(exc, DjangoValidationError):
        return " ".join(exc.messages)
    return str(exc)


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
