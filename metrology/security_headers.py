"""The Content-Security-Policy header of every response (``GCPS_CONTENT_SECURITY_POLICY``).

The default (metrology/settings.py) allows only this site's own scripts, styles, images, fonts and connections:
plotly.js and the Swagger UI are served locally. ``'unsafe-inline'`` remains for scripts and styles
because the pages carry one inline script (figures, progress bars) and plotly.js sets inline
styles, and the self-contained HTML reports inline plotly.js itself; no other origin can load
anything into the pages, and no page can be framed by another site.
"""

from __future__ import annotations

from collections.abc import Callable

from django.conf import settings
from django.http import HttpRequest, HttpResponse


class ContentSecurityPolicyMiddleware:
    """Adds ``settings.GCPS_CONTENT_SECURITY_POLICY`` to responses that do not set their own."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        response = self.get_response(request)
        policy = settings.GCPS_CONTENT_SECURITY_POLICY
        if policy and "Content-Security-Policy" not in response:
            response["Content-Security-Policy"] = policy
        return response
