"""The ``periodic_disturbance`` effect's stage: narrow-band pickup (mains, fan blade passing) as sampled."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.blocks.stage_base import OutputStage, _finite, _positive


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
    per_record = ("phase_rad",)
    """Parameters of a record's own, not of the pickup: re-estimated on each record
    (:func:`rtlift.model.validation.predict_record`)."""
    kind = "additive"
    compiled_form = True

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
        self._xs = np.zeros(self.state_size)
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
            self._xs[2 * i] = float(a * math.sin(p - w))
            self._xs[2 * i + 1] = float(a * math.cos(p - w))

    def get_state(self) -> np.ndarray:
        return np.array(self._xs)

    def set_state(self, state: np.ndarray) -> None:
        st = np.asarray(state, dtype=float)
        if st.shape != (self.state_size,):
            raise ValueError(f"{self.name} state must have shape ({self.state_size},), got {st.shape}")
        self._xs[:] = [float(v) for v in st]

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        L = self.omegas.size
        A = np.zeros((2 * L, 2 * L))
        for i, (c, s) in enumerate(zip(self._cos, self._sin, strict=True)):
            A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[c, s], [-s, c]]
        C = np.zeros(2 * L)
        C[0::2] = 1.0
        return A, np.zeros(2 * L), C, np.array(1.0)

    def step(self, dcl: float) -> float:
        x = self._xs
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
            x0, x1 = self._xs[2 * i], self._xs[2 * i + 1]
            amp = math.hypot(x0, x1)
            theta = math.atan2(x0, x1) + w * k
            self._xs[2 * i] = float(amp * math.sin(theta[-1]))
            self._xs[2 * i + 1] = float(amp * math.cos(theta[-1]))
            out += amp * np.sin(theta)
        return out

    def disturbance(self, n: int) -> np.ndarray:
        """d(k) for the next n samples (advances the state)."""
        return self.simulate(np.zeros(n))
