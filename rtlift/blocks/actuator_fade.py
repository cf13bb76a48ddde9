"""The ``actuator_fade`` effect's stage: actuators deliver less Cμ as they heat up."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.blocks.stage_base import InputStage, _finite, _positive


class ActuatorFade(InputStage):
    """Actuators deliver less Cμ as they heat up:

        g(k) = f + (1 − f) exp(−E(k)/τ),   Cμ′(k) = g(k) Cμ(k),   Cμ_env′(k) = g(k) Cμ_env(k),
        E(k + 1) = E(k) + 1/fs if Cμ(k) > 0 else E(k)        (``clock`` "on_time", E(0) = E₀)
        E(k + 1) = E(k) + 1/fs                                (``clock`` "time")

    with ``clock`` "on_time" the fade follows the burst on-time accumulated *before* sample k
    (heating by actuation), with "time" the wall time since the record started.
    ``final_fraction`` = f ∈ [0, 1], ``time_constant_s`` = τ > 0 (seconds of the clock),
    ``on_time0_s`` = E₀ ≥ 0 the clock at rest (0: the fade starts with the record; > 0: it had run
    that long before, as when ``--adapt`` fits it again on a later window of a run).
    State: [E], the clock before the next sample.
    """

    name = "actuator_fade"
    state_size = 1
    CLOCKS = ("on_time", "time")

    def __init__(self, final_fraction: float, time_constant_s: float, fs_hz: float,
                 clock: str = "on_time", on_time0_s: float = 0.0) -> None:
        f = _finite(final_fraction, "actuator_fade final_fraction")
        if not 0.0 <= f <= 1.0:
            raise ValueError(f"actuator_fade final_fraction must be in [0, 1], got {f}")
        if clock not in self.CLOCKS:
            raise ValueError(f"actuator_fade clock must be one of {', '.join(self.CLOCKS)}, got {clock!r}")
        tau = _positive(time_constant_s, "actuator_fade time_constant_s")
        e0 = _finite(on_time0_s, "actuator_fade on_time0_s")
        if e0 < 0.0:
            raise ValueError(f"actuator_fade on_time0_s must be >= 0, got {e0}")
        self.on_time0_s = e0
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self.clock = clock
        self._always = clock == "time"
        self.dt = 1.0 / self.fs_hz
        # the compiled step's view of this stage (rtlift.blocks.compiled._faded): its parameters
        # [on, f, τ, 1/fs, clock is "time"] and its state [E], the arrays themselves, so that a fit
        # that sets f or τ (rtlift.effects.actuator_fade) is seen by the compiled model at once
        self._par = np.array([1.0, f, tau, self.dt, float(self._always)])
        self._state = np.array([e0])

    final_fraction = property(lambda self: float(self._par[1]),
                              lambda self, v: self._par.__setitem__(1, float(v)))
    time_constant_s = property(lambda self: float(self._par[2]),
                               lambda self, v: self._par.__setitem__(2, float(v)))
    on_time = property(lambda self: float(self._state[0]), lambda self, v: self._state.__setitem__(0, float(v)))
    """E, the clock before the next sample (s)."""

    def reset(self) -> None:
        """At rest: the clock at E₀."""
        self.on_time = self.on_time0_s

    def adopt_state(self, view: np.ndarray) -> None:
        """Hold the clock E in ``view`` (one float64, already holding it) from now on: the compiled
        step advances that array (:func:`rtlift.blocks.compiled_stages.bind_stage_states`)."""
        self._state = view

    def kernel_arrays(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: the parameters and the state, not copies."""
        return (self._par,), (self._state,)

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> ActuatorFade:
        return cls(float(params["final_fraction"]), float(params["time_constant_s"]), fs_hz,
                   str(params.get("clock", "on_time")), float(params.get("on_time0_s", 0.0)))

    def params(self) -> dict[str, Any]:
        out: dict[str, Any] = {"final_fraction": self.final_fraction, "time_constant_s": self.time_constant_s,
                               "clock": self.clock}
        if self.on_time0_s:
            out["on_time0_s"] = self.on_time0_s
        return out

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        par, state = self._par, self._state
        f = float(par[1])
        e = float(state[0])
        g = f + (1.0 - f) * math.exp(-e / float(par[2]))
        if cmu > 0.0 or self._always:
            state[0] = e + self.dt
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
