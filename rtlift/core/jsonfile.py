"""JSON files written whole or not at all (model files): :func:`write_json_atomic`."""

from __future__ import annotations

import contextlib
import json
import os

from rtlift.core.errors import NumericalError, first_nonfinite


def write_json_atomic(path: str | os.PathLike, doc: dict, *, stage: str, default=None) -> None:
    """Write ``doc`` as JSON to ``path`` whole or not at all: every number checked finite first
    (:func:`require_finite`, naming ``stage``), then a temporary file beside it renamed over
    ``path``; the temporary file is removed if anything fails."""
    bad = first_nonfinite(doc)
    if bad is not None:
        raise NumericalError(f"{stage} {path}: {bad} is not finite (NaN or Inf); nothing was written")
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1, allow_nan=False, default=default)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
