"""Augmentation stages: effects the paper's model lacks, added around the hybrid model.

An *input stage* maps the actuation record before the model sees it,
``(Cμ, Cμ_env) → (Cμ′, Cμ_env′)`` (a delay, a fading actuator); an *output stage* maps the
model's ΔCL to what the balance reports, ``ΔCL → ΔCL′`` (a sensor mode, a drift, a pickup).
Every stage is a streaming block (``step``, batch twin ``simulate``, explicit state) and is
named and parametrised as in INTERFACES.md, so a model file can list it and
:data:`STAGES` (built from the effect registry, :mod:`rtlift.core.registry`) can rebuild it with
``from_params(params, fs_hz)``.

Catalog (``name``: equation; k = 0 is the first sample after ``reset()``, t_k = k / fs):

- ``delay`` (input): Cμ′(k) = Cμ(k − D), D = round(seconds · fs).
- ``actuator_fade`` (input): g(k) = f + (1 − f) exp(−E(k)/τ), Cμ′ = g Cμ, Cμ_env′ = g Cμ_env,
  E(k) the burst on-time (s) accumulated *before* sample k (E += 1/fs while Cμ(k) > 0), or
  the wall time (``clock`` "time").
- ``delivered_momentum`` (input, part of the ``interaction`` structure as first merged, not an
  effect): Cμ_env′(k) = m(k) = λ m(k−1) + (1 − λ) Cμ(k)/d, λ = exp(−1/(τ fs)); Cμ′ = Cμ.
- ``delivered_envelope`` (input, the ``interaction`` structure's Wiener input, not an effect):
  Cμ_env′(k) = Cμ_env(k) · min(1, q(k)/q₀), q(k) = λ q(k−1) + (1 − λ) [Cμ(k) > 0], q₀ the
  minimum of q at the lift-optimal burst rate; Cμ′ = Cμ.
- ``sensor_resonance`` (output, kind "filter"): the unity-DC-gain mode
  ω²/(s² + 2ζωs + ω²), bilinear with pre-warping at ω (as on the bench).
- ``zero_drift`` (output, kind "additive"): d(k) = offset + rate · t_k, or
  d(k) = offset + amplitude (1 − exp(−t_k/τ)); ``offset`` is the tare's share of the drift.
- ``periodic_disturbance`` (output, kind "additive"): d(k) = Σ_i A_i sin(2π f_i t_k + φ_i), a
  fundamental and its harmonics as sampled (aliased).

The static-gain effects live in the Wiener nonlinearity instead (they need Cμ(k) and y(k)
together): ``hysteresis`` is :class:`rtlift.blocks.wiener.HysteresisGain`,
``output_nonlinearity`` is :class:`rtlift.blocks.wiener.OutputNonlinearity`.

**For a Kalman observer** every output stage has a ``kind`` and ``statespace()`` returning
``(A, B, C, D)`` in the paper's timing, on the very state that ``get_state()`` returns::

    x(k) = A x(k−1) + B u(k),    out(k) = C x(k) + D u(k),    u = the stage's input ΔCL

- ``kind == "filter"``: the stage filters ΔCL (B, C, D as above); stack its state after the
  hybrid model's and measure ``out``.
- ``kind == "additive"``: ``out(k) = ΔCL(k) + d(k)`` with an autonomous disturbance state,
  ``B = 0``, ``D = 1``, ``d(k) = C x(k)``: d is known given its state (a drift or a pickup
  whose phase the observer tracks by adding process noise to x).

Input stages are deterministic maps of the known input and need no observer state.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from scipy import signal

from rtlift.core.registry import EFFECTS, resolve


class InputStage:
    """Base of stages acting on (Cμ, Cμ_env)."""

    name: ClassVar[str] = ""
    where: ClassVar[str] = "input"
    state_size: int = 0

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        raise NotImplementedError

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def params(self) -> dict[str, float]:
        raise NotImplementedError

    def reset(self) -> None:
        self.set_state(np.zeros(self.state_size))

    def get_state(self) -> np.ndarray:
        raise NotImplementedError

    def set_state(self, state: np.ndarray) -> None:
        raise NotImplementedError


class OutputStage(InputStage):
    """Base of stages acting on the model's ΔCL."""

    where: ClassVar[str] = "output"
    kind: ClassVar[str] = ""
    """"filter" or "additive" (module docstring, "For a Kalman observer")."""

    def step(self, dcl: float) -> float:  # type: ignore[override]
        raise NotImplementedError

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D): x(k) = A x(k−1) + B u(k), out(k) = C x(k) + D u(k), x = get_state()."""
        raise NotImplementedError

    def simulate(self, dcl: np.ndarray) -> np.ndarray:  # type: ignore[override]
        raise NotImplementedError


class Delay(InputStage):
    """Measured lift lags the actuation record by D samples (DAQ or convective latency):
    ``Cμ′(k) = Cμ(k − D)``, ``Cμ_env′(k) = Cμ_env(k − D)``, ``D = round(seconds · fs)``."""

    name = "delay"

    def __init__(self, seconds: float, fs_hz: float) -> None:
        if not np.isfinite(seconds) or seconds < 0:
            raise ValueError(f"delay must be a non-negative number of seconds, got {seconds}")
        self.fs_hz = float(fs_hz)
        self.samples = int(round(seconds * fs_hz))
        self.state_size = 2 * self.samples
        self._cmu = np.zeros(self.samples)         # numpy, so the compiled step advances them too
        self._env = np.zeros(self.samples)
        self._pos = np.zeros(1, dtype=np.int64)     # next slot to read (the oldest) and write

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> Delay:
        return cls(float(params["seconds"]), fs_hz)

    def params(self) -> dict[str, float]:
        return {"seconds": self.samples / self.fs_hz}

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        if self.samples == 0:
            return cmu, env
        i = self._pos.item()
        out = (self._cmu.item(i), self._env.item(i))
        self._cmu[i] = cmu
        self._env[i] = env
        self._pos[0] = i + 1 if i + 1 < self.samples else 0
        return out

    def kernel_arrays(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: no parameters, state (Cμ ring, Cμ_env ring, position), not copies."""
        return (), (self._cmu, self._env, self._pos)

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(env, dtype=float)
        d = self.samples
        if d == 0:
            return cmu.copy(), env.copy()
        past = self.get_state()
        ext_c = np.concatenate([past[:d], cmu])
        ext_e = np.concatenate([past[d:], env])
        self.set_state(np.concatenate([ext_c[-d:], ext_e[-d:]]))
        return ext_c[: cmu.size], ext_e[: env.size]

    def get_state(self) -> np.ndarray:
        """Pending inputs, oldest first: [Cμ(k−D+1) … Cμ(k), env(k−D+1) … env(k)]."""
        i = int(self._pos[0])
        return np.concatenate([self._cmu[i:], self._cmu[:i], self._env[i:], self._env[:i]])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"delay state must have shape ({self.state_size},), got {s.shape}")
        d = self.samples
        self._cmu[:] = s[:d]
        self._env[:] = s[d:]
        self._pos[0] = 0


