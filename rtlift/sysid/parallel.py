"""Both cores for the identification and the diagnosis, the same numbers as one core.

Two uses, each bit for bit the serial computation (a forked copy of this process runs the
same code on the same data with the same BLAS settings): :func:`least_squares`, a refinement
whose finite-difference Jacobian's evaluations are shared with a child (:class:`Halves`, below),
and :func:`two_lanes`, independent whole fits (the diagnosis's candidate structures) run two at
a time.

The refinements of :mod:`.identify` spend most of their time in scipy's finite-difference
Jacobian (``least_squares(jac="2-point")``): one simulation of the whole cost record per
parameter, J[:, i] = (r(θ + hᵢeᵢ) − r(θ)) / hᵢ, each independent of the others. scipy (≥ 1.16)
evaluates them through a map-like ``workers(fun, points)``; :class:`Halves` is one: a child
process forked once per refinement evaluates the first half of the points while this process
evaluates the rest. The child is a copy of this process made when the refinement starts, so it
runs the residual function it was given, on the same data with the same code and BLAS settings:
every entry of the Jacobian is the number one process computes (bit for bit), so the refinement
takes the same path and ends at the same θ, in about half the wall time of its Jacobians where
the two cores are free. Where no child can be started (no ``fork`` on the platform, a refusal of
the system) or the child fails, the points are evaluated here: never an error, never a different
number.

The child gets only points (a few parameters each) and returns residual vectors over a pipe; it
ends with the refinement (:meth:`Halves.close`, or the context manager) and never touches this
process's files or streams (``os._exit``).

``RTLIFT_SYSID_CORES=1`` in the environment keeps both on one core (the same numbers): for a
machine whose other core is taken, e.g. the test suite, whose two workers already fill both
cores beside its real-time loops (tests/conftest.py sets it).
"""

from __future__ import annotations

import inspect
import os
import signal
from collections.abc import Callable, Iterable, Sequence
from multiprocessing.connection import Connection, Pipe
from typing import Any

import numpy as np
from scipy import optimize

WORKERS = "workers" in inspect.signature(optimize.least_squares).parameters
"""Whether this scipy's ``least_squares`` takes ``workers`` (scipy >= 1.16); older ones run on one core."""
MIN_SAMPLES = 2000
"""The fewest residual samples a refinement shares its Jacobian for: below, one evaluation costs
less than a child's start (10–30 ms on the project's 2-core machine, loaded) saves over a short
refinement. Set from the sizes, not tuned on a benchmark: the property test's records of 50–150
samples took 13.7 min with a child per refinement (load 6–9) where they took about 4 min
before; every measured benchmark's cost record has 800 (Cascaded Tanks) to 30 000 samples."""
CORES_ENV = "RTLIFT_SYSID_CORES"
"""The environment variable that, set to 1, keeps the identification on one core."""
MIN_POINTS = 2
"""The fewest points a map shares with the child: one point is evaluated here."""


def _serve(conn: Connection, residual: Callable[[np.ndarray], np.ndarray]) -> None:   # pragma: no cover (child)
    """The child's loop: a list of points in, their residuals out (``None`` for one that raised),
    until the pipe closes."""
    while True:
        try:
            points = conn.recv()
        except (EOFError, OSError):
            return
        out = []
        for x in points:
            try:
                out.append(np.atleast_1d(residual(x)))
            except BaseException:       # the parent evaluates this one itself
                out.append(None)
        conn.send(out)


