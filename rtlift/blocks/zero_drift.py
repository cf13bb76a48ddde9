"""The ``zero_drift`` effect's stage: thermal drift of the sensor zero, added to ΔCL."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.blocks.stage_base import OutputStage, _finite, _positive


class _Additive(OutputStage):
    """out(k) = ΔCL(k) + d(k), d(k) = C x(k), x(k) = A x(k−1) (2 states, see subclasses)."""

    kind = "additive"
    state_size = 2
    compiled_form = True
    _x0 = property(lambda self: float(self._xs[0]), lambda self, v: self._xs.__setitem__(0, v))
    _x1 = property(lambda self: float(self._xs[1]), lambda self, v: self._xs.__setitem__(1, v))

    def _initial(self) -> tuple[float, float]:
        raise NotImplementedError

    def reset(self) -> None:
        self._x0, self._x1 = self._initial()

    def get_state(self) -> np.ndarray:
        return np.array([self._x0, self._x1])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (2,):
            raise ValueError(f"{self.name} state must have shape (2,), got {s.shape}")
        self._x0, self._x1 = float(s[0]), float(s[1])

    def disturbance(self, n: int) -> np.ndarray:
        """d(k) for the next n samples (advances the state)."""
        return self.simulate(np.zeros(n))


class ZeroDrift(_Additive):
    """Thermal drift of the sensor zero, added to ΔCL (t_k = k/fs, k = 0 after reset):

        linear:       d(k) = offset + rate · t_k
                      x = [d(k), rate/fs], A = [[1, 1], [0, 1]], C = [1, 0]
        exponential:  d(k) = offset + amplitude (1 − exp(−t_k/τ))
                      x = [−amplitude λᵏ, offset + amplitude], λ = exp(−1/(τ fs)),
                      A = diag(λ, 1), C = [1, 1]

    ``offset`` (ΔCL) is the drift's value at the record's first sample relative to the tare
    (the tare is taken while the zero is already drifting); it is fitted with the rest.
    """

    name = "zero_drift"

    def __init__(self, fs_hz: float, *, rate_per_s: float | None = None,
                 amplitude: float | None = None, time_constant_s: float | None = None,
                 offset: float = 0.0) -> None:
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self.offset = _finite(offset, "zero_drift offset")
        if rate_per_s is not None and amplitude is None and time_constant_s is None:
            self.linear = True
            self.rate_per_s = _finite(rate_per_s, "zero_drift rate_per_s")
            self._lam = 1.0
        elif rate_per_s is None and amplitude is not None and time_constant_s is not None:
            self.linear = False
            self.amplitude = _finite(amplitude, "zero_drift amplitude")
            self.time_constant_s = _positive(time_constant_s, "zero_drift time_constant_s")
            self._lam = math.exp(-1.0 / (self.time_constant_s * self.fs_hz))
        else:
            raise ValueError("zero_drift takes rate_per_s, or amplitude and time_constant_s")
        self._xs = np.zeros(2)
        self.reset()

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> ZeroDrift:
        p = {k: float(v) for k, v in params.items()}
        return cls(fs_hz, rate_per_s=p.get("rate_per_s"), amplitude=p.get("amplitude"),
                   time_constant_s=p.get("time_constant_s"), offset=p.get("offset", 0.0))

    def params(self) -> dict[str, float]:
        if self.linear:
            return {"rate_per_s": self.rate_per_s, "offset": self.offset}
        return {"amplitude": self.amplitude, "time_constant_s": self.time_constant_s,
                "offset": self.offset}

    def _initial(self) -> tuple[float, float]:
        if self.linear:
            s = self.rate_per_s / self.fs_hz
            return self.offset - s, s
        return -self.amplitude / self._lam, self.offset + self.amplitude

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self.linear:
            return (np.array([[1.0, 1.0], [0.0, 1.0]]), np.zeros(2), np.array([1.0, 0.0]),
                    np.array(1.0))
        return (np.diag([self._lam, 1.0]), np.zeros(2), np.array([1.0, 1.0]), np.array(1.0))

    def step(self, dcl: float) -> float:
        if self.linear:
            self._x0 = self._x0 + self._x1
            return dcl + self._x0
        self._x0 = self._lam * self._x0
        return dcl + (self._x0 + self._x1)

    def simulate(self, dcl: np.ndarray) -> np.ndarray:
        u = np.asarray(dcl, dtype=float)
        n = u.size
        if n == 0:
            return u.copy()
        if self.linear:
            x0 = np.cumsum(np.concatenate([[self._x0], np.full(n, self._x1)]))[1:]
            self._x0 = float(x0[-1])
            return u + x0
        x0 = np.cumprod(np.concatenate([[self._x0], np.full(n, self._lam)]))[1:]
        self._x0 = float(x0[-1])
        return u + (x0 + self._x1)
