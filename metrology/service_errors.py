"""What a caller of the services catches and shows in words: a page's form, an enclosing service.

The services raise the domain errors of :mod:`metrology.errors`, let ``ValueError`` from the
measurement core through, and Django's ``ValidationError`` may come from a model field (an
unparsable value). The API maps the same errors itself (:mod:`metrology.api_errors`); this module
imports no DRF.
"""

from __future__ import annotations

from django.core.exceptions import ValidationError as DjangoValidationError

from metrology.errors import DomainError

#: What services raise for refused input: the domain errors (:class:`~metrology.errors.BadInput`,
#: :class:`~metrology.errors.Conflict`), Django's model ``ValidationError`` and ``ValueError`` from
#: the measurement core.
SERVICE_ERRORS: tuple[type[Exception], ...] = (DomainError, ValueError, DjangoValidationError)


def error_sentence(exc: Exception) -> str:
    """One of :data:`SERVICE_ERRORS` as one sentence for a page or an enclosing error."""
    if isinstance(exc, DjangoValidationError):
        return " ".join(exc.messages)
    return str(exc)
