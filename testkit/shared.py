"""Results a test run computes once and every pytest-xdist worker reads: :func:`shared_dir`.

The suite runs each module in a worker of its own (tests/conftest.py), so a module fixture or a
``functools.cache`` is computed once per worker: an identification several modules need was
computed by each worker that ran one of them, the same numbers two or three times over. Here the
first process of the run that asks builds the result into a directory, under an exclusive
``flock``; the others wait for the lock and read what it wrote.

- **Where**: ``<pytest's base temporary directory>/shared`` (:func:`set_root`, from
  tests/conftest.py): the base directory of the whole run under xdist (the parent of the
  workers' own), pytest's own without it. A new run never reads an earlier run's results.
- **Key**: the result's name, its inputs (what the caller passes: arguments, and the bytes of any
  input file, :func:`file_digest`) and the SHA-256 of every ``.py`` file of rtlift, hil_sim,
  benchmarks, testkit and tests (:func:`source_digest`): an edit to the code during a run builds
  anew.
- Nothing is precomputed: the first caller in each run computes the result.
- Outside pytest (:func:`set_root` not called) each call builds into a fresh temporary directory.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:          # no flock (Windows): each process builds its own copy
    fcntl = None

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("rtlift", "hil_sim", "benchmarks", "testkit", "tests")
"""The packages whose code a shared result may depend on (hashed into every key)."""

_root: Path | None = None


def set_root(path: Path) -> None:
    """The directory shared by every process of this test run (tests/conftest.py sets it)."""
    global _root
    _root = Path(path)
    _root.mkdir(parents=True, exist_ok=True)


@functools.cache
def source_digest() -> str:
    """SHA-256 (hex) over the path and bytes of every ``.py`` file in :data:`SOURCES`, sorted."""
    h = hashlib.sha256()
    for pkg in SOURCES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            h.update(str(path.relative_to(REPO)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def file_digest(path: Path | str) -> str:
    """SHA-256 (hex) of a file's bytes: an input file's part of a key."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with open(path, "a+b") as f:
        if fcntl is not None:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def shared_dir(name: str, key: tuple, build: Callable[[Path], None]) -> Path:
    """The directory into which ``build(directory)`` wrote the result ``name`` for the inputs
    ``key`` (a tuple whose ``repr`` names them: option values, :func:`file_digest` of input files)
    with the code as it is now (:func:`source_digest`). Built once per run, by whichever process
    asks first; the directory appears whole (renamed into place after ``build`` returned) or not
    at all (a ``build`` that raises leaves nothing, and the next caller tries again). Treat it as
    read-only: copy a file out before changing it."""
    if _root is None:
        out = Path(tempfile.mkdtemp(prefix=f"{name}-"))
        build(out)
        return out
    digest = hashlib.sha256(repr((name, key, source_digest())).encode()).hexdigest()[:20]
    final = _root / f"{name}-{digest}"
    with _locked(_root / f"{name}-{digest}.lock"):
        if not final.is_dir():
            partial = _root / f"{name}-{digest}.partial-{os.getpid()}"
            shutil.rmtree(partial, ignore_errors=True)
            partial.mkdir()
            try:
                build(partial)
            except BaseException:
                shutil.rmtree(partial, ignore_errors=True)
                raise
            partial.rename(final)
    return final


def identified(*args: str | Path) -> Path:
    """The model file ``rtlift identify ARGS -o FILE`` writes (read-only; copy it to change it),
    run once per test run for the same arguments and the same bytes in every file they name.
    The key holds the arguments as given (paths too) and the digest of every argument that is a
    file; the command runs in this process, as the tests run it, and must exit 0."""
    from rtlift.app.cli import main

    argv = [str(a) for a in args]
    files = tuple(file_digest(a) for a in argv if Path(a).is_file())

    def build(out: Path) -> None:
        code = main(["identify", *argv, "-o", str(out / "model.json")])
        if code != 0:
            raise RuntimeError(f"rtlift identify {' '.join(argv)} exited {code}")

    return shared_dir("identify", (tuple(argv), files), build) / "model.json"


def bench_records(seed: int, names: tuple[str, ...]) -> dict[str, Path]:
    """The simulated bench's records ``names`` of noise seed ``seed``, one ``NAME.csv`` each
    (``write_record(path, run_experiment(name, seed=seed).to_record())``), written once per run
    so that the files, and so :func:`identified`'s results on them, are shared (read-only)."""
    from hil_sim.experiments import run_experiment
    from rtlift.core.records import write_record

    def build(out: Path) -> None:
        for name in names:
            write_record(out / f"{name}.csv", run_experiment(name, seed=seed).to_record())

    d = shared_dir("bench-records", (seed, names), build)
    return {name: d / f"{name}.csv" for name in names}
