"""The services' domain errors (``metrology.errors``): the API's answers and the pages' sentences."""

from __future__ import annotations

import pytest
from django.core.exceptions import ValidationError as DjangoValidationError
from rest_framework import exceptions

from metrology.api_errors import exception_handler
from metrology.errors import BadInput, Conflict, DomainError
from metrology.measurements.acceptance import NotDone
from metrology.service_errors import SERVICE_ERRORS, error_sentence


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (BadInput("options: unknown option 'x'"), 400),
        (Conflict("rig 1 already has a connected capture agent"), 409),
        (NotDone("measurement 3 is not done (its job is queued)"), 409),
    ],
)
def test_the_api_answers_a_domain_error_with_its_status_and_sentence(error, status):
    response = exception_handler(error, {})
    assert response is not None
    assert response.status_code == status
    assert response.data == {"error": str(error)}


def test_a_domain_error_answers_as_the_drf_error_it_replaces():
    """The body of a ``BadInput`` is that of DRF's ``APIException`` with the same sentence (the 400
    the services raised before they stopped importing DRF)."""
    sentence = "board: at most 100 points per row"
    drf = exceptions.APIException(sentence)
    drf.status_code = 400
    before, after = exception_handler(drf, {}), exception_handler(BadInput(sentence), {})
    assert before is not None and after is not None
    assert (after.status_code, after.data) == (before.status_code, before.data)
    assert dict(after.items()) == dict(before.items())  # the headers


def test_domain_errors_are_not_value_errors():
    """The services turn the core's ``ValueError`` into ``BadInput``; their own refusals pass through."""
    assert not issubclass(DomainError, ValueError)


def test_the_pages_show_the_sentence_of_each_service_error():
    errors = [BadInput("a refused option"), Conflict("another agent"), ValueError("from the core")]
    errors.append(DjangoValidationError(["one", "two"]))
    assert all(isinstance(error, SERVICE_ERRORS) for error in errors)
    sentences = [error_sentence(error) for error in errors]
    assert sentences == ["a refused option", "another agent", "from the core", "one two"]
