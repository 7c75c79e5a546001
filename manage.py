#!/usr/bin/env python
"""Django's command-line utility for GCPS Lab."""

import os
import sys


def main() -> None:
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "metrology.settings")
    from django.core.management import execute_from_command_line

    if sys.argv[1:2] == ["runserver"]:
        from metrology.devserver import disable_nagle

        disable_nagle()
    execute_from_command_line(sys.argv)


if __name__ == "__main__":
    main()
