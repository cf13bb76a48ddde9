"""Wiener block: LTI dynamics followed by a static nonlinearity (paper eqs. 4–6).

    x(k) = A x(k−1) + B Cμ(k),   y(k) = C x(k),   ΔCL_L(k) = N(Cμ(k)) · y(k)

``N(Cμ) = ΔCL/Cμ`` from the static map is a lookup table (:class:`InputGain`, the paper's
form: a gain scheduled on the *input*). The textbook Wiener form ``ΔCL_L = f(y)`` is
:class:`OutputNonlinearity`. Both are linear interpolants with the same formula in the
streaming and batch paths (that of ``numpy.interp``), so the two agree to rounding.
"""

from __future__ import annotations

from bisect import bisect_right
from typing import Any

import numpy as np
from scipy import signal

from rtlift.blocks.lti import LTIBlock


def _check_table(x: np.ndarray, f: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float).ravel()
    f = np.asarray(f, dtype=float).ravel()
    if x.size < 2 or x.size != f.size:
        raise ValueError(f"{what} table needs two or more points and equal lengths")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise ValueError(f"{what} table must be finite")
    if np.any(np.diff(x) <= 0):
        raise ValueError(f"{what} table grid must be strictly increasing")
    return x, f


class _Table:
    """Piecewise-linear ``f(x)`` on a grid; ``extrapolate`` continues the end segments,
    otherwise the end values are held (numpy.interp's behaviour)."""

    def __init__(self, x: np.ndarray, f: np.ndarray, extrapolate: bool) -> None:
        self.x, self.f = x, f
        self.extrapolate = extrapolate
        self._x = [float(v) for v in x]
        self._f = [float(v) for v in f]
        self._slope = [float(v) for v in np.diff(f) / np.diff(x)]
        self._last = len(self._x) - 1

    def __call__(self, v: float) -> float:
        xs = self._x
        j = bisect_right(xs, v) - 1
        if j < 0:
            return self._slope[0] * (v - xs[0]) + self._f[0] if self.extrapolate else self._f[0]
        if j >= self._last:
            if v == xs[-1] or not self.extrapolate:
                return self._f[-1]
            return self._slope[-1] * (v - xs[-1]) + self._f[-1]
        return self._slope[j] * (v - xs[j]) + self._f[j]

    def batch(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        if not self.extrapolate:
            return np.interp(v, self.x, self.f)            # the same formula, compiled
        j = np.clip(np.searchsorted(self.x, v, side="right") - 1, 0, self._last - 1)
        slope = np.asarray(self._slope)[j]
        out = slope * (v - self.x[j]) + self.f[j]
        below, above = v < self.x[0], v >= self.x[-1]
        if self.extrapolate:
            out[above] = slope[above] * (v[above] - self.x[-1]) + self.f[-1]
            out[v == self.x[-1]] = self.f[-1]
        else:
            out[below] = self.f[0]
            out[above] = self.f[-1]
        return out


class _Stateless:
    """A static nonlinearity: no state to reset, get or set."""

    state_size = 0

    def reset(self) -> None:
        pass

    def get_state(self) -> np.ndarray:
        return np.empty(0)

    def set_state(self, state: np.ndarray) -> None:
        if np.asarray(state).size:
            raise ValueError(f"{type(self).__name__} has no state")


class InputGain(_Stateless):
    """N(Cμ)·y — the paper's gain scheduled on the input (eq. 6), N from a (Cμ, N) table.

    Outside the table N is held at its end values: below the first point N is the static
    map's limit slope, beyond the last the map continues along its last chord.
    """

    form = "input_gain"

    def __init__(self, cmu: np.ndarray, gain: np.ndarray) -> None:
        self.cmu, self.gain = _check_table(cmu, gain, "N(Cmu)")
        self._n = _Table(self.cmu, self.gain, extrapolate=False)

    def step(self, cmu: float, y: float) -> float:
        return self._n(cmu) * y

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self._n.batch(cmu) * np.asarray(y, dtype=float)

    def gain_at(self, cmu: float) -> float:
        """N(Cμ) (the observer's time-varying measurement gain)."""
        return self._n(cmu)

    def to_dict(self) -> dict[str, Any]:
        return {"form": self.form, "cmu": self.cmu.tolist(), "gain": self.gain.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InputGain:
        return cls(d["cmu"], d["gain"])


class HysteresisGain(InputGain):
    """N(Cμ)·y·(1 + m h) — the paper's gain with a direction-dependent factor (``hysteresis``):

        s(k) = 1 if Cμ(k) < Cμ(k−1),  0 if Cμ(k) > Cμ(k−1),  s(k−1) otherwise (held)
        h(k) = λ h(k−1) + (1 − λ) s(k),   λ = exp(−1/(τ fs))  (λ = 0 for τ = 0)
        ΔCL_L(k) = N(Cμ(k)) · y(k) · (1 + m h(k))

    so the static gain on falling Cμ is (1 + m) times that on rising Cμ, the switch relaxing in
    τ. ``magnitude`` = m, ``time_constant_s`` = τ. State: [h, s, Cμ(k−1)].
    """

    form = "input_gain_hysteresis"

    def __init__(self, cmu: np.ndarray, gain: np.ndarray, magnitude: float,
                 time_constant_s: float, fs_hz: float) -> None:
        super().__init__(cmu, gain)
        m, tau, fs = float(magnitude), float(time_constant_s), float(fs_hz)
        if not (np.isfinite(m) and np.isfinite(tau) and np.isfinite(fs)) or tau < 0 or fs <= 0:
            raise ValueError("hysteresis needs a finite magnitude, time_constant_s >= 0, fs_hz > 0")
        self.magnitude, self.time_constant_s, self.fs_hz = m, tau, fs
        self._lam = float(np.exp(-1.0 / (tau * fs))) if tau > 0 else 0.0
        self.h = self.s = self.last = 0.0

    state_size = 3

    def step(self, cmu: float, y: float) -> float:
        if cmu < self.last:
            self.s = 1.0
        elif cmu > self.last:
            self.s = 0.0
        self.last = cmu
        self.h = (1.0 - self._lam) * self.s + self._lam * self.h
        return self._n(cmu) * y * (1.0 + self.magnitude * self.h)

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        cmu = np.asarray(cmu, dtype=float)
        if cmu.size == 0:
            return cmu.copy()
        step = np.diff(cmu, prepend=self.last)
        idx = np.where(step != 0.0, np.arange(cmu.size), -1)
        last_change = np.maximum.accumulate(idx)
        s = np.where(last_change >= 0, (step[np.maximum(last_change, 0)] < 0.0).astype(float), self.s)
        h, _ = signal.lfilter([1.0 - self._lam], [1.0, -self._lam], s, zi=[self._lam * self.h])
        self.h, self.s, self.last = float(h[-1]), float(s[-1]), float(cmu[-1])
        return self._n.batch(cmu) * np.asarray(y, dtype=float) * (1.0 + self.magnitude * h)

    def reset(self) -> None:
        self.h = self.s = self.last = 0.0

    def get_state(self) -> np.ndarray:
        return np.array([self.h, self.s, self.last])

    def set_state(self, state: np.ndarray) -> None:
        st = np.asarray(state, dtype=float)
        if st.shape != (3,):
            raise ValueError(f"hysteresis state must have shape (3,), got {st.shape}")
        self.h, self.s, self.last = (float(v) for v in st)

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "magnitude": self.magnitude,
                "time_constant_s": self.time_constant_s, "fs_hz": self.fs_hz}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HysteresisGain:
        return cls(d["cmu"], d["gain"], d["magnitude"], d["time_constant_s"], d["fs_hz"])


class OutputNonlinearity(_Stateless):
    """f(y) — the textbook Wiener output nonlinearity, a (y, f) table, linear beyond its ends."""

    form = "output"

    def __init__(self, y: np.ndarray, f: np.ndarray) -> None:
        self.y, self.f = _check_table(y, f, "f(y)")
        self._f = _Table(self.y, self.f, extrapolate=True)

    def step(self, cmu: float, y: float) -> float:
        return self._f(y)

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self._f.batch(y)

    def slope_at(self, y: float) -> float:
        """df/dy at y (for an extended Kalman observer)."""
        j = min(max(bisect_right(self._f._x, y) - 1, 0), self._f._last - 1)
        return self._f._slope[j]

    def to_dict(self) -> dict[str, Any]:
        return {"form": self.form, "y": self.y.tolist(), "f": self.f.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OutputNonlinearity:
        return cls(d["y"], d["f"])


NONLINEARITIES: dict[str, Any] = {InputGain.form: InputGain, OutputNonlinearity.form: OutputNonlinearity,
                                  HysteresisGain.form: HysteresisGain}


class WienerBlock:
    """x(k) = A x(k−1) + B Cμ(k), y(k) = C x(k), ΔCL_L(k) = nl(Cμ(k), y(k))."""

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, nonlinearity: Any) -> None:
        self.lti = LTIBlock(A, B, C)
        self.nonlinearity = nonlinearity
        self.y = 0.0

    A = property(lambda self: self.lti.A)
    B = property(lambda self: self.lti.B)
    C = property(lambda self: self.lti.C)

    @property
    def state_size(self) -> int:
        return self.lti.state_size + self.nonlinearity.state_size

    def step(self, cmu: float) -> float:
        y = self.lti.step(cmu)
        self.y = y
        return self.nonlinearity.step(cmu, y)

    def simulate(self, cmu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch twin: (ΔCL_L, y) over ``cmu``; advances the state."""
        cmu = np.asarray(cmu, dtype=float)
        y = self.lti.simulate(cmu)
        if y.size:
            self.y = float(y[-1])
        return self.nonlinearity.simulate(cmu, y), y

    def reset(self) -> None:
        self.lti.reset()
        self.nonlinearity.reset()
        self.y = 0.0

    def get_state(self) -> np.ndarray:
        return np.concatenate([self.lti.get_state(), self.nonlinearity.get_state()])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        n = self.lti.state_size
        if s.shape != (self.state_size,):
            raise ValueError(f"Wiener state must have shape ({self.state_size},), got {s.shape}")
        self.lti.set_state(s[:n])
        self.nonlinearity.set_state(s[n:])
        self.y = float(self.lti.C @ s[:n])
