"""The ``interaction`` structure's input stages (not effects): what the actuators deliver.

- ``delivered_momentum`` (as first merged): Cμ_env′(k) = m(k) = λ m(k−1) + (1 − λ) Cμ(k)/d,
  λ = exp(−1/(τ fs)); Cμ′ = Cμ.
- ``delivered_envelope`` (the structure's Wiener input): Cμ_env′(k) = Cμ_env(k) · min(1, q(k)/q₀),
  q(k) = λ q(k−1) + (1 − λ) [Cμ(k) > 0], q₀ the minimum of q at the lift-optimal burst rate
  (:func:`optimal_rate_floor`); Cμ′ = Cμ. With a static map (``lift``, issue 31):
  Cμ_env′(k) = f(Cμ_env(k))/s · min(1, q(k)/q₀)^p, f(Cμ) = N(Cμ)·Cμ the map, s its last chord.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.blocks.stage_base import InputStage, _positive, _state_shaped
from rtlift.blocks.wiener import _check_table, _Table

STRUCTURE_STAGES = ("delivered_momentum", "delivered_envelope")
"""The interaction structure's own input stages (not effects): an effect's input stage (a fade,
a delay) acts on the actuation they see, so it goes before them (:func:`rtlift.effects.surgery.augment`)."""


class DeliveredMomentum(InputStage):
    """``m(k) = λ m(k−1) + (1 − λ) Cμ(k)/d``, ``λ = exp(−1/(τ fs))``; maps (Cμ, Cμ_env) to
    (Cμ, m). ``time_constant_s`` = τ > 0, ``duty`` = d ∈ (0, 1]. State: [m(k)]."""

    name = "delivered_momentum"
    state_size = 1

    def __init__(self, time_constant_s: float, duty: float, fs_hz: float) -> None:
        tau, d, fs = float(time_constant_s), float(duty), float(fs_hz)
        if not (math.isfinite(tau) and tau > 0):
            raise ValueError(f"delivered_momentum time_constant_s must be positive, got {time_constant_s}")
        if not (math.isfinite(d) and 0 < d <= 1):
            raise ValueError(f"delivered_momentum duty must be in (0, 1], got {duty}")
        if not (math.isfinite(fs) and fs > 0):
            raise ValueError(f"fs_hz must be positive, got {fs_hz}")
        self.time_constant_s, self.duty, self.fs_hz = tau, d, fs
        self._lam = math.exp(-1.0 / (tau * fs))
        self._b = 1.0 - self._lam
        self._inv_d = 1.0 / d
        self._m = np.zeros(1)           # numpy, so the compiled step advances it too

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> DeliveredMomentum:
        return cls(float(params["time_constant_s"]), float(params["duty"]), fs_hz)

    def params(self) -> dict[str, float]:
        return {"time_constant_s": self.time_constant_s, "duty": self.duty}

    def momentum(self, cmu: float) -> float:
        """One sample of m (what :meth:`step` returns as the envelope)."""
        m = self._b * (cmu * self._inv_d) + self._lam * self._m.item()
        self._m[0] = m
        return m

    def kernel_arrays(self) -> tuple[tuple[float, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: parameters (λ, 1 − λ, 1/d) and state (m,), not a copy."""
        return (self._lam, self._b, self._inv_d), (self._m,)

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        return cmu, self.momentum(cmu)

    def momentum_batch(self, cmu: np.ndarray) -> np.ndarray:
        """Batch twin of :meth:`momentum` (``lfilter`` with the state as ``zi``)."""
        cmu = np.asarray(cmu, dtype=float)
        if cmu.size == 0:
            return cmu.copy()
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        m, _ = signal.lfilter([self._b], [1.0, -self._lam], cmu * self._inv_d, zi=[self._lam * self._m.item()])
        self._m[0] = m[-1]
        return m

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        return cmu.copy(), self.momentum_batch(cmu)

    def get_state(self) -> np.ndarray:
        return self._m.copy()

    def set_state(self, state: np.ndarray) -> None:
        self._m[0] = _state_shaped(state, self.name, 1)[0]


