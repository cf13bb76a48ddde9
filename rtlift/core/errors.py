"""Errors a user can act on.

Anything raised as :class:`UserError` (or a subclass) reaches the command line as one line
on stderr and exit status 2; a :class:`NumericalError` (a stage produced NaN or Inf) as one
line naming the stage and the record, exit status 1; everything else is an internal failure
(exit status 1).
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input: a file, an argument, a port. The message is one line a user can act on."""


class RecordError(UserError):
    """A record file that does not follow INTERFACES.md (missing column, NaN, bad ``t`` …)."""


class ModelFileError(UserError):
    """A model file that cannot be used (wrong shape, non-finite, unstable, unknown version)."""


class NumericalError(Exception):
    """A computation produced a non-finite number (NaN or ±Inf) from finite inputs. Not the
    user's input and not a bug to hide: the command names the stage and the record in one line
    and exits with status 1, and writes no file from it."""


def first_nonfinite(value: object, where: str = "") -> str | None:
    """The path (``[2]``, ``.poles_std[1]`` …) of the first NaN or ±Inf in ``value`` — a number,
    an array, or dicts and lists of them — or ``None`` if every number in it is finite.
    ``None`` values are not numbers and pass (a model file writes an unknown as null)."""
    import math

    import numpy as np

    if isinstance(value, (float, np.floating)):
        return None if math.isfinite(value) else where or "value"
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "fc" or np.all(np.isfinite(value)):
            return None
        index = np.unravel_index(int(np.argmin(np.isfinite(value))), value.shape)
        return f"{where}[{', '.join(map(str, index))}]"
    if isinstance(value, dict):
        for k, v in value.items():
            bad = first_nonfinite(v, f"{where}.{k}" if where else str(k))
            if bad is not None:
                return bad
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            bad = first_nonfinite(v, f"{where}[{i}]")
            if bad is not None:
                return bad
    return None


def require_finite(stage: str, record: str, **values: object) -> None:
    """Raise :class:`NumericalError` naming ``stage``, ``record`` and where the first
    non-finite number in ``values`` sits."""
    for name, value in values.items():
        bad = first_nonfinite(value, name)
        if bad is not None:
            raise NumericalError(f"{stage} on {record}: {bad} is not finite (NaN or Inf); "
                                 "nothing was written")

