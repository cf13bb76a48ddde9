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
        self.slope = np.ascontiguousarray(np.diff(f) / np.diff(x))
        self._slope = [float(v) for v in self.slope]
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
    kernel_kind: int | None = 0
    """How :mod:`rtlift.blocks.compiled` evaluates this form (None: it does not)."""

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

    def kernel_arrays(self) -> tuple[np.ndarray, ...]:
        """(grid, values, slopes) of the N(Cμ) table, for the compiled step."""
        return self._n.x, self._n.f, self._n.slope

    def to_dict(self) -> dict[str, Any]:
        return {"form": self.form, "cmu": self.cmu.tolist(), "gain": self.gain.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InputGain:
        return cls(d["cmu"], d["gain"])


class _DirectionMemory:
    """The direction-dependent factor of the ``hysteresis`` effect, a play operator of width w
    (the Prandtl–Ishlinskii / Preisach element) on a driver x, followed by a first-order
    relaxation:

        p(k) = min(max(p(k−1), x(k) − w/2), x(k) + w/2),   s(k) = (p(k) − x(k))/w + 1/2
        (w = 0:  s(k) = 1 if x(k) < x(k−1), 0 if x(k) > x(k−1), s(k−1) otherwise)
        h(k) = λ h(k−1) + (1 − λ) s(k),   λ = exp(−1/(τ fs))  (λ = 0 for τ = 0)
        factor(k) = g (1 + m h(k))

    The driver is the actuation, x = Cμ (``driver = "cmu"``: the gain remembers which way the
    command last moved), or the flow's own state, x = q + ``offset``, the flow's quasi-steady
    lift (``driver = "lift"``: stall hysteresis, where whether the flow reattaches depends on
    the lift it has, which lags the command by the LTI's dynamics): q the nonlinearity's own
    lift before the factor (N(Cμ)·y or f(y)), ``offset`` the rest of the model's slow lift, the
    interaction structure's burst slow term G(m)(c − HF c) + S(u)u, which carries about half of
    its static lift (0 in the paper's structure, whose burst part is high-passed). The model
    sets ``offset`` before each :meth:`step` (a float) or ``simulate`` (an array of the chunk's
    length): :meth:`rtlift.model.hybrid.HybridModel.parts_step`. The factor scales q only.

    s is 0 on the rising branch, 1 on the falling one, and crosses between them while x reverses
    by less than w (small reversals do not switch branch). The gain on a falling driver is
    (1 + m) times that on a rising one; the rising branch is g times the identified map (a map
    swept up and down is the mean of the two branches: g < 1 < g (1 + m)).
    ``magnitude`` = m, ``rising_gain`` = g, ``width`` = w (in the driver's unit: Cμ or ΔCL),
    ``time_constant_s`` = τ, ``driver``. State: [h, s, p] (w > 0) or [h, s, x(k−1)] (w = 0);
    at rest p = −w/2 (the rising branch).
    """

    DRIVERS = ("cmu", "lift")

    state_size = 3
    h = property(lambda self: float(self._hs[0]), lambda self, v: self._hs.__setitem__(0, v))
    s = property(lambda self: float(self._hs[1]), lambda self, v: self._hs.__setitem__(1, v))
    last = property(lambda self: float(self._hs[2]), lambda self, v: self._hs.__setitem__(2, v))
    """The state [h, s, p or x(k−1)] lives in the array ``_hs`` (the compiled step advances it)."""

    def _init_memory(self, magnitude: float, time_constant_s: float, fs_hz: float, width: float = 0.0,
                     rising_gain: float = 1.0, driver: str = "cmu") -> None:
        if driver not in self.DRIVERS:
            raise ValueError(f"hysteresis driver must be one of {', '.join(self.DRIVERS)}, got {driver!r}")
        self.driver = driver
        m, tau, fs, w, g = (float(v) for v in (magnitude, time_constant_s, fs_hz, width, rising_gain))
        if not all(np.isfinite(v) for v in (m, tau, fs, w, g)) or tau < 0 or fs <= 0 or w < 0 or g <= 0:
            raise ValueError("hysteresis needs a finite magnitude, rising_gain > 0, width >= 0, "
                             "time_constant_s >= 0, fs_hz > 0")
        self.magnitude, self.time_constant_s, self.fs_hz, self.width = m, tau, fs, w
        self.rising_gain = g
        self._lam = float(np.exp(-1.0 / (tau * fs))) if tau > 0 else 0.0
        self._hs = np.zeros(3)
        self.reset()

    def _factor_step(self, cmu: float, q: float) -> float:
        x = cmu if self.driver == "cmu" else q + self.offset
        if self.width > 0.0:
            half = 0.5 * self.width
            p = min(max(self.last, x - half), x + half)
            self.last = p
            self.s = (p - x) / self.width + 0.5
        else:
            if x < self.last:
                self.s = 1.0
            elif x > self.last:
                self.s = 0.0
            self.last = x
        self.h = (1.0 - self._lam) * self.s + self._lam * self.h
        return self.rising_gain * (1.0 + self.magnitude * self.h)

    def factor(self) -> float:
        """g (1 + m h) in force (after this sample's step; for the observer's gain)."""
        return self.rising_gain * (1.0 + self.magnitude * self.h)

    def branch(self, cmu: np.ndarray, q: np.ndarray) -> np.ndarray:
        """h(k) over a chunk (Cμ and the quasi-steady lift q), advancing the state."""
        x = np.asarray(cmu if self.driver == "cmu" else q + self.offset, dtype=float)
        if self.width > 0.0:                 # the play operator is a recursion: one pass
            half, inv = 0.5 * self.width, 1.0 / self.width
            s = np.empty(x.size)
            p = self.last
            for k, c in enumerate(x.tolist()):
                p = min(max(p, c - half), c + half)
                s[k] = (p - c) * inv + 0.5
            self.last = p
        else:
            step = np.diff(x, prepend=self.last)
            idx = np.where(step != 0.0, np.arange(x.size), -1)
            last_change = np.maximum.accumulate(idx)
            s = np.where(last_change >= 0, (step[np.maximum(last_change, 0)] < 0.0).astype(float), self.s)
            self.last = float(x[-1])
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        h, _ = signal.lfilter([1.0 - self._lam], [1.0, -self._lam], s, zi=[self._lam * self.h])
        self.h, self.s = float(h[-1]), float(s[-1])
        return h

    def _factor_batch(self, cmu: np.ndarray, q: np.ndarray) -> np.ndarray:
        return self.rising_gain * (1.0 + self.magnitude * self.branch(cmu, q))

    def reset(self) -> None:
        self.h = self.s = 0.0
        self.last = -0.5 * self.width
        self.offset: float | np.ndarray = 0.0

    def get_state(self) -> np.ndarray:
        return np.array([self.h, self.s, self.last])

    def set_state(self, state: np.ndarray) -> None:
        st = np.asarray(state, dtype=float)
        if st.shape != (3,):
            raise ValueError(f"hysteresis state must have shape (3,), got {st.shape}")
        self.h, self.s, self.last = (float(v) for v in st)

    def memory_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """For the compiled step: the parameters [m, g, w, λ, driver is "lift"] (a copy) and the
        state array [h, s, p] itself (:func:`rtlift.blocks.compiled_stages._direction_factor`)."""
        par = np.array([self.magnitude, self.rising_gain, self.width, self._lam, float(self.driver == "lift")])
        return par, self._hs

    def adopt_state(self, view: np.ndarray) -> None:
        """Hold [h, s, p] in ``view`` (already holding them) from now on (the compiled step's array)."""
        self._hs = view

    def _memory_dict(self) -> dict[str, Any]:
        return {"magnitude": self.magnitude, "rising_gain": self.rising_gain, "width": self.width,
                "time_constant_s": self.time_constant_s, "fs_hz": self.fs_hz, "driver": self.driver}


class HysteresisGain(_DirectionMemory, InputGain):
    """N(Cμ)·y·(1 + m h) — the paper's gain with the direction-dependent factor of
    :class:`_DirectionMemory` (``hysteresis`` on the paper's form)."""

    form = "input_gain_hysteresis"
    kernel_kind = 0            # the paper's table, times the factor (rtlift.blocks.compiled_stages)

    def __init__(self, cmu: np.ndarray, gain: np.ndarray, magnitude: float,
                 time_constant_s: float, fs_hz: float, width: float = 0.0, rising_gain: float = 1.0,
                 driver: str = "cmu") -> None:
        InputGain.__init__(self, cmu, gain)
        self._init_memory(magnitude, time_constant_s, fs_hz, width, rising_gain, driver)

    def step(self, cmu: float, y: float) -> float:
        q = self._n(cmu) * y
        return q * self._factor_step(cmu, q)

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        cmu = np.asarray(cmu, dtype=float)
        if cmu.size == 0:
            return cmu.copy()
        q = self._n.batch(cmu) * np.asarray(y, dtype=float)
        return q * self._factor_batch(cmu, q)

    def to_dict(self) -> dict[str, Any]:
        return {**InputGain.to_dict(self), **self._memory_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HysteresisGain:
        return cls(d["cmu"], d["gain"], d["magnitude"], d["time_constant_s"], d["fs_hz"], d.get("width", 0.0),
                   d.get("rising_gain", 1.0), d.get("driver", "cmu"))


class OutputNonlinearity(_Stateless):
    """f(y) — the textbook Wiener output nonlinearity, a (y, f) table, linear beyond its ends."""

    form = "output"
    kernel_kind: int | None = 1

    def __init__(self, y: np.ndarray, f: np.ndarray) -> None:
        self.y, self.f = _check_table(y, f, "f(y)")
        self._f = _Table(self.y, self.f, extrapolate=True)

    def step(self, cmu: float, y: float) -> float:
        return self._f(y)

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self._f.batch(y)

    def output_at(self, cmu: float, y: float) -> float:
        """f(y) without advancing any state (the observer's evaluation at its estimate)."""
        return self._f(y)

    def kernel_arrays(self) -> tuple[np.ndarray, ...]:
        """(grid, values, slopes) of the f(y) table, for the compiled step."""
        return self._f.x, self._f.f, self._f.slope

    def slope_at(self, y: float) -> float:
        """df/dy at y (for an extended Kalman observer)."""
        j = min(max(bisect_right(self._f._x, y) - 1, 0), self._f._last - 1)
        return self._f._slope[j]

    def to_dict(self) -> dict[str, Any]:
        return {"form": self.form, "y": self.y.tolist(), "f": self.f.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OutputNonlinearity:
        return cls(d["y"], d["f"])


class OutputHysteresis(_DirectionMemory, OutputNonlinearity):
    """f(y)·(1 + m h) — the textbook form with the direction-dependent factor of
    :class:`_DirectionMemory` (``hysteresis`` on the textbook form). :meth:`output_at` and
    :meth:`slope_at` use the factor in force (after this sample's :meth:`step`)."""

    form = "output_hysteresis"
    kernel_kind = 1            # the textbook table, times the factor (rtlift.blocks.compiled_stages)

    def __init__(self, y: np.ndarray, f: np.ndarray, magnitude: float, time_constant_s: float,
                 fs_hz: float, width: float = 0.0, rising_gain: float = 1.0, driver: str = "cmu") -> None:
        OutputNonlinearity.__init__(self, y, f)
        self._init_memory(magnitude, time_constant_s, fs_hz, width, rising_gain, driver)

    def step(self, cmu: float, y: float) -> float:
        q = self._f(y)
        return q * self._factor_step(cmu, q)

    def simulate(self, cmu: np.ndarray, y: np.ndarray) -> np.ndarray:
        cmu = np.asarray(cmu, dtype=float)
        if cmu.size == 0:
            return cmu.copy()
        q = self._f.batch(y)
        return q * self._factor_batch(cmu, q)

    def output_at(self, cmu: float, y: float) -> float:
        return self._f(y) * self.factor()

    def slope_at(self, y: float) -> float:
        return OutputNonlinearity.slope_at(self, y) * self.factor()

    def to_dict(self) -> dict[str, Any]:
        return {**OutputNonlinearity.to_dict(self), **self._memory_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OutputHysteresis:
        return cls(d["y"], d["f"], d["magnitude"], d["time_constant_s"], d["fs_hz"], d.get("width", 0.0),
                   d.get("rising_gain", 1.0), d.get("driver", "cmu"))


NONLINEARITIES: dict[str, Any] = {c.form: c for c in (InputGain, OutputNonlinearity, HysteresisGain,
                                                        OutputHysteresis)}


class WienerBlock:
    """x(k) = A x(k−1) + B Cμ(k), y(k) = C x(k), ΔCL_L(k) = nl(Cμ(k), y(k))."""

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, nonlinearity: Any) -> None:
        self.lti = LTIBlock(A, B, C)
        self.nonlinearity = nonlinearity

    @property
    def y(self) -> float:
        """y(k) = C x(k) of the last step (before the nonlinearity)."""
        return float(self.lti.C @ self.lti.get_state())

    A = property(lambda self: self.lti.A)
    B = property(lambda self: self.lti.B)
    C = property(lambda self: self.lti.C)

    @property
    def state_size(self) -> int:
        return self.lti.state_size + self.nonlinearity.state_size

    def step(self, cmu: float) -> float:
        return self.nonlinearity.step(cmu, self.lti.step(cmu))

    def kernel_arrays(self) -> tuple[tuple[Any, ...], tuple[np.ndarray, ...]] | None:
        """For the compiled step: parameters (A, B, C, form, grid, values, slopes) and state
        (x,), or None when the nonlinearity has no compiled form (``kernel_kind`` None)."""
        kind = getattr(self.nonlinearity, "kernel_kind", None)
        if kind is None:
            return None
        lti_par, lti_state = self.lti.kernel_arrays()
        return (*lti_par, kind, *self.nonlinearity.kernel_arrays()), lti_state

    def simulate(self, cmu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch twin: (ΔCL_L, y) over ``cmu``; advances the state."""
        cmu = np.asarray(cmu, dtype=float)
        y = self.lti.simulate(cmu)
        return self.nonlinearity.simulate(cmu, y), y

    def reset(self) -> None:
        self.lti.reset()
        self.nonlinearity.reset()

    def get_state(self) -> np.ndarray:
        return np.concatenate([self.lti.get_state(), self.nonlinearity.get_state()])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        n = self.lti.state_size
        if s.shape != (self.state_size,):
            raise ValueError(f"Wiener state must have shape ({self.state_size},), got {s.shape}")
        self.lti.set_state(s[:n])
        self.nonlinearity.set_state(s[n:])
