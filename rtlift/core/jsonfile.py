"""JSON files written whole or not at all (model files): :func:`write_json_atomic`."""

from __future__ import annotations

import contextlib
import json
import os

from rtlift.core.errors import NumericalError, first_nonfinite


def write_json_atomic(path: str | os.PathLike, doc: dict, *, stage: str, default=None, sort_keys: bool = False,
                      finite: bool = True) -> None:
    """Write ``doc`` as JSON (indent 1, a final newline; keys sorted with ``sort_keys``) to ``path``
    whole or not at all: with ``finite`` every number checked finite first (naming ``stage``;
    without it NaN and ±Inf are written as JSON's ``NaN``/``Infinity``, as a run summary's
    unbounded thresholds), then a temporary file beside it renamed over ``path``; the temporary
    file is removed if anything fails."""
    bad = first_nonfinite(doc) if finite else None
    if bad is not None:
        raise NumericalError(f"{stage} {path}: {bad} is not finite (NaN or Inf); nothing was written")
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1, allow_nan=not finite, default=default, sort_keys=sort_keys)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
