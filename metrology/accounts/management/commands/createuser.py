"""``python manage.py createuser NAME``: create a user and print its 40-hex-character API token.

``--staff`` makes a user who logs in to the admin (/admin/) to edit report schedules,
``--superuser`` one with every permission; both need a password (``--password``, or typed at the
prompt when run in a terminal).
"""

from __future__ import annotations

import getpass
import sys

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
        parser.add_argument(
            "--staff", action="store_true", help="May log in to the admin (/admin/) and edit the report schedules"
        )
        parser.add_argument("--superuser", action="store_true", help="Every permission in the admin")

    def handle(
        self, *args, username: str, email: str, password: str | None, staff: bool, superuser: bool, **options
    ) -> None:
        if not username.strip() or len(username) > 150:
            raise CommandError("username must be 1-150 characters")
        if email:
            try:
                validate_email(email)
            except ValidationError:
                raise CommandError(f"--email {email!r} is not an email address") from None
        if (staff or superuser) and not password:
            password = self.ask_password()
        try:
            _user, key = create_user_with_token(
                username=username, email=email, password=password, staff=staff, superuser=superuser
            )
        except ValueError as exc:
            raise CommandError(str(exc)) from None
        self.stdout.write(key)

    def ask_password(self) -> str:
        if not sys.stdin.isatty():
            raise CommandError("--staff and --superuser need --password (the admin logs in with a password)")
        first = getpass.getpass("Password: ")
        if not first or first != getpass.getpass("Password (again): "):
            raise CommandError("the passwords are empty or differ")
        return first
