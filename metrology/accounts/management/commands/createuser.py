"""``python manage.py createuser NAME``: create a user and print its 40-hex-character API token."""

from __future__ import annotations

from django.core.exceptions import ValidationError
from django.core.management.base import BaseCommand, CommandError
from django.core.validators import validate_email

from metrology.accounts.services import create_user_with_token


class Command(BaseCommand):
    help = "Create a user and print its API token (use it as 'Authorization: Token <key>')."

    def add_arguments(self, parser) -> None:
        parser.add_argument("username")
        parser.add_argument("--email", default="")
        parser.add_argument("--password", default=None, help="Also set a password (for the admin and dashboard)")

    def handle(self, *args, username: str, email: str, password: str | None, **options) -> None:
        if not username.strip() or len(username) > 150:
            raise CommandError("username must be 1-150 characters")
        if email:
            try:
                validate_email(email)
            except ValidationError:
                raise CommandError(f"--email {email!r} is not an email address") from None
        try:
            _user, key = create_user_with_token(username=username, email=email, password=password)
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        self.stdout.write(key)
