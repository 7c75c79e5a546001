"""Writes for accounts: create a user with an API token (optionally staff or superuser)."""

from __future__ import annotations

from django.contrib.auth import get_user_model
from django.contrib.auth.models import Permission
from django.db import transaction
from rest_framework.authtoken.models import Token

#: Apps whose models a staff user may edit in the admin: the report schedules (django-celery-beat's
#: periodic tasks and their crontabs/intervals) and the reports themselves.
STAFF_APPS: tuple[str, ...] = ("django_celery_beat", "reports")


@transaction.atomic
def create_user_with_token(
    *,
    username: str,
    email: str = "",
    password: str | None = None,
    staff: bool = False,
    superuser: bool = False,
) -> tuple[object, str]:
    """Create ``username`` (unusable password unless given) and its API token; returns (user, key).

    ``staff`` lets the user log in to the admin at /admin/ and edit the report schedules
    (every permission of :data:`STAFF_APPS`); ``superuser`` gives every permission. Both need a
    password, since the admin logs in with one.
    """
    user_model = get_user_model()
    if user_model.objects.filter(username=username).exists():
        raise ValueError(f"user {username!r} already exists")
    if (staff or superuser) and not password:
        raise ValueError("a staff user or superuser needs a password (the admin logs in with one)")
    user = user_model.objects.create_user(
        username=username, email=email, password=password, is_staff=staff or superuser, is_superuser=superuser
    )
    if staff and not superuser:
        user.user_permissions.set(Permission.objects.filter(content_type__app_label__in=STAFF_APPS))
    token = Token.objects.create(user=user)
    return user, token.key
