"""An effect's parameter schema: defaults, units, documented ranges, alternative sets, and the
intervals a parameter may take.

The schemas themselves are declared by each effect's class in :mod:`rtlift.effects`
(:data:`rtlift.effects.SCHEMAS` by name); this module holds only their form. The simulated
bench draws and checks its injected effects against these ranges (it keeps its own truth
physics), the model's stages take these parameter names, and the diagnosis's catalog adds to
each the fit and the evidence that point at it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np


@dataclass(frozen=True)
class EffectSchema:
    """One effect's name, meaning, parameters (defaults, units and documented ranges, SI units)."""

    name: str
    meaning: str
    defaults: Mapping[str, float] = field(default_factory=dict)
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    alternatives: tuple[Mapping[str, float], ...] = ()
    """Parameter sets, with their defaults, that may be given instead of the defaults' set
    (zero_drift: an exponential approach instead of a rate)."""
    units: Mapping[str, str] = field(default_factory=dict)

    @property
    def parameter_sets(self) -> tuple[tuple[str, ...], ...]:
        return (tuple(self.defaults), *(tuple(a) for a in self.alternatives))

    def defaults_for(self, given: set[str]) -> Mapping[str, float]:
        """The defaults of the first parameter set that holds every given name (the
        defaults' own set when none does, or nothing is given)."""
        for d in (self.defaults, *self.alternatives):
            if given <= set(d):
                return d
        return self.defaults

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """Parameters drawn uniformly from ``ranges`` (one of the parameter sets)."""
        sets = self.parameter_sets
        chosen = sets[int(rng.integers(len(sets)))]
        return {k: float(rng.uniform(*self.ranges[k])) for k in chosen}


def schema(name: str, meaning: str, params: dict[str, tuple[float, float, float, str]] | None = None,
           alternatives: dict[str, tuple[float, float, float, str]] | None = None) -> EffectSchema:
    """A schema from ``{param: (default, lo, hi, unit)}`` (and one alternative set alike)."""
    params, alt = params or {}, alternatives or {}
    both = {**params, **alt}
    frozen = MappingProxyType
    return EffectSchema(name, meaning, frozen({k: v[0] for k, v in params.items()}),
                        frozen({k: (v[1], v[2]) for k, v in both.items()}),
                        (frozen({k: v[0] for k, v in alt.items()}),) if alt else (),
                        frozen({k: v[3] for k, v in both.items()}))


@dataclass(frozen=True)
class Interval:
    """Where a parameter may lie, written as in mathematics: ``"(0, 10]"``, ``"[0, inf)"``."""

    text: str

    def __post_init__(self) -> None:
        lo, hi = self.text[1:-1].split(",")
        if self.text[0] not in "([" or self.text[-1] not in ")]" or not float(lo) < float(hi):
            raise ValueError(f"not an interval: {self.text!r}")

    def __contains__(self, value: float) -> bool:
        lo, hi = (float(v) for v in self.text[1:-1].split(","))
        above = value >= lo if self.text[0] == "[" else value > lo
        below = value <= hi if self.text[-1] == "]" else value < hi
        return above and below and math.isfinite(value)

    def __str__(self) -> str:
        return self.text