class Halves:
    """A map-like callable for ``scipy.optimize.least_squares(workers=...)`` (module docstring):
    ``residual`` is the function given to ``least_squares`` (scipy hands the map a thin wrapper
    of it, which this process calls; the child calls ``residual`` itself, the same numbers for a
    float64 θ). Use as a context manager around the one ``least_squares`` call."""

    def __init__(self, residual: Callable[[np.ndarray], np.ndarray]) -> None:
        self.residual = residual
        self.pid: int | None = None
        self.conn: Connection | None = None

    def __enter__(self) -> Halves:
        self._start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _start(self) -> None:
        if not forking():
            return
        try:
            mine, theirs = Pipe()
            pid = os.fork()
        except OSError:
            return
        if pid == 0:                                        # pragma: no cover (child)
            code = 0
            try:
                mine.close()
                _serve(theirs, self.residual)
            except BaseException:
                code = 1
            finally:
                os._exit(code)
        theirs.close()
        self.pid, self.conn = pid, mine

    def close(self) -> None:
        """End the child (if any) and wait for it."""
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        if self.pid is not None:
            try:
                os.waitpid(self.pid, 0)
            except ChildProcessError:
                pass
            self.pid = None

    def __call__(self, fun: Callable[[np.ndarray], np.ndarray], points: Iterable[np.ndarray]) -> list[np.ndarray]:
        """[fun(x) for x in points], the first half evaluated by the child."""
        points = list(points)
        k = len(points) // 2 if len(points) >= MIN_POINTS else 0
        sent = False
        if k and self.conn is not None:
            try:
                self.conn.send(points[:k])
                sent = True
            except (OSError, ValueError):
                self.close()
        own = [fun(x) for x in points[k:]] if sent else []
        theirs: list = [None] * k
        if sent:
            try:
                theirs = self.conn.recv()
            except (EOFError, OSError):
                self.close()
        if not sent:
            return [fun(x) for x in points]
        return [fun(x) if r is None else r for x, r in zip(points[:k], theirs, strict=True)] + own


def least_squares(residual: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, samples: int,
                  **options: Any) -> optimize.OptimizeResult:
    """``scipy.optimize.least_squares(residual, x0, **options)`` (method ``trf``, a finite-difference
    Jacobian) with its Jacobian's evaluations shared with a child process (:class:`Halves`) where
    the residual has at least :data:`MIN_SAMPLES` ``samples``: the same result, bit for bit."""
    if not WORKERS or samples < MIN_SAMPLES:
        return optimize.least_squares(residual, x0, **options)
    with Halves(residual) as workers:
        return optimize.least_squares(residual, x0, workers=workers, **options)


def forking() -> bool:
    """Whether a child may be forked: the platform has ``fork`` and :data:`CORES_ENV` is not 1."""
    return hasattr(os, "fork") and os.environ.get(CORES_ENV, "").strip() != "1"


def _attempt(task: Callable[[], Any]) -> Any:
    """``task()``, or the exception it raised (an Exception instance) as its result."""
    try:
        return task()
    except Exception as exc:          # noqa: BLE001 - handed back to the caller, who decides
        return exc


def two_lanes(tasks: Sequence[Callable[[], Any]]) -> list[Any]:
    """[task() for task in tasks] on both cores: the first task in a forked child, the others here
    in turn (the diagnosis's candidate structures, each fitted whole and independent of the
    others; the first is the longest). A task's exception is its result (the caller raises it or
    not). The child computes what this process would (a copy of it, the same data and code), so
    every result is the serial one; where no child can be started, or it fails or its result
    cannot be sent back, the first task is run here after the others."""
    if len(tasks) < 2 or not forking():
        return [_attempt(t) for t in tasks]
    try:
        mine, theirs = Pipe(duplex=False)
        pid = os.fork()
    except OSError:
        return [_attempt(t) for t in tasks]
    if pid == 0:                                            # pragma: no cover (child)
        try:
            mine.close()
            theirs.send(_attempt(tasks[0]))
        finally:
            os._exit(0)
    theirs.close()
    try:
        rest = [_attempt(t) for t in tasks[1:]]
    except BaseException:             # interrupted here: the child's work is not wanted
        os.kill(pid, signal.SIGTERM)
        os.waitpid(pid, 0)
        mine.close()
        raise
    try:
        first = mine.recv()
    except (EOFError, OSError):
        first = None
    finally:
        mine.close()
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:
            pass
    return [_attempt(tasks[0]) if first is None else first, *rest]
