"""The compiled observer step called with one argument for all its arrays (issue 46, third pass).

:func:`~rtlift.observer.compiled.observer_step` takes 20 arrays (22 for the interaction
structure, :func:`~rtlift.observer.compiled.observer_step_interaction`). Called from Python,
numba's dispatcher types and unboxes each of them per call: it reads every array's Python object
(header, shape, strides, dtype), and the interpreter builds the 23-item argument tuple. In a tight
loop that is ≈ 0.5–1 µs; in the live loop, which sleeps 2.5 ms between samples, the core's
caches and TLB have lost those objects by the next sample. Called this way instead, the live
step went from 26.1 to 19.1 µs median and from 159 to 112 µs p99, the tight loop from 5.25 to
3.26 µs (``benchmarks/observer_loop.py --anatomy``, alternated in one run on a loaded machine;
docs/results/monitor.md "Issue 46, the live step (third pass)").

Here the arrays are bound once: :func:`bind` writes each array's address and shape into one
int64 array ``at`` (three slots per array: address, rows, columns), and :func:`observer_step_at`
/ :func:`observer_step_interaction_at` rebuild the arrays from it in machine code
(``numba.carray``: no allocation, no Python object) and call the same compiled step. The step's
arithmetic is the one machine code: results and states are bit-identical to the dispatcher's call
(``tests/test_compiled_step.py``). The addresses stay valid as long as the arrays live and are
never replaced, which the observer's binding already requires (every array is advanced in
place); :func:`bind` keeps them with the addresses, and an observer cannot be copied (its BLAS
handles do not pickle), so no copy steps the original's arrays. An argument whose kind (float64
or int64, rank, C-contiguous, writeable) differs from what the wrapper rebuilds is never bound
by address: :func:`bind` returns ``()`` and the caller keeps numba's dispatcher.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import carray, types
from numba.extending import intrinsic

from rtlift.core.jit import njit_cached
from rtlift.observer.compiled import observer_step, observer_step_interaction

SLOTS = 3
"""int64 slots of ``at`` per array: its address, rows, columns (0 for a vector)."""


@intrinsic
def _pointer(typingctx, address, dtype):
    """The int64 ``address`` as a pointer to ``dtype`` (``np.float64`` or ``np.int64``)."""
    ptr = types.CPointer(dtype.dtype)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(ptr))

    return ptr(types.int64, dtype), codegen


@njit_cached(inline="always")
def _v(at, i):
    """Argument ``i``: a float64 vector."""
    return carray(_pointer(at[SLOTS * i], np.float64), at[SLOTS * i + 1])


@njit_cached(inline="always")
def _i(at, i):
    """Argument ``i``: an int64 vector."""
    return carray(_pointer(at[SLOTS * i], np.int64), at[SLOTS * i + 1])


@njit_cached(inline="always")
def _m(at, i):
    """Argument ``i``: a float64 matrix (C order)."""
    return carray(_pointer(at[SLOTS * i], np.float64), (at[SLOTS * i + 1], at[SLOTS * i + 2]))


@njit_cached
def observer_step_at(cmu, env, dcl, at):
    """:func:`~rtlift.observer.compiled.observer_step` on the arrays bound in ``at`` (:func:`bind`)."""
    return observer_step(cmu, env, dcl, _v(at, 0), _v(at, 1), _v(at, 2), _i(at, 3), _v(at, 4), _v(at, 5),
                         _v(at, 6), _i(at, 7), _v(at, 8), _v(at, 9), _i(at, 10), _v(at, 11), _m(at, 12),
                         _v(at, 13), _m(at, 14), _v(at, 15), _m(at, 16), _v(at, 17), _m(at, 18), _v(at, 19))


@njit_cached
def observer_step_interaction_at(cmu, env, dcl, at):
    """:func:`~rtlift.observer.compiled.observer_step_interaction` on the arrays bound in ``at``."""
    return observer_step_interaction(cmu, env, dcl, _v(at, 0), _v(at, 1), _v(at, 2), _i(at, 3), _v(at, 4),
                                     _v(at, 5), _v(at, 6), _v(at, 7), _i(at, 8), _v(at, 9), _v(at, 10),
                                     _v(at, 11), _i(at, 12), _v(at, 13), _m(at, 14), _v(at, 15), _m(at, 16),
                                     _v(at, 17), _m(at, 18), _v(at, 19), _m(at, 20), _v(at, 21))


KINDS = {observer_step: ("vvvivvvivvivmvmvmvmv", observer_step_at),
         observer_step_interaction: ("vvvivvvvivvvivmvmvmvmv", observer_step_interaction_at)}
"""Compiled step → (the kind of each array argument: ``v`` float64 vector, ``i`` int64 vector,
``m`` float64 matrix; the wrapper that rebuilds them from ``at``)."""


def _kind(a: Any) -> str:
    if not (isinstance(a, np.ndarray) and a.flags.c_contiguous and a.flags.writeable and a.flags.aligned):
        return "?"
    if a.dtype == np.float64:
        return {1: "v", 2: "m"}.get(a.ndim, "?")
    return "i" if a.dtype == np.int64 and a.ndim == 1 else "?"


def addresses(arrays: tuple[np.ndarray, ...]) -> np.ndarray:
    """``at`` for ``arrays``: per array its address (bytes), rows and columns (0 for a vector), int64."""
    at = np.zeros(SLOTS * len(arrays), dtype=np.int64)
    for k, a in enumerate(arrays):
        at[SLOTS * k] = a.ctypes.data
        at[SLOTS * k + 1] = a.shape[0]
        at[SLOTS * k + 2] = a.shape[1] if a.ndim == 2 else 0
    return at


Bound = tuple[Any, tuple[np.ndarray], tuple[np.ndarray, ...]]
"""What :func:`bind` returns: (wrapper, ``(at,)``, the arrays)."""


def bind(step: Any, arrays: tuple[np.ndarray, ...]) -> Bound | tuple[()]:
    """(the wrapper of ``step``, its arguments after Cμ, Cμ_env, ΔCL: ``(at,)``, ``arrays`` — kept
    alive with their addresses), the form of the observer's ``(step, arguments, touch)``; ``()``
    when ``step`` has no wrapper or an argument is not of the kind it rebuilds."""
    kinds, wrapper = KINDS.get(step, ("", None))
    if wrapper is None or "".join(_kind(a) for a in arrays) != kinds:
        return ()
    return wrapper, (addresses(arrays),), arrays


def warm_up(step: Any, arrays: tuple[np.ndarray, ...]) -> None:
    """Compile the wrapper of ``step`` (or load it from numba's cache) on copies of ``arrays``:
    the arrays themselves are untouched."""
    copies = tuple(a.copy() for a in arrays)
    bound = bind(step, copies)
    if bound:
        wrapper, at, _ = bound
        wrapper(0.0, 0.0, 0.0, *at)
