"""ASGI entry point, the production web server: ``gunicorn metrology.asgi:application -k uvicorn_worker.UvicornWorker``.

Under ASGI the projector long-poll (``metrology.acquisition.longpoll``) waits on the event loop;
every other view is sync and runs in a thread of its own per request. Database connections are
therefore closed at the end of each request (``GCPS_DB_CONN_MAX_AGE`` defaults to 0 here, 60 under
WSGI): a connection kept by a request's thread would never be used again. docs/operations.md, "Web server".
"""

import os

from django.core.asgi import get_asgi_application

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "metrology.settings")
os.environ.setdefault("GCPS_DB_CONN_MAX_AGE", "0")
application = get_asgi_application()
