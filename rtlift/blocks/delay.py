"""The ``delay`` effect's stage: the measured lift lags the actuation record by D samples."""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.blocks.stage_base import InputStage


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
