"""The request type of views behind ``login_required``, for the type checker."""

from __future__ import annotations

from django.contrib.auth.models import User
from django.http import HttpRequest


class AuthenticatedHttpRequest(HttpRequest):
    """An ``HttpRequest`` whose user has logged in (views decorated with ``login_required``).

    Only an annotation: Django still passes its own request object; this class tells the type
    checker that ``request.user`` is a ``User``, not an ``AnonymousUser``.
    """

    user: User
