"""The ``onset_hold`` input stage: the envelope each burst delivered, held until the next onset
(issue 47, fifth pass; the lift identification's Wiener input for records with bursts).

The bench's firmware (``hil_sim.actuation.actuate_volts``, ``hil_sim.hil``) fires a burst of
Δt_b = 4 samples at every onset of its schedule with the envelope's amplitude: the record's Cμ
column is the envelope's Cμ while a burst is on, 0 between bursts; under host control the
envelope itself is latched at each onset. So the flow receives the envelope only at the
onsets, whatever it does in between: a smooth envelope is sampled by the bursts, and a held one
(the loop's, decided once a period) delivers the same bursts. The stage gives the Wiener part
that delivered envelope, from the inputs the model receives in every loop::

    onset(k) = [Cμ(k) > 0 and Cμ(k−1) ≤ 0]
    u(k) = 0                 if Cμ_env(k) ≤ 0        (actuators off: no burst from here on)
         = Cμ_env(k)         if onset(k)              (the burst's amplitude)
         = u(k−1)            otherwise                (held until the next onset)

maps (Cμ, Cμ_env) to (Cμ, u); Cμ passes unchanged (the burst part sees each burst as fired).
u is in the envelope's units (Cμ). A constant envelope with bursts at any rate gives u =
Cμ_env from the first onset on, so the stage changes nothing on single bursts and burst trains
at a held amplitude; it removes the half burst period (on average) by which a smooth envelope
leads what the bursts deliver. State: [u(k−1), Cμ(k−1)].

Compiled step: :func:`rtlift.blocks.compiled_stages._faded` runs it after the ``actuator_fade``
slot when the model has no fade (its parameter array then carries the hold's flag and state,
:meth:`kernel_arrays`); a model with both a fade and this stage takes the reference step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.blocks.stage_base import InputStage, _positive

HOLD_FLAG = 5
"""Index of the hold's flag in the compiled step's fade-slot parameter array (after the fade's
five); the hold's state [u, Cμ(k−1)] follows it."""


class OnsetHold(InputStage):
    """The delivered envelope (module docstring): the envelope sampled at each burst onset and
    held until the next, 0 while the envelope is 0. No parameters. State: [u(k−1), Cμ(k−1)]."""

    name = "onset_hold"
    state_size = 2

    def __init__(self, fs_hz: float) -> None:
        self.fs_hz = _positive(fs_hz, "fs_hz")
        # the compiled step's fade slot without a fade: [on, f = 1, τ = 1, 1/fs, clock, hold on,
        # u, Cμ(k−1)] (g = f + (1 − f) e^(−E/τ) = 1 exactly); the state is a view into it
        self._slot = np.array([1.0, 1.0, 1.0, 1.0 / self.fs_hz, 0.0, 1.0, 0.0, 0.0])
        self._s = self._slot[HOLD_FLAG + 1:HOLD_FLAG + 3]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_s"]                   # a view into _slot: made again on unpickling / copying
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._s = self._slot[HOLD_FLAG + 1:HOLD_FLAG + 3]

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> OnsetHold:
        return cls(fs_hz)

    def params(self) -> dict[str, float]:
        return {}

    def kernel_arrays(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """For the compiled step: the fade slot's parameter array with the hold's flag and state
        (the state a view into it, not a copy), and the state."""
        return (self._slot,), (self._s,)

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        s = self._s
        if not env > 0.0:
            u = 0.0
        elif cmu > 0.0 and not s[1] > 0.0:
            u = env
        else:
            u = s[0]
        s[0] = u
        s[1] = cmu
        return cmu, u

    def simulate(self, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch twin of :meth:`step`: each sample takes the value of the last event (an onset:
        the envelope; the envelope ≤ 0: 0) at or before it, the state's u before the first."""
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(env, dtype=float)
        if cmu.size == 0:
            return cmu.copy(), env.copy()
        prev = np.concatenate(([self._s[1]], cmu[:-1]))
        off = ~(env > 0.0)
        event = off | ((cmu > 0.0) & ~(prev > 0.0))
        value = np.where(off, 0.0, env)
        last = np.maximum.accumulate(np.where(event, np.arange(cmu.size), -1))
        u = np.where(last >= 0, value[np.maximum(last, 0)], self._s[0])
        self._s[0] = u[-1]
        self._s[1] = cmu[-1]
        return cmu.copy(), u

    def get_state(self) -> np.ndarray:
        return self._s.copy()

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (2,):
            raise ValueError(f"onset_hold state must have shape (2,), got {s.shape}")
        self._s[:] = s
