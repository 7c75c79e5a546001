"""Writes for accounts: create a user with an API token."""

from __future__ import annotations

from django.contrib.auth import get_user_model
from django.db import transaction
from rest_framework.authtoken.models import Token


@transaction.atomic
def create_user_with_token(*, username: str, email: str = "", password: str | None = None) -> tuple[object, str]:
    """Create ``username`` (unusable password unless given) and its API token; returns (user, key)."""
    user_model = get_user_model()
    if user_model.objects.filter(username=username).exists():
        raise ValueError(f"user {username!r} already exists")
    user = user_model.objects.create_user(username=username, email=email, password=password)
    token = Token.objects.create(user=user)
    return user, token.key
