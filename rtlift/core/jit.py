"""Compiled functions that every rtlift process may share safely: :func:`njit_cached`.

numba's ``cache=True`` writes the machine code of each compiled specialisation to an index
file (``NAME.nbi``: signature → data file) and numbered data files (``NAME.N.nbc``). Two
things go wrong with the defaults, and both were seen here (issue 26):

- **Where**: beside the source, in ``site-packages/rtlift/*/__pycache__``. Files numba writes
  there are not in the wheel's record, so ``pip uninstall`` leaves them, and the orphan
  ``site-packages/rtlift/`` directory then shadows a later editable install of the package
  (``No module named 'rtlift.blocks.convolution'``). Here the cache lives in the user's cache
  home instead (``$XDG_CACHE_HOME/rtlift/numba``, ``~/.cache/rtlift/numba``; the platform's
  equivalent elsewhere), set before any function is compiled; ``NUMBA_CACHE_DIR`` still wins
  when a user sets it.
- **Races**: ``IndexDataCacheFile.save`` reads the index, picks the first free data-file
  number, writes the index, then the data, without a lock. Two processes compiling two
  specialisations of one function at once (say the filter orders 2 and 4 of
  ``hybrid_simulate``) both pick ``NAME.1.nbc``; one index entry then points at the other
  specialisation's code, and a third process that loads it runs machine code built for other
  argument sizes: stack buffers of the wrong length, NaN or Inf where a number should be
  (numba issues #4807, #10128). Here every cache file of a function is read under a shared
  and written under an exclusive ``flock`` on ``NAME.nbi.lock`` (POSIX), so an index and the
  data it names are always written together.
- **Staleness across files**: numba keeps a function's cached code while *its own* source file's
  modification time and size are unchanged, but rtlift's kernels inline helpers from other files
  (the observer step inlines the model step, which inlines the stages' kernels): after an upgrade
  or an edit that changed only a helper's file, the old machine code would be loaded. Here every
  cache index is stamped with the function's file *and* every rtlift source file that compiles
  code (:func:`compiled_sources_stamp`), so any change to any of them recompiles them all.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numba
from numba.core import caching

try:
    import fcntl
except ImportError:          # Windows: no flock; numba's own behaviour
    fcntl = None

CACHE_ENV = "NUMBA_CACHE_DIR"


def cache_home() -> Path:
    """The per-user directory for rtlift's compiled code (not inside the installed package)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "rtlift" / "numba"


def _use_cache_home() -> None:
    """Point numba at :func:`cache_home` unless the user chose a directory (``NUMBA_CACHE_DIR``)."""
    if os.environ.get(CACHE_ENV):
        return
    numba.config.CACHE_DIR = str(cache_home())


PACKAGE = Path(__file__).resolve().parents[1]


def compiled_sources_stamp(root: Path = PACKAGE, marker: str = "njit_cached") -> tuple:
    """(path, mtime_ns, size) of every ``.py`` file under ``root`` whose text names ``marker``
    (the files that compile code, and so may be inlined into one another), sorted."""
    out = []
    for path in sorted(root.rglob("*.py")):
        try:
            if marker in path.read_text(encoding="utf-8", errors="ignore"):
                st = path.stat()
                out.append((str(path.relative_to(root)), st.st_mtime_ns, st.st_size))
        except OSError:
            continue
    return tuple(out)


_STAMP: tuple | None = None


def _sources_stamp() -> tuple:
    global _STAMP
    if _STAMP is None:
        _STAMP = compiled_sources_stamp()
    return _STAMP


class _LockedCacheFile(caching.IndexDataCacheFile):
    """numba's index-and-data cache file with each ``save`` and ``load`` under one ``flock``."""

    @contextlib.contextmanager
    def _locked(self, exclusive: bool) -> Iterator[None]:
        if fcntl is None:
            yield
            return
        with open(self._index_path + ".lock", "a+b") as f:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            try:
                yield
            finally:
                fcntl.flock(f.fileno(), fcntl.LOCK_UN)

    def save(self, key: Any, data: Any) -> None:
        with self._locked(True):
            super().save(key, data)

    def load(self, key: Any) -> Any:
        with self._locked(False):
            return super().load(key)


def njit_cached(*args: Any, **options: Any) -> Callable:
    """``numba.njit(cache=True, **options)`` with the cache in :func:`cache_home`, its files
    read and written under a lock and stamped with every compiling source file (see the module's
    docstring). Use it bare or with options,
    like ``njit``: ``@njit_cached`` or ``@njit_cached(inline="always")``."""
    def decorate(func: Callable) -> Any:
        dispatcher = numba.njit(cache=True, **options)(func)
        cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
        if type(cache_file) is caching.IndexDataCacheFile:
            cache_file.__class__ = _LockedCacheFile
            cache_file._source_stamp = (cache_file._source_stamp, _sources_stamp())
        return dispatcher

    if args and callable(args[0]):
        return decorate(args[0])
    return decorate


_use_cache_home()
