"""Recursive high-pass filter HF of the hybrid model (eq. 11's first term).

A cascade of second-order sections, each in transposed direct form II with the exact
recurrences of ``scipy.signal.sosfilt`` (section s, a₀ = 1):

    y(k)  = b₀ x(k) + z₀(k−1)
    z₀(k) = b₁ x(k) − a₁ y(k) + z₁(k−1)
    z₁(k) = b₂ x(k) − a₂ y(k)

so the state ``z`` (n_sections × 2) is sosfilt's ``zi`` and chunks can be handed to sosfilt
and back. Sections rather than one transfer function: a single (b, a) polynomial of
order ≥ 3 at a cutoff near 1 Hz at 400 Hz has poles within 1e-2 of z = 1 and amplifies its
own rounding by ~1e5 at DC; the cascade does not. Designed once as a Butterworth high-pass
(``scipy.signal.butter(..., output="sos")``). The state is one numpy array,
[z₀ z₁ of section 1, z₀ z₁ of section 2, …], so that the compiled step of
:mod:`rtlift.blocks.compiled` advances the very state this block reads and sets.
"""

from __future__ import annotations

import numpy as np


class HighPassFilter:
    """Streaming SOS filter with sosfilt-compatible state; :meth:`design` makes a Butterworth HPF."""

    def __init__(self, sos: np.ndarray, *, order: int | None = None, cutoff_hz: float | None = None) -> None:
        sos = np.atleast_2d(np.asarray(sos, dtype=float))
        if sos.ndim != 2 or sos.shape[1] != 6 or sos.shape[0] == 0:
            raise ValueError(f"filter sections must have shape (n, 6), got {sos.shape}")
        if not np.all(np.isfinite(sos)):
            raise ValueError("filter coefficients must be finite")
        if np.any(sos[:, 3] == 0):
            raise ValueError("every filter section needs a non-zero a0")
        sos = sos / sos[:, 3:4]
        for sec in sos:
            if np.any(sec[4:]) and np.max(np.abs(np.roots(sec[3:]))) >= 1.0:
                raise ValueError("high-pass filter is unstable (a pole on or outside the unit circle)")
        self.sos = sos
        poles = sum(2 if sec[5] != 0 else 1 if sec[4] != 0 else 0 for sec in sos)
        self.order = order if order is not None else int(poles)
        self.cutoff_hz = cutoff_hz
        self._coef = np.ascontiguousarray(sos[:, [0, 1, 2, 4, 5]])   # b₀ b₁ b₂ a₁ a₂ per section
        self._sec = [tuple(float(v) for v in row) for row in self._coef]
        self._z = np.zeros(2 * len(sos))

    @classmethod
    def design(cls, order: int, cutoff_hz: float, fs_hz: float) -> HighPassFilter:
        """Butterworth high-pass of ``order`` with −3 dB at ``cutoff_hz``."""
        if order < 1:
            raise ValueError("high-pass order must be at least 1")
        if not 0 < cutoff_hz < fs_hz / 2:
            raise ValueError(f"cutoff {cutoff_hz} Hz must lie between 0 and fs/2 = {fs_hz / 2} Hz")
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        sos = signal.butter(order, cutoff_hz, btype="highpass", fs=fs_hz, output="sos")
        return cls(sos, order=order, cutoff_hz=cutoff_hz)

    @classmethod
    def from_ba(cls, b: np.ndarray, a: np.ndarray, **kw) -> HighPassFilter:
        """From a transfer function (converted to sections once)."""
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        return cls(signal.tf2sos(b, a), **kw)

    @property
    def ba(self) -> tuple[np.ndarray, np.ndarray]:
        """The equivalent single transfer function (for reports; not used to filter)."""
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        return signal.sos2tf(self.sos)

    @property
    def state_size(self) -> int:
        return 2 * len(self._sec)

    def step(self, x: float) -> float:
        z, zs = self._z, self._z.tolist()
        i = 0
        for b0, b1, b2, a1, a2 in self._sec:
            y = b0 * x + zs[i]
            z[i] = b1 * x - a1 * y + zs[i + 1]
            z[i + 1] = b2 * x - a2 * y
            x = y
            i += 2
        return x

    def kernel_arrays(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: parameters (sections (n, 5): b₀ b₁ b₂ a₁ a₂,) and state (z,)."""
        return (self._coef,), (self._z,)

    def simulate(self, x: np.ndarray) -> np.ndarray:
        """Batch twin: ``sosfilt(sos, x, zi=state)``; advances the state."""
        x = np.asarray(x, dtype=float)
        if x.size == 0:
            return x.copy()
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        y, zf = signal.sosfilt(self.sos, x, zi=self._z.reshape(-1, 2))
        self._z[:] = zf.ravel()
        return y

    def reset(self) -> None:
        self._z[:] = 0.0

    def get_state(self) -> np.ndarray:
        return self._z.copy()

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"filter state must have shape ({self.state_size},), got {s.shape}")
        self._z[:] = s

    def frequency_response(self, freqs_hz: np.ndarray, fs_hz: float) -> np.ndarray:
        """Complex gain at ``freqs_hz`` (for reports)."""
        from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
        _, h = signal.sosfreqz(self.sos, worN=np.asarray(freqs_hz, dtype=float), fs=fs_hz)
        return h
