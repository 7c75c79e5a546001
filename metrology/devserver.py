"""Django's development server (``manage.py runserver``: the embedded default, the tests' live server)
answering kept-alive connections without a 40 ms stall.

Django's ``WSGIRequestHandler`` writes a response's headers and its body in separate ``send`` calls
on an unbuffered socket. On a kept-alive connection (browsers, ``requests.Session``) the body then
waits for the ACK of the headers (Nagle's algorithm), which the client delays by up to 40 ms: each
request took 44 ms on a kept-alive connection against 2.3 ms on a new one (40 GETs of
``/api/rigs/`` on this machine). ``TCP_NODELAY`` on the accepted sockets sends each write at once,
as production servers (gunicorn, uvicorn) do.
"""

from __future__ import annotations


def disable_nagle() -> None:
    """Set ``TCP_NODELAY`` on every connection the development server accepts from now on
    (:attr:`socketserver.StreamRequestHandler.disable_nagle_algorithm` of Django's handler)."""
    from django.core.servers.basehttp import WSGIRequestHandler

    WSGIRequestHandler.disable_nagle_algorithm = True
