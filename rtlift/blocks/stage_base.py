"""The stage interface (the base classes every stage implements) and the stages by name
(:data:`STAGES`, :func:`stage_class`): effects the paper's model lacks, added around the hybrid
model as stages.

An *input stage* maps the actuation record before the model sees it,
``(Cμ, Cμ_env) → (Cμ′, Cμ_env′)`` (a delay, a fading actuator); an *output stage* maps the
model's ΔCL to what the balance reports, ``ΔCL → ΔCL′`` (a sensor mode, a drift, a pickup).
Every stage is a streaming block (``step``, batch twin ``simulate``, explicit state) and is
named and parametrised as in INTERFACES.md, so a model file can list it and :func:`stage_class`
can rebuild it with ``from_params(params, fs_hz)``.

**Stages register themselves**: defining a subclass that sets ``name`` puts it in :data:`STAGES`
(``__init_subclass__``; two classes of one name are an error, and a test's stand-in opts out
with ``class X(OutputStage, register=False)``). The stages the model layer steps itself live in
:mod:`rtlift.blocks`, one module each (:mod:`rtlift.blocks.delay`,
:mod:`rtlift.blocks.actuator_fade`, :mod:`rtlift.blocks.sensor_resonance`,
:mod:`rtlift.blocks.zero_drift`, :mod:`rtlift.blocks.periodic_disturbance`; the ``interaction``
structure's in :mod:`rtlift.blocks.delivered`), each docstring holding its equation; a newer
effect may define its stage in its own module of :mod:`rtlift.effects`, a floor above the model
file's reader: :func:`stage_class` then finds it through the stage providers the package's entry
hands down (:mod:`rtlift.core.registry`), never by importing upward.

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

from rtlift.core.registry import run_stage_providers

STAGES: dict[str, type[InputStage]] = {}
"""Every stage class defined so far, by its ``name`` (the model file's key; the effect that adds
the stage takes it as its own name): filled by :meth:`InputStage.__init_subclass__`."""


class UnknownStageError(ValueError):
    """A model file names a stage no class registered (after the stage providers ran)."""


class InputStage:
    """Base of stages acting on (Cμ, Cμ_env)."""

    name: ClassVar[str] = ""
    where: ClassVar[str] = "input"
    state_size: int = 0

    def __init_subclass__(cls, register: bool = True, **kwargs: Any) -> None:
        """Register a stage class that sets ``name`` in :data:`STAGES` (module docstring)."""
        super().__init_subclass__(**kwargs)
        name = cls.__dict__.get("name")
        if not register or not name:
            return                        # an intermediate base, or a test's stand-in
        if name in STAGES:
            raise TypeError(f"two stages named {name!r}: {STAGES[name].__qualname__} and {cls.__qualname__}")
        STAGES[name] = cls

    @classmethod
    def from_params(cls, params: dict[str, Any], fs_hz: float) -> InputStage:
        """The stage from its model-file parameters at sample rate ``fs_hz`` (Hz)."""
        raise NotImplementedError

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


def stage_class(name: str) -> type[InputStage]:
    """The stage class a model file's ``name`` means (:data:`STAGES`). A name not registered
    runs the stage providers first (an effect's own stage, :mod:`rtlift.core.registry`);
    :class:`UnknownStageError` if it is still unknown."""
    if name not in STAGES:
        run_stage_providers()
    if name not in STAGES:
        raise UnknownStageError(
            f"unknown augmentation '{name}' (known: {', '.join(sorted(STAGES))}); an effect module's own stage "
            "is known once its module is imported (import rtlift.effects)")
    return STAGES[name]


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


def _state_shaped(state: np.ndarray, name: str, size: int) -> np.ndarray:
    """``state`` as float64 when it has shape (``size``,), else a ValueError naming stage ``name``
    (each stage's ``set_state`` check)."""
    s = np.asarray(state, dtype=float)
    if s.shape != (size,):
        raise ValueError(f"{name} state must have shape ({size},), got {s.shape}")
    return s