class DeliveredEnvelope(InputStage):
    """The envelope where bursts fire at least at the lift-optimal rate, less where they fire
    more sparsely (the Wiener input of the ``interaction`` structure, issue 31)::

        q(k) = λ q(k−1) + (1 − λ) [Cμ(k) > 0],   λ = exp(−1/(τ fs))
        u(k) = Cμ_env(k) · min(1, q(k)/q₀)

    maps (Cμ, Cμ_env) to (Cμ, u). q is the recent fraction of samples with a burst on, q₀ its
    minimum under bursting at the lift-optimal period (``burst_samples`` on in every
    ``period_samples``, :func:`optimal_rate_floor`): at that rate or denser u is the envelope
    itself, the paper's hybrid's Wiener input, with no lag; after an isolated burst or between
    the bursts of a sparse train u falls with the memory q. ``time_constant_s`` = τ > 0.

    With ``lift`` = (Cμ grid, N) the static map's gain table (f(Cμ) = N(Cμ)·Cμ, N held at the
    table's ends) and ``power`` p, the stage puts the static map before the Wiener LTI (a
    Hammerstein slow part, issue 31)::

        u(k) = f(Cμ_env(k)) / s · min(1, q(k)/q₀)^p,   s = N(Cμ_max) = f(Cμ_max)/Cμ_max

    u is the static lift of the envelope, in envelope units (u = Cμ_env at Cμ_max), falling as
    the p-th power of the delivered burst rate below the lift-optimal one. A Wiener part
    s·C x(k), x(k) = A x(k−1) + B u(k), then settles at f(Cμ_env) for every held envelope at
    that rate or denser, and its mean over an amplitude-modulated record is the mean of f over
    the envelope — what the independent plant's lift does on every record (issue 31).
    State: [q(k)]."""

    name = "delivered_envelope"
    state_size = 1

    def __init__(self, time_constant_s: float, burst_samples: int, period_samples: int, fs_hz: float,
                 lift: tuple[np.ndarray, np.ndarray] | None = None, power: float = 1.0) -> None:
        tau, fs = _positive(time_constant_s, "delivered_envelope time_constant_s"), _positive(fs_hz, "fs_hz")
        on, period = int(burst_samples), int(period_samples)
        if not 0 < on <= period:
            raise ValueError(f"delivered_envelope needs 0 < burst_samples <= period_samples, got {on}, {period}")
        self.time_constant_s, self.burst_samples, self.period_samples, self.fs_hz = tau, on, period, fs
        self._lam = math.exp(-1.0 / (tau * fs))
        self._b = 1.0 - self._lam
        self._scale = 1.0 / optimal_rate_floor(self._lam, on, period)
        self._q = np.zeros(1)           # numpy, so the compiled step advances it too
        self.lift: _Table | None = None
        self.power = _positive(power, "delivered_envelope power") if lift is not None else 1.0
        if lift is not None:
            grid, gain = _check_table(lift[0], lift[1], "delivered_envelope lift N(Cmu)")
            if gain[-1] <= 0:
                raise ValueError("delivered_envelope lift: N at the table's end must be positive")
            self.lift = _Table(grid, gain, extrapolate=False)
            self._chord = float(gain[-1])
            self._inv_chord = 1.0 / self._chord

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> DeliveredEnvelope:
        lift = params.get("lift")
        return cls(float(params["time_constant_s"]), int(params["burst_samples"]), int(params["period_samples"]),
                   fs_hz, None if lift is None else (np.asarray(lift["cmu"], float), np.asarray(lift["gain"], float)),
                   float(params.get("power", 1.0)))

    def params(self) -> dict[str, Any]:
        out: dict[str, Any] = {"time_constant_s": self.time_constant_s, "burst_samples": self.burst_samples,
                               "period_samples": self.period_samples}
        if self.lift is not None:
            out.update(lift={"cmu": self.lift.x.tolist(), "gain": self.lift.f.tolist()}, power=self.power)
        return out

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        q = self._b * (1.0 if cmu > 0.0 else 0.0) + self._lam * self._q.item()
        self._q[0] = q
        gate = min(1.0, self._scale * q)
        if self.lift is None:
            return cmu, env * gate
        return cmu, self.steady(env) * gate_power(gate, self.power)

    @property
    def chord(self) -> float:
        """s, the static map's last chord N(Cμ_max) (1 without a map): the Wiener part's constant N."""
        return self._chord if self.lift is not None else 1.0

    def steady(self, env: float) -> float:
        """u for an envelope held while bursts fire at the lift-optimal rate or denser (gate 1):
        the envelope, or its static lift f(Cμ_env)/s."""
        return env if self.lift is None else self.lift(env) * env * self._inv_chord

    def kernel_arrays(self) -> tuple[tuple[float, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: parameters (λ, 1 − λ, 1/q₀) and state (q,), not a copy."""
        return (self._lam, self._b, self._scale), (self._q,)

    def lift_arrays(self) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
        """For the compiled step: (p, 1/s, grid, N, slopes); an empty grid without a map."""
        if self.lift is None:
            return 1.0, 1.0, np.zeros(0), np.zeros(0), np.zeros(0)
        return self.power, self._inv_chord, self.lift.x, self.lift.f, self.lift.slope

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(env, dtype=float)
        if cmu.size == 0:
            return cmu.copy(), env.copy()
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        q, _ = signal.lfilter([self._b], [1.0, -self._lam], (cmu > 0).astype(float), zi=[self._lam * self._q.item()])
        self._q[0] = q[-1]
        gate = np.minimum(1.0, self._scale * q)
        if self.lift is None:
            return cmu.copy(), env * gate
        return cmu.copy(), self.lift.batch(env) * env * self._inv_chord * gate_power(gate, self.power)

    def get_state(self) -> np.ndarray:
        return self._q.copy()

    def set_state(self, state: np.ndarray) -> None:
        self._q[0] = _state_shaped(state, self.name, 1)[0]


def gate_power(gate, power: float):
    """gate^p (a float or an array): for a whole p in 1 … 8 by repeated products, left to right
    (the compiled step's order, and no pow call on the hot path), else ``**``."""
    n = int(power)
    if n == power and 0 < n <= 8:
        out = gate
        for _ in range(n - 1):
            out = out * gate
        return out
    return gate ** power


def optimal_rate_floor(lam: float, burst_samples: int, period_samples: int) -> float:
    """The minimum over a period of q(k) = λ q(k−1) + (1 − λ) x(k) in the periodic steady state of
    x = ``burst_samples`` ones then zeros, every ``period_samples``: q just before a burst,
    (1 − λ^on) λ^(T − on) / (1 − λ^T)."""
    on, period = int(burst_samples), int(period_samples)
    return (1.0 - lam ** on) * lam ** (period - on) / (1.0 - lam ** period)
