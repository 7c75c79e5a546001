"""The error of malformed capture stacks and stage series."""

from __future__ import annotations


class StackError(ValueError):
    """A capture stack (or stage series) is malformed; the one-line message names the problem."""
