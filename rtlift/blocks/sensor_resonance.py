"""The ``sensor_resonance`` effect's stage: a force-balance / wing mode filtering the measured lift."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.blocks.stage_base import OutputStage, _positive


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
    compiled_form = True
    _w0 = property(lambda self: float(self._xs[0]), lambda self, v: self._xs.__setitem__(0, v))
    _w1 = property(lambda self: float(self._xs[1]), lambda self, v: self._xs.__setitem__(1, v))

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
        self._xs = np.zeros(2)

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
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
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
    from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
    b, a = signal.bilinear([w * w], [1.0, 2.0 * damping_ratio * w, w * w], fs=fs_hz)
    return np.asarray(b, dtype=float), np.asarray(a, dtype=float)
