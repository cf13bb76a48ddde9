"""The stage interface (the base classes every stage implements; :mod:`rtlift.blocks.stages`
finds the stages by name): effects the paper's model lacks, added around the hybrid model as stages.

An *input stage* maps the actuation record before the model sees it,
``(Cμ, Cμ_env) → (Cμ′, Cμ_env′)`` (a delay, a fading actuator); an *output stage* maps the
model's ΔCL to what the balance reports, ``ΔCL → ΔCL′`` (a sensor mode, a drift, a pickup).
Every stage is a streaming block (``step``, batch twin ``simulate``, explicit state) and is
named and parametrised as in INTERFACES.md, so a model file can list it and
:data:`rtlift.blocks.stages.STAGES` (derived from the stage classes; the effect of
:mod:`rtlift.effects` that adds a stage takes the stage's name) can rebuild it with
``from_params(params, fs_hz)``. Each stage lives in a module of its own
(:mod:`rtlift.blocks.delay`, :mod:`rtlift.blocks.actuator_fade`, :mod:`rtlift.blocks.sensor_resonance`,
:mod:`rtlift.blocks.zero_drift`, :mod:`rtlift.blocks.periodic_disturbance`; the ``interaction``
structure's in :mod:`rtlift.blocks.delivered`), its docstring holding its equation.

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
from typing import ClassVar

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
    kind: ClassVar[str] = ""
    """"filter" or "additive" (module docstring, "For a Kalman observer")."""
    compiled_form: ClassVar[bool] = False
    """True when :meth:`statespace` is the stage's whole step and its state lives in ``_xs``
    (:meth:`adopt_state`): the compiled step then runs it (:mod:`rtlift.blocks.compiled_stages`)."""

    def step(self, dcl: float) -> float:  # type: ignore[override]
        raise NotImplementedError

    def statespace(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D): x(k) = A x(k−1) + B u(k), out(k) = C x(k) + D u(k), x = get_state()."""
        raise NotImplementedError

    def adopt_state(self, view: np.ndarray) -> None:
        """Hold the state in ``view`` from now on (it already holds the current state; float64,
        ``state_size`` long): the compiled output chain advances that array in place
        (:func:`rtlift.blocks.compiled_stages.bind_output_states`). Every output stage keeps its
        state in the array ``self._xs``, in the order of :meth:`get_state`."""
        self._xs = view

    def simulate(self, dcl: np.ndarray) -> np.ndarray:  # type: ignore[override]
        raise NotImplementedError


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