def _positive(value: float, what: str) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{what} must be a positive number, got {value}")
    return v


def _finite(value: float, what: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {value}")
    return v


class ActuatorFade(InputStage):
    """Actuators deliver less Cμ as they heat up:

        g(k) = f + (1 − f) exp(−E(k)/τ),   Cμ′(k) = g(k) Cμ(k),   Cμ_env′(k) = g(k) Cμ_env(k),
        E(k + 1) = E(k) + 1/fs if Cμ(k) > 0 else E(k)        (``clock`` "on_time", E(0) = 0)
        E(k + 1) = E(k) + 1/fs                                (``clock`` "time")

    with ``clock`` "on_time" the fade follows the burst on-time accumulated *before* sample k
    (heating by actuation), with "time" the wall time since the record started.
    ``final_fraction`` = f ∈ [0, 1], ``time_constant_s`` = τ > 0 (seconds of the clock).
    State: [E], the clock before the next sample.
    """

    name = "actuator_fade"
    state_size = 1
    CLOCKS = ("on_time", "time")

    def __init__(self, final_fraction: float, time_constant_s: float, fs_hz: float,
                 clock: str = "on_time") -> None:
        f = _finite(final_fraction, "actuator_fade final_fraction")
        if not 0.0 <= f <= 1.0:
            raise ValueError(f"actuator_fade final_fraction must be in [0, 1], got {f}")
        if clock not in self.CLOCKS:
            raise ValueError(f"actuator_fade clock must be one of {', '.join(self.CLOCKS)}, got {clock!r}")
        self.final_fraction = f
        self.time_constant_s = _positive(time_constant_s, "actuator_fade time_constant_s")
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self.clock = clock
        self._always = clock == "time"
        self.dt = 1.0 / self.fs_hz
        self.on_time = 0.0

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> ActuatorFade:
        return cls(float(params["final_fraction"]), float(params["time_constant_s"]), fs_hz,
                   str(params.get("clock", "on_time")))

    def params(self) -> dict[str, Any]:
        return {"final_fraction": self.final_fraction, "time_constant_s": self.time_constant_s,
                "clock": self.clock}

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        f = self.final_fraction
        g = f + (1.0 - f) * math.exp(-self.on_time / self.time_constant_s)
        if cmu > 0.0 or self._always:
            self.on_time += self.dt
        return cmu * g, env * g

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(env, dtype=float)
        inc = np.full(cmu.size, self.dt) if self._always else np.where(cmu > 0.0, self.dt, 0.0)
        elapsed = np.cumsum(np.concatenate([[self.on_time], inc]))   # sequential sums, as step
        before = elapsed[:-1]
        self.on_time = float(elapsed[-1])
        f = self.final_fraction
        g = f + (1.0 - f) * np.exp(-before / self.time_constant_s)
        return cmu * g, env * g

    def get_state(self) -> np.ndarray:
        return np.array([self.on_time])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (1,):
            raise ValueError(f"actuator_fade state must have shape (1,), got {s.shape}")
        self.on_time = float(s[0])


class SensorResonance(OutputStage):
    """Force-balance / wing mode filtering the measured lift, unity DC gain:

        H(s) = ω² / (s² + 2ζωs + ω²),  ω = 2π f, discretised by the bilinear transform with
        pre-warping at ω:  H(z) = (b₀ + b₁z⁻¹ + b₂z⁻²) / (1 + a₁z⁻¹ + a₂z⁻²).

    State x(k) = [w(k), w(k−1)] of the all-pole part w(k) = u(k) − a₁ w(k−1) − a₂ w(k−2);
    the output eliminates w(k−2) with the recursion:
    out(k) = (b₀ − b₂/a₂) w(k) + (b₁ − a₁b₂/a₂) w(k−1) + (b₂/a₂) u(k).
    """

    name = "sensor_resonance"
    kind = "filter"
    state_size = 2

    def __init__(self, frequency_hz: float, damping_ratio: float, fs_hz: float) -> None:
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self.frequency_hz = _positive(frequency_hz, "sensor_resonance frequency_hz")
        self.damping_ratio = _positive(damping_ratio, "sensor_resonance damping_ratio")
        if self.frequency_hz >= 0.5 * self.fs_hz:
            raise ValueError(f"sensor_resonance frequency_hz {self.frequency_hz:g} is not below "
                             f"Nyquist ({0.5 * self.fs_hz:g} Hz)")
        self.b, self.a = resonance_ba(self.frequency_hz, self.damping_ratio, self.fs_hz)
        b0, b1, b2 = (float(v) for v in self.b)
        _, a1, a2 = (float(v) for v in self.a)
        self._a1, self._a2 = a1, a2
        self._c0, self._c1, self._d = b0 - b2 / a2, b1 - a1 * b2 / a2, b2 / a2
        self._w0 = 0.0
        self._w1 = 0.0

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> SensorResonance:
        return cls(float(params["frequency_hz"]), float(params["damping_ratio"]), fs_hz)

    def params(self) -> dict[str, float]:
        return {"frequency_hz": self.frequency_hz, "damping_ratio": self.damping_ratio}

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        A = np.array([[-self._a1, -self._a2], [1.0, 0.0]])
        return A, np.array([1.0, 0.0]), np.array([self._c0, self._c1]), np.array(self._d)

    def step(self, dcl: float) -> float:
        w = dcl - self._a1 * self._w0 - self._a2 * self._w1
        self._w1 = self._w0
        self._w0 = w
        return self._c0 * w + self._c1 * self._w1 + self._d * dcl

    def simulate(self, dcl: np.ndarray) -> np.ndarray:
        u = np.asarray(dcl, dtype=float)
        if u.size == 0:
            return u.copy()
        a1, a2 = self._a1, self._a2
        zi = np.array([-a1 * self._w0 - a2 * self._w1, -a2 * self._w0])
        w, _ = signal.lfilter([1.0], self.a, u, zi=zi)
        w_prev = np.concatenate([[self._w0], w[:-1]])
        self._w1 = float(w_prev[-1])
        self._w0 = float(w[-1])
        return self._c0 * w + self._c1 * w_prev + self._d * u

    def get_state(self) -> np.ndarray:
        return np.array([self._w0, self._w1])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (2,):
            raise ValueError(f"sensor_resonance state must have shape (2,), got {s.shape}")
        self._w0, self._w1 = float(s[0]), float(s[1])


def resonance_ba(frequency_hz: float, damping_ratio: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of ω²/(s² + 2ζωs + ω²), bilinear with pre-warping at ω = 2π f."""
    w = 2.0 * fs_hz * math.tan(math.pi * frequency_hz / fs_hz)
    b, a = signal.bilinear([w * w], [1.0, 2.0 * damping_ratio * w, w * w], fs=fs_hz)
    return np.asarray(b, dtype=float), np.asarray(a, dtype=float)


class _Additive(OutputStage):
    """out(k) = ΔCL(k) + d(k), d(k) = C x(k), x(k) = A x(k−1) (2 states, see subclasses)."""

    kind = "additive"
    state_size = 2

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


def alias_hz(frequency_hz: float, fs_hz: float) -> float:
    """The frequency a sampler at ``fs_hz`` sees for a tone at ``frequency_hz`` (folded into
    [0, fs/2]): 420 Hz mains harmonic at 400 Hz → 20 Hz."""
    f = math.fmod(abs(frequency_hz), fs_hz)
    return fs_hz - f if f > 0.5 * fs_hz else f


class PeriodicDisturbance(OutputStage):
    """Narrow-band pickup as sampled: a set of lines added to ΔCL (t_k = k/fs, k = 0 after reset),

        d(k) = Σ_i A_i sin(ω_i k + φ_i),   ω_i = 2π f_i / fs,

    the fundamental f₀ (``frequency_hz``, ``amplitude``, ``phase_rad``) and optional harmonics
    n f₀ *as sampled* (``harmonics``: [{"n", "amplitude", "phase_rad"}], frequency
    :func:`alias_hz` (n f₀)): mains pickup with its odd harmonics, some folded by the sampler.
    State per line x_i(k) = [A_i sin(ω_i k + φ_i), A_i cos(ω_i k + φ_i)], rotated by R(ω_i);
    d(k) = Σ x_i,0(k) (kind "additive": B = 0, D = 1). The phases are a property of a record,
    not of the pickup: an observer tracks them in x, the diagnosis and ``rtlift validate``
    re-estimate them per record (:func:`rtlift.model.validation.predict_record`). The batch twin
    evaluates the rotation in closed form from the current state; the recursion and the
    closed form differ by rounding only (≈ k·1e-16·A).
    """

    name = "periodic_disturbance"
    kind = "additive"

    def __init__(self, frequency_hz: float, amplitude: float, phase_rad: float, fs_hz: float,
                 harmonics: list[dict[str, float]] | tuple = ()) -> None:
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self.frequency_hz = _positive(frequency_hz, "periodic_disturbance frequency_hz")
        if self.frequency_hz > 0.5 * self.fs_hz:
            raise ValueError(f"periodic_disturbance frequency_hz {self.frequency_hz:g} is above "
                             f"Nyquist ({0.5 * self.fs_hz:g} Hz): give the aliased frequency")
        self.amplitude = _finite(amplitude, "periodic_disturbance amplitude")
        self.phase_rad = _finite(phase_rad, "periodic_disturbance phase_rad")
        self.harmonics = []
        for h in harmonics:
            n = int(h["n"])
            if n < 2:
                raise ValueError(f"periodic_disturbance harmonic n must be >= 2, got {h['n']}")
            self.harmonics.append({"n": n, "amplitude": _finite(h["amplitude"], "harmonic amplitude"),
                                   "phase_rad": _finite(h.get("phase_rad", 0.0), "harmonic phase_rad")})
        freqs = [self.frequency_hz] + [alias_hz(h["n"] * self.frequency_hz, self.fs_hz) for h in self.harmonics]
        self.line_hz = np.array(freqs)
        self.omegas = 2.0 * math.pi * self.line_hz / self.fs_hz
        self.omega = float(self.omegas[0])
        self.state_size = 2 * self.omegas.size
        self._cos = [math.cos(w) for w in self.omegas]
        self._sin = [math.sin(w) for w in self.omegas]
        self._x = [0.0] * self.state_size
        self.reset()

    @property
    def amplitudes(self) -> np.ndarray:
        return np.array([self.amplitude] + [h["amplitude"] for h in self.harmonics])

    @property
    def phases(self) -> np.ndarray:
        return np.array([self.phase_rad] + [h["phase_rad"] for h in self.harmonics])

    def with_phases(self, phases: np.ndarray) -> PeriodicDisturbance:
        """The same lines with other phases (a record's own)."""
        harm = [{**h, "phase_rad": float(p)} for h, p in zip(self.harmonics, phases[1:], strict=True)]
        return PeriodicDisturbance(self.frequency_hz, self.amplitude, float(phases[0]), self.fs_hz, harm)

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> PeriodicDisturbance:
        return cls(float(params["frequency_hz"]), float(params["amplitude"]),
                   float(params.get("phase_rad", 0.0)), fs_hz, params.get("harmonics", ()))

    def params(self) -> dict[str, Any]:
        out: dict[str, Any] = {"frequency_hz": self.frequency_hz, "amplitude": self.amplitude,
                               "phase_rad": self.phase_rad}
        if self.harmonics:
            out["harmonics"] = [{**h, "frequency_hz": float(f)} for h, f in
                                zip(self.harmonics, self.line_hz[1:], strict=True)]
        return out

    def reset(self) -> None:
        for i, (a, p, w) in enumerate(zip(self.amplitudes, self.phases, self.omegas, strict=True)):
            self._x[2 * i] = float(a * math.sin(p - w))
            self._x[2 * i + 1] = float(a * math.cos(p - w))

    def get_state(self) -> np.ndarray:
        return np.array(self._x)

    def set_state(self, state: np.ndarray) -> None:
        st = np.asarray(state, dtype=float)
        if st.shape != (self.state_size,):
            raise ValueError(f"{self.name} state must have shape ({self.state_size},), got {st.shape}")
        self._x[:] = [float(v) for v in st]

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        L = self.omegas.size
        A = np.zeros((2 * L, 2 * L))
        for i, (c, s) in enumerate(zip(self._cos, self._sin, strict=True)):
            A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[c, s], [-s, c]]
        C = np.zeros(2 * L)
        C[0::2] = 1.0
        return A, np.zeros(2 * L), C, np.array(1.0)

    def step(self, dcl: float) -> float:
        x = self._x
        d = 0.0
        for i in range(len(self._cos)):
            c, s = self._cos[i], self._sin[i]
            x0, x1 = x[2 * i], x[2 * i + 1]
            x[2 * i] = c * x0 + s * x1
            x[2 * i + 1] = c * x1 - s * x0
            d += x[2 * i]
        return dcl + d

    def simulate(self, dcl: np.ndarray) -> np.ndarray:
        u = np.asarray(dcl, dtype=float)
        n = u.size
        if n == 0:
            return u.copy()
        out = u.copy()
        k = np.arange(1, n + 1)
        for i, w in enumerate(self.omegas):
            x0, x1 = self._x[2 * i], self._x[2 * i + 1]
            amp = math.hypot(x0, x1)
            theta = math.atan2(x0, x1) + w * k
            self._x[2 * i] = float(amp * math.sin(theta[-1]))
            self._x[2 * i + 1] = float(amp * math.cos(theta[-1]))
            out += amp * np.sin(theta)
        return out

    def disturbance(self, n: int) -> np.ndarray:
        """d(k) for the next n samples (advances the state)."""
        return self.simulate(np.zeros(n))


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
        m, _ = signal.lfilter([self._b], [1.0, -self._lam], cmu * self._inv_d, zi=[self._lam * self._m.item()])
        self._m[0] = m[-1]
        return m

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        return cmu.copy(), self.momentum_batch(cmu)

    def get_state(self) -> np.ndarray:
        return self._m.copy()

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (1,):
            raise ValueError(f"delivered_momentum state must have shape (1,), got {s.shape}")
        self._m[0] = s[0]


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
    State: [q(k)]."""

    name = "delivered_envelope"
    state_size = 1

    def __init__(self, time_constant_s: float, burst_samples: int, period_samples: int, fs_hz: float) -> None:
        tau, fs = _positive(time_constant_s, "delivered_envelope time_constant_s"), _positive(fs_hz, "fs_hz")
        on, period = int(burst_samples), int(period_samples)
        if not 0 < on <= period:
            raise ValueError(f"delivered_envelope needs 0 < burst_samples <= period_samples, got {on}, {period}")
        self.time_constant_s, self.burst_samples, self.period_samples, self.fs_hz = tau, on, period, fs
        self._lam = math.exp(-1.0 / (tau * fs))
        self._b = 1.0 - self._lam
        self._scale = 1.0 / optimal_rate_floor(self._lam, on, period)
        self._q = np.zeros(1)           # numpy, so the compiled step advances it too

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> DeliveredEnvelope:
        return cls(float(params["time_constant_s"]), int(params["burst_samples"]), int(params["period_samples"]),
                   fs_hz)

    def params(self) -> dict[str, float]:
        return {"time_constant_s": self.time_constant_s, "burst_samples": self.burst_samples,
                "period_samples": self.period_samples}

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        q = self._b * (1.0 if cmu > 0.0 else 0.0) + self._lam * self._q.item()
        self._q[0] = q
        return cmu, env * min(1.0, self._scale * q)

    def kernel_arrays(self) -> tuple[tuple[float, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: parameters (λ, 1 − λ, 1/q₀) and state (q,), not a copy."""
        return (self._lam, self._b, self._scale), (self._q,)

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(env, dtype=float)
        if cmu.size == 0:
            return cmu.copy(), env.copy()
        q, _ = signal.lfilter([self._b], [1.0, -self._lam], (cmu > 0).astype(float), zi=[self._lam * self._q.item()])
        self._q[0] = q[-1]
        return cmu.copy(), env * np.minimum(1.0, self._scale * q)

    def get_state(self) -> np.ndarray:
        return self._q.copy()

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (1,):
            raise ValueError(f"delivered_envelope state must have shape (1,), got {s.shape}")
        self._q[0] = s[0]


def optimal_rate_floor(lam: float, burst_samples: int, period_samples: int) -> float:
    """The minimum over a period of q(k) = λ q(k−1) + (1 − λ) x(k) in the periodic steady state of
    x = ``burst_samples`` ones then zeros, every ``period_samples``: q just before a burst,
    (1 − λ^on) λ^(T − on) / (1 − λ^T)."""
    on, period = int(burst_samples), int(period_samples)
    return (1.0 - lam ** on) * lam ** (period - on) / (1.0 - lam ** period)


STAGES: dict[str, Any] = {**{e.name: resolve(e.stages[0]) for e in EFFECTS if e.path != "nonlinearity"},
                          DeliveredMomentum.name: DeliveredMomentum, DeliveredEnvelope.name: DeliveredEnvelope}
"""Every stage by name: the effects' stages as the registry (:mod:`rtlift.core.registry`) names them
(the static-gain effects' are Wiener nonlinearities instead), and the interaction structure's
``delivered_envelope`` (and ``delivered_momentum``, as first merged), which are not effects."""


def stage_from_spec(name: str, params: dict[str, Any], fs_hz: float) -> InputStage:
    """Rebuild a stage from its model-file entry; ValueError for an unknown name."""
    if name not in STAGES:
        raise ValueError(f"unknown augmentation '{name}' (known: {', '.join(sorted(STAGES))})")
    return STAGES[name].from_params(params, fs_hz)
