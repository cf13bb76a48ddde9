"""One BLAS thread for the identification and the diagnosis.

Their linear algebra is many small, tall problems — least squares on tens of thousands of rows
and a few to a few tens of columns, the trust-region solver's SVD of its Jacobian once an
iteration, thousands of times. OpenBLAS splits each over every core, and on this project's
2-core machines the split costs more than it saves: measured on a 32 000 × 10 SVD, 5.3 ms on one
thread against 96 ms on two while another process kept a core busy (``docs/results/house.md``).
:func:`one_blas_thread` runs a function with BLAS held to one thread (threadpoolctl, restoring
the caller's setting afterwards); the answer then also no longer depends on the number of cores.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TypeVar

from threadpoolctl import threadpool_limits

F = TypeVar("F", bound=Callable)


def one_blas_thread(func: F) -> F:
    """``func`` run with BLAS limited to one thread (module docstring)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
