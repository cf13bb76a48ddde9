"""Errors a user can act on.

Anything raised as :class:`UserError` (or a subclass) reaches the command line as one line
on stderr and exit status 2; everything else is an internal failure (exit status 1).
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input: a file, an argument, a port. The message is one line a user can act on."""


class RecordError(UserError):
    """A record file that does not follow INTERFACES.md (missing column, NaN, bad ``t`` …)."""


class ModelFileError(UserError):
    """A model file that cannot be used (wrong shape, non-finite, unstable, unknown version)."""
