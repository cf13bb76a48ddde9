"""A UTF-8 text file read whole, every way it can fail one line: what a record CSV and an
estimates CSV (``rtlift plot``) are read with."""

from __future__ import annotations

import os


def read_text(path: str | os.PathLike, what: str, error: type[Exception], hint: str = "") -> str:
    """The text of ``path``; ``error`` (a one-line message naming ``path``) when it does not
    exist, is a directory (not a ``what``), is not UTF-8 (``hint`` appended) or cannot be read."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, not {what}") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text (UTF-8) file{hint}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
