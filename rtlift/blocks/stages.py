"""Augmentation stages: effects the paper's model lacks, added around the hybrid model.

An *input stage* maps the actuation record before the model sees it,
``(Cμ, Cμ_env) → (Cμ′, Cμ_env′)`` (a delay, a fading actuator); an *output stage* maps the
model's ΔCL to what the balance reports, ``ΔCL → ΔCL′`` (a sensor mode, a drift, a pickup).
Every stage is a streaming block (``step``, batch twin ``simulate``, explicit state) and is
named and parametrised as in INTERFACES.md, so a model file can list it and
:data:`STAGES` can rebuild it with ``from_params(params, fs_hz)``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np


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

    def step(self, dcl: float) -> float:  # type: ignore[override]
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
        self._cmu = [0.0] * self.samples
        self._env = [0.0] * self.samples
        self._i = 0

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> Delay:
        return cls(float(params["seconds"]), fs_hz)

    def params(self) -> dict[str, float]:
        return {"seconds": self.samples / self.fs_hz}

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        if self.samples == 0:
            return cmu, env
        i = self._i
        out = (self._cmu[i], self._env[i])
        self._cmu[i] = cmu
        self._env[i] = env
        self._i = i + 1 if i + 1 < self.samples else 0
        return out

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
        i = self._i
        return np.array(self._cmu[i:] + self._cmu[:i] + self._env[i:] + self._env[:i])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"delay state must have shape ({self.state_size},), got {s.shape}")
        d = self.samples
        self._cmu[:] = [float(v) for v in s[:d]]
        self._env[:] = [float(v) for v in s[d:]]
        self._i = 0


STAGES: dict[str, Any] = {Delay.name: Delay}


def stage_from_spec(name: str, params: dict[str, Any], fs_hz: float) -> InputStage:
    """Rebuild a stage from its model-file entry; ValueError for an unknown name."""
    if name not in STAGES:
        raise ValueError(f"unknown augmentation '{name}' (known: {', '.join(sorted(STAGES))})")
    return STAGES[name].from_params(params, fs_hz)
