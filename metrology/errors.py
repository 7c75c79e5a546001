"""What the services raise when they refuse a request: domain errors free of Django and DRF.

A service (``metrology/<app>/services.py``, selectors and the modules they use) raises one of
these with a sentence saying what is wrong and what to do; it knows nothing of HTTP. The API maps
them to responses (:func:`metrology.api_errors.exception_handler`: :class:`BadInput` is a 400,
:class:`Conflict` a 409, with the body ``{"error": "<the sentence>"}``); the pages and the
management commands show the sentence (``str(exc)``). This module imports nothing, so the
measurement core, the pipeline and the command line may raise them too.

They are not ``ValueError``: the services catch ``ValueError`` from the core to turn it into a
:class:`BadInput` naming the field, and must not catch their own refusals that way.
"""

from __future__ import annotations


class DomainError(Exception):
    """A request refused on purpose; ``str(exc)`` is the sentence for the person who made it."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


class BadInput(DomainError):  # noqa: N818 - the name the services and the API have long raised
    """The request is understood but its content is refused (the API answers 400)."""


class Conflict(DomainError):  # noqa: N818 - named like BadInput: what the API answers
    """The request is refused because of the current state of what it names: another agent is
    connected, a job is not done (the API answers 409)."""
