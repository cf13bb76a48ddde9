"""Discrete LTI state update in the paper's timing (eqs. 4–5 as printed in eq. SS):

    x(k) = A x(k−1) + B u(k),    y(k) = C x(k)

The input enters at time k, so y(k) has a direct path C B u(k). In the standard
``x⁺ = A x + B u, y = C x + D u`` form used by python-control this is the realisation
(A, B, C A, C B) on the state z(k) = x(k−1); :func:`to_statespace` returns it.

The batch twin is vectorised and carries exactly the state of the per-sample recursion. In
the paper's controllable canonical form (A's first row −a₁ … −aₙ, ones on the subdiagonal,
B = b₀e₁) the first state is an all-pole filter of the input,
``x₁(k) = b₀ u(k) − Σ aᵢ x₁(k−i)``, and ``xᵢ(k) = x₁(k−i+1)``: one ``lfilter`` call. Any
other (A, B) runs the step's own recursion in one compiled loop (:func:`_states`: the same
products summed in the same order, so the states equal the step's bit for bit). It used to be
processed in blocks of 128 samples with the block Toeplitz matrix of Markov parameters; with a
pole at 0.991 that drifted 8e-12 from the step over 400 samples (a hypothesis example in CI),
beyond the 1e-12 that streaming and batch must agree to.
"""

from __future__ import annotations

import numpy as np

from rtlift.core.jit import njit_cached


def spectral_radius(A: np.ndarray) -> float:
    """max |λ(A)|: the LTI is asymptotically stable iff this is < 1."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def to_statespace(A: np.ndarray, B: np.ndarray, C: np.ndarray, dt: float):
    """python-control ``StateSpace`` equal to x(k) = A x(k−1) + B u(k), y(k) = C x(k)."""
    import control

    A = np.atleast_2d(A)
    B = np.asarray(B, dtype=float).reshape(-1, 1)
    C = np.asarray(C, dtype=float).reshape(1, -1)
    return control.ss(A, B, C @ A, C @ B, dt)


class LTIBlock:
    """Streaming single-input, single-output state update with an exact batch twin."""

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> None:
        A = np.atleast_2d(np.asarray(A, dtype=float))
        n = A.shape[0]
        B = np.asarray(B, dtype=float).ravel()
        C = np.asarray(C, dtype=float).ravel()
        if A.shape != (n, n) or B.shape != (n,) or C.shape != (n,) or n == 0:
            raise ValueError(f"LTI shapes do not agree: A {A.shape}, B {B.shape}, C {C.shape}")
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B)) and np.all(np.isfinite(C))):
            raise ValueError("LTI matrices must be finite")
        self.A, self.B, self.C = (np.ascontiguousarray(M).copy() for M in (A, B, C))
        self.n = n
        self._A = [[float(v) for v in row] for row in A]
        self._B = [float(v) for v in B]
        self._C = [float(v) for v in C]
        self._x = np.zeros(n)                  # x(k); numpy, so the compiled step advances it too
        self._tmp = [0.0] * n
        shift = np.zeros((n, n))
        shift[1:, :-1] = np.eye(n - 1)
        self.canonical = bool(np.array_equal(A[1:], shift[1:]) and np.all(B[1:] == 0))
        self._den = np.concatenate([[1.0], -A[0]])

    @property
    def state_size(self) -> int:
        return self.n

    def step(self, u: float) -> float:
        """x(k) = A x(k−1) + B u(k); returns y(k) = C x(k)."""
        A, B, x, t, n = self._A, self._B, self._x.tolist(), self._tmp, self.n
        for i in range(n):
            row = A[i]
            s = B[i] * u
            for j in range(n):
                s += row[j] * x[j]
            t[i] = s
        y = 0.0
        C, state = self._C, self._x
        for i in range(n):
            state[i] = t[i]                     # element-wise: cheaper than a slice from a list
            y += C[i] * t[i]
        return y

    def kernel_arrays(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: parameters (A, B, C) and state (x,), not copies."""
        return (self.A, self.B, self.C), (self._x,)

    def simulate_states(self, u: np.ndarray) -> np.ndarray:
        """States x(k) for every sample of ``u`` (N, n); advances the current state."""
        u = np.ascontiguousarray(u, dtype=float)
        N = u.size
        if self.canonical and N:
            return self._simulate_canonical(u)
        X = np.empty((N, self.n))
        _states(self.A, self.B, self._x, u, X)
        return X

    def _canonical_first_state(self, u: np.ndarray) -> np.ndarray:
        """x₁ over ``u`` preceded by its n−1 past values (oldest first); advances the state."""
        n = self.n
        past = np.array(self._x)                              # x₁(k−1), x₁(k−2), … x₁(k−n)
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        zi = signal.lfiltic([self._B[0]], self._den, past)
        x1, _ = signal.lfilter([self._B[0]], self._den, u, zi=zi)
        ext = np.concatenate([past[::-1][1:], x1])            # x₁(k−n+1) … x₁(k+N−1)
        self._x[:] = [float(v) for v in ext[::-1][:n]]
        return ext

    def _simulate_canonical(self, u: np.ndarray) -> np.ndarray:
        ext = self._canonical_first_state(u)
        return np.lib.stride_tricks.sliding_window_view(ext, self.n)[:, ::-1]

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """Batch twin of :meth:`step`: y(k) for every sample of ``u``."""
        u = np.asarray(u, dtype=float)
        if self.canonical and u.size:                         # y(k) = Σᵢ Cᵢ x₁(k−i+1): a short FIR of x₁
            return np.convolve(self._canonical_first_state(u), self.C, mode="valid")
        return self.simulate_states(u) @ self.C

    def reset(self) -> None:
        self._x[:] = [0.0] * self.n

    def get_state(self) -> np.ndarray:
        return np.array(self._x, dtype=float)

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.n,):
            raise ValueError(f"LTI state must have shape ({self.n},), got {s.shape}")
        self._x[:] = [float(v) for v in s]

    def dc_gain(self) -> float:
        """y/u in steady state: C (I − A)⁻¹ B (inf for an integrator)."""
        try:
            return float(self.C @ np.linalg.solve(np.eye(self.n) - self.A, self.B))
        except np.linalg.LinAlgError:
            return float("inf")


@njit_cached
def _states(A, B, x, u, X):
    """X[k] = x(k) = A x(k−1) + B u(k) for every k, from and advancing ``x`` in place: the
    recurrence of :meth:`LTIBlock.step`, its products summed in the same order."""
    n = x.shape[0]
    for k in range(u.shape[0]):
        for i in range(n):
            s = B[i] * u[k]
            for j in range(n):
                s += A[i, j] * x[j]
            X[k, i] = s
        for i in range(n):
            x[i] = X[k, i]
