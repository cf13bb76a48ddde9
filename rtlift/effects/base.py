"""What an effect or a structure declares, as one class, and how the list of them is derived.

An :class:`Effect` subclass in a module of its own (``rtlift/effects/<name>.py``) declares one
lift effect: its name, its one line of meaning and its parameters (``{param: (default, lo, hi,
unit)}``, SI units: the :class:`~rtlift.core.effects.EffectSchema` built from them), where it acts
(``path``, one of :data:`PATHS`), its streaming stage or Wiener nonlinearity forms (``stages``),
its fit (:meth:`Effect.fit`), the evidence that points at it (:meth:`Effect.evidence`), the
parameters it spends (:meth:`Effect.n_params`), the frequency bands an accepted fit accounts for
(:meth:`Effect.bands`), the effects it excludes, and its observer form
(:meth:`Effect.observer_form`). A :class:`Structure` subclass declares a generic ``t,u,y``
model's structure the generic diagnosis adds (its meaning, how it is fitted, the model
structures it is tried in).

Defining the class registers it (``__init_subclass__``, as scipy.stats derives its distributions
from their classes): :mod:`rtlift.effects` imports every module of its package and derives its
tables (:data:`rtlift.effects.EFFECTS`, ``CATALOG``, ``STRUCTURES``, ``BY_NAME``) from what
registered, in the order of INTERFACES.md's effects table (``row``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from rtlift.core.effects import EffectSchema, schema
from rtlift.core.records import Record
from rtlift.effects.surgery import Context, Fitted
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure
from rtlift.residual.stats import TestResult

PATHS = ("input", "nonlinearity", "filter", "additive")
"""Where a lift effect acts, in the signal path's order (input stages, the Wiener nonlinearity,
filter-kind output stages, additive output stages): the order a combination is built in."""

Params = dict[str, tuple[float, float, float, str]]


@dataclass(frozen=True)
class StateBlock:
    """States an accepted effect adds to the observer: ``s(k) = F s(k−1) + w``, ``w ~ N(0, Q)``,
    seen in the measurement through ``h · s(k)``; ``in_estimate`` if they are part of the lift
    ΔĈL (:mod:`rtlift.observer.layout`)."""

    name: str
    F: np.ndarray
    Q: np.ndarray
    h: np.ndarray
    P0: np.ndarray
    in_estimate: bool = False

    @property
    def size(self) -> int:
        return int(self.h.size)


class Entry:
    """One effect or structure (module docstring); a subclass that sets ``name`` registers
    itself, one instance per class."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""
    row: ClassVar[int] = 0
    """Where it stands in INTERFACES.md's effects table among those of its kind (the effects
    first, then the structures; rows in steps of 10, so that a new one goes between two others
    without renumbering them)."""
    meaning: ClassVar[str] = ""
    params: ClassVar[Params | None] = None
    alternatives: ClassVar[Params | None] = None
    schema: ClassVar[EffectSchema]
    _registered: ClassVar[dict[str, Entry]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            return                       # an intermediate base, not an effect
        if cls.name in Entry._registered:
            raise TypeError(f"two effects named {cls.name!r}")
        cls.schema = schema(cls.name, cls.meaning, cls.params, cls.alternatives)
        Entry._registered[cls.name] = cls()

    @property
    def doc(self) -> str:
        """The one line of meaning (the diagnosis report quotes it)."""
        return self.meaning

    def __repr__(self) -> str:
        return f"<{self.kind} {self.name}>"


KINDS = ("effect", "structure")


def registered() -> tuple[Entry, ...]:
    """Every effect and structure defined so far, in INTERFACES.md's order (the effects, then
    the structures, each by ``row``)."""
    return tuple(sorted(Entry._registered.values(), key=lambda e: (KINDS.index(e.kind), e.row)))


def no_print(what: str) -> Departure:
    """The evidence without a fingerprint: compared with a white residual."""
    return Departure(float("inf"), True, f"{what} (no fingerprint: compared with a white residual)")


class Effect(Entry):
    """A lift-model effect: it departs from what the model's identification data showed."""

    kind = "effect"
    path: ClassVar[str] = ""
    stages: ClassVar[tuple[type, ...]] = ()
    """The streaming stage (one of :mod:`rtlift.blocks`, or one the effect's own module defines: it
    registers itself, :mod:`rtlift.blocks.stage_base`), or the Wiener nonlinearity forms."""
    spent: ClassVar[int] = 0
    """Parameters the effect spends (:meth:`n_params` when it depends on the fit)."""
    excludes: ClassVar[tuple[str, ...]] = ()
    fits_change: ClassVar[bool] = False
    """Replaces the model's static map: fitted to what changed since identification where the
    model's own misfit on the training input is known (:func:`rtlift.residual.fingerprint.change_misfit`:
    the identification run it repeats, or the misfit predicted for its input), since that misfit
    is a misfit of the map too and a fit to the raw residual takes it for part of the effect."""
    per_record: ClassVar[tuple[str, ...]] = ()
    """Parameters that belong to a record, not to the effect: re-estimated on each record
    (the stage's own ``per_record``, :func:`rtlift.model.validation.predict_record`)."""
    observed: ClassVar[bool] = False
    """Whether :meth:`observer_form` applies (the observer represents the stage by states, or
    by its bias state); otherwise the stage is applied as a known correction."""
    bands: ClassVar[Any] = None
    """``None``, or a method ``bands(params, df) → [(lo_hz, hi_hz)]``: the frequency bands an
    accepted fit accounts for in the residual's spectrum, widened by half a bin ``df``
    (:func:`rtlift.diagnose.unexplained.explained_bands`)."""

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        """The augmented model fitted on the training record after ``ctx.start`` (output error,
        Ljung eq. 7.12), or why there is nothing to fit."""
        raise NotImplementedError

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        """What in the training residual points at the effect, against the model's print."""
        raise NotImplementedError

    def n_params(self, params: Mapping[str, Any]) -> int:
        """Parameters the fitted effect spends."""
        return self.spent

    def observer_form(self, params: dict[str, Any], fs_hz: float) -> StateBlock | None:
        """The observer's states for the effect's stage (``None``: the bias state covers it)."""
        return None


class Structure(Entry):
    """A generic ``t,u,y`` model's form is too simple: the generic diagnosis tries it
    (:mod:`rtlift.sysid.diagnose`)."""

    kind = "structure"
    how: ClassVar[str] = ""
    """How the generic diagnosis fits it (the report says so)."""
    forms: ClassVar[tuple[tuple[str, str | None], ...]] = ()
    """The model structures it is tried in, each with where its limit sits (``None``: none)."""


def frozen(entries: tuple[Entry, ...]) -> Mapping[str, Entry]:
    """``{name: entry}``, read-only."""
    return MappingProxyType({e.name: e for e in entries})
