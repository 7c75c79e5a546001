"""WSGI entry point: ``gunicorn metrology.wsgi``."""

import os

from django.core.wsgi import get_wsgi_application

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "metrology.settings")
application = get_wsgi_application()
