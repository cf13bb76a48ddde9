"""The effects a lift model can be augmented with and the structures a generic ``t,u,y`` model
can be given: one module each, one class each (:mod:`rtlift.effects.base`: what a class
declares — schema, signal path, stage, fit, evidence, parameters spent, bands, observer form).

Importing the package imports every module in it; each class registers itself when defined,
and the tables below are derived from what registered (a new effect is a new module here and
its row in INTERFACES.md's table, plus its bench processor in :mod:`hil_sim.effects` if the bench
injects it; a stage of its own is defined in the same module, and the model file's reader finds it
through the stage provider ``rtlift/__init__.py`` hands down, :mod:`rtlift.core.registry`):

- :data:`EFFECTS`, :data:`STRUCTURES`: the lift effects and the structures, in INTERFACES.md's
  order; :data:`BY_NAME` both by name;
- :data:`CATALOG`: the effects in the order the diagnosis builds a combination in, the signal
  path's (:data:`~rtlift.effects.base.PATHS`: input stages, the nonlinearity, filter, additive;
  INTERFACES.md's order within one path), :data:`EFFECT_NAMES` their names;
- :data:`SCHEMAS`: each effect's parameter schema by name.

Layer: above identification (the fits re-identify), below the diagnosis and the observer, which
use these tables (``tests/test_layers.py``).
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Mapping
from types import MappingProxyType

from rtlift.core.effects import EffectSchema
from rtlift.effects.base import PATHS, Effect, Entry, StateBlock, Structure, frozen, registered
from rtlift.effects.surgery import Context, Fitted, augment, predict, reestimate, rescaled

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")      # its classes register themselves

ENTRIES: tuple[Entry, ...] = registered()
BY_NAME: Mapping[str, Entry] = frozen(ENTRIES)
EFFECTS: tuple[Effect, ...] = tuple(e for e in ENTRIES if isinstance(e, Effect))
"""The lift-model effects, in INTERFACES.md's order."""
STRUCTURES: tuple[Structure, ...] = tuple(e for e in ENTRIES if isinstance(e, Structure))
"""The generic ``t,u,y`` structures the diagnosis adds, in INTERFACES.md's order."""
CATALOG: tuple[Effect, ...] = tuple(sorted(EFFECTS, key=lambda e: PATHS.index(e.path)))
"""The effects in the order a combination is built: the signal path's (stable within one path)."""
EFFECT_NAMES: tuple[str, ...] = tuple(e.name for e in CATALOG)
SCHEMAS: Mapping[str, EffectSchema] = MappingProxyType({e.name: e.schema for e in EFFECTS})

__all__ = ["BY_NAME", "CATALOG", "EFFECTS", "EFFECT_NAMES", "ENTRIES", "PATHS", "SCHEMAS", "STRUCTURES", "Context",
           "Effect", "Entry", "Fitted", "StateBlock", "Structure", "augment", "predict", "reestimate", "rescaled"]
