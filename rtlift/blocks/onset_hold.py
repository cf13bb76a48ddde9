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

Compiled step: a slot of its own among the input stages
(:func:`rtlift.blocks.compiled_stages._held`, the same :func:`onset_value` compiled): its place
among the ``delay`` and the ``actuator_fade`` a flag in the model's packed parameters, its state
the last two floats of the stages' state array (:meth:`adopt_state`), so a model with a delay,
a fade and this stage in any of the orders the identification and the diagnosis make runs
compiled.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.blocks.stage_base import InputStage, _positive, _state_shaped


def onset_value(u: float, previous: float, cmu: float, env: float) -> float:
    """u(k) of the module docstring's recurrence from u(k−1), Cμ(k−1), Cμ(k) and Cμ_env(k) (Cμ
    units): 0 while Cμ_env ≤ 0, Cμ_env at an onset (Cμ > 0 after Cμ ≤ 0), else u(k−1). The one
    statement of the recurrence: :meth:`OnsetHold.step` runs it, and the compiled step runs it
    compiled (:func:`rtlift.blocks.compiled_stages._held`, through ``njit_cached``: this file's
    name of it puts the file in the compiled code's cache stamp, :mod:`rtlift.core.jit`)."""
    if not env > 0.0:
        return 0.0
    if cmu > 0.0 and not previous > 0.0:
        return env
    return u


class OnsetHold(InputStage):
    """The delivered envelope (module docstring): the envelope sampled at each burst onset and
    held until the next, 0 while the envelope is 0. No parameters. State: [u(k−1), Cμ(k−1)]."""

    name = "onset_hold"
    state_size = 2

    def __init__(self, fs_hz: float) -> None:
        self.fs_hz = _positive(fs_hz, "fs_hz")
        self._s = np.zeros(2)             # numpy, so the compiled step advances it too

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> OnsetHold:
        return cls(fs_hz)

    def params(self) -> dict[str, float]:
        return {}

    def adopt_state(self, view: np.ndarray) -> None:
        """Hold the state [u, Cμ(k−1)] in ``view`` (two float64, already holding it) from now on:
        the compiled step advances that array (:func:`rtlift.blocks.compiled_stages.bind_stage_states`)."""
        self._s = view

    def step(self, cmu: float, env: float) -> tuple[float, float]:
        s = self._s
        u = onset_value(s[0], s[1], cmu, env)
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
        self._s[:] = _state_shaped(state, self.name, 2)
